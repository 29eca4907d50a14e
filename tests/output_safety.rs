//! What a build may write and replace (DESIGN.md, promise 7): never `.`,
//! `..`, the current directory, a folder above it or one that holds an
//! input; an existing OUT only if it is a tileset this tool wrote, swapped
//! in whole; an OUT that appears during the build left alone; dead builds'
//! temporary folders cleaned by the next build; settings outside what the
//! output can carry refused before anything is written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use serde_json::Value;
use terrachunk::pipeline::out_dir::{MARKER, OutDir, OutDirError};

use crate::common::{cli, fixture, verified, verified_against, write_asc};

fn cli_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terrachunk")).current_dir(dir).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every file below `dir` with its bytes, or an empty list.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    if dir.exists() { crate::common::all_files(dir) } else { Vec::new() }
}

/// The names in `dir` that a build's temporary or set-aside folders carry.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".terrachunk-"))
        .collect()
}

/// A small DEM that builds in well under a second.
fn small_dem(dir: &Path) -> PathBuf {
    write_asc(dir, "dem.asc", 33, 33, |i, j| ((i * 7 + j * 3) % 11) as f64 + (i as f64 * 0.3).sin() * 5.0)
}

/// OUT holds a whole tileset: the marker, tileset.json, and every tile it
/// names. Returns tileset.json's bytes.
#[track_caller]
fn assert_whole_tileset(out: &Path) -> Vec<u8> {
    assert!(out.join(MARKER).is_file(), "{} has no marker", out.display());
    let bytes = std::fs::read(out.join("tileset.json")).unwrap();
    let doc: Value = serde_json::from_slice(&bytes).unwrap();
    let mut stack = vec![&doc["root"]];
    let mut tiles = 0;
    while let Some(t) = stack.pop() {
        if let Some(uri) = t["content"]["uri"].as_str() {
            let len = std::fs::metadata(out.join(uri)).map(|m| m.len()).unwrap_or(0);
            assert!(len > 0, "{}: {uri} is missing", out.display());
            tiles += 1;
        }
        stack.extend(t["children"].as_array().into_iter().flatten());
    }
    assert!(tiles > 0);
    bytes
}

#[test]
fn dot_and_parents_of_the_current_directory_are_never_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let b = tmp.path().join("x/a/b");
    std::fs::create_dir_all(&b).unwrap();
    std::fs::copy(fixture("mount_st_helens_30m.tif"), b.join("dem.tif")).unwrap();
    std::fs::write(b.join("notes.txt"), "keep").unwrap();
    std::fs::write(tmp.path().join("x/a/sibling.txt"), "keep").unwrap();
    let before = snapshot(tmp.path());
    let abs = b.to_str().unwrap().to_string();
    for (out, says) in [
        (".", "names no folder"),
        ("..", "names no folder"),
        ("../..", "names no folder"),
        ("./", "names no folder"),
        ("../b", "current directory"),
        (abs.as_str(), "current directory"),
        ("../../a", "current directory"),
        ("/", "names no folder"),
    ] {
        for force in [false, true] {
            let mut args = vec!["build", "dem.tif", "-o", out, "--texture", "none"];
            if force {
                args.push("--force");
            }
            let o = cli_in(&b, &args);
            assert_eq!(o.status.code(), Some(2), "-o {out}: {}", stderr(&o));
            assert!(stderr(&o).contains(says), "-o {out}: {}", stderr(&o));
            assert_eq!(snapshot(tmp.path()), before, "-o {out} changed files");
        }
    }
}

#[test]
fn force_replaces_only_a_tileset_this_tool_wrote() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("d");
    std::fs::create_dir(&d).unwrap();
    let dem = small_dem(&d);
    std::fs::write(d.join("notes.txt"), "keep").unwrap();
    let dem_s = dem.to_str().unwrap();
    let build = |out: &Path, force: bool| {
        let mut args = vec!["build", dem_s, "-o", out.to_str().unwrap(), "--texture", "none"];
        if force {
            args.push("--force");
        }
        cli(&args)
    };

    // A folder that holds the input, or one above it.
    for out in [d.clone(), tmp.path().to_path_buf()] {
        let before = snapshot(tmp.path());
        let o = build(&out, true);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("holds the input"), "{}", stderr(&o));
        assert_eq!(snapshot(tmp.path()), before);
    }

    // A folder of other files, with and without --force.
    let other = tmp.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("p.txt"), "precious").unwrap();
    let o = build(&other, false);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--force"), "{}", stderr(&o));
    let o = build(&other, true);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("not a tileset terrachunk wrote"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(other.join("p.txt")).unwrap(), "precious");
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));

    // A file and a symbolic link are not folders to replace.
    let file = tmp.path().join("file");
    std::fs::write(&file, "keep").unwrap();
    let link = tmp.path().join("link");
    #[cfg(unix)]
    std::os::unix::fs::symlink(&other, &link).unwrap();
    for out in [&file, &link] {
        let o = build(out, true);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("not a folder"), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep");

    // A tileset this tool wrote is replaced with --force only; so is an
    // empty folder.
    let out = tmp.path().join("out");
    assert!(build(&out, false).status.success());
    assert_whole_tileset(&out);
    let o = build(&out, false);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("already exists"), "{}", stderr(&o));
    std::fs::write(out.join("extra.txt"), "from the old one").unwrap();
    assert!(build(&out, true).status.success());
    assert_whole_tileset(&out);
    assert!(!out.join("extra.txt").exists(), "the old tileset was replaced whole");
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    assert!(build(&empty, true).status.success());
    assert_whole_tileset(&empty);
    verified_against(&out, std::slice::from_ref(&dem));
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
    assert_eq!(std::fs::read_to_string(d.join("notes.txt")).unwrap(), "keep");
}

#[test]
fn a_build_killed_at_any_moment_leaves_a_whole_tileset_at_out() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let out = tmp.path().join("out");
    let fresh = tmp.path().join("fresh");
    let args = |out: &Path, error: &str| {
        vec![
            "build".to_string(),
            dem.to_str().unwrap().into(),
            "-o".into(),
            out.to_str().unwrap().into(),
            "--texture".into(),
            "none".into(),
            "--max-error".into(),
            error.into(),
            "--force".into(),
        ]
    };
    let run = |a: Vec<String>| Command::new(env!("CARGO_BIN_EXE_terrachunk")).args(a).output().unwrap();
    assert!(run(args(&out, "4")).status.success());
    let old = assert_whole_tileset(&out);
    assert!(run(args(&fresh, "2")).status.success());
    let new = assert_whole_tileset(&fresh);
    // How long a whole replacing build takes here, to spread the kills over it.
    let t = std::time::Instant::now();
    assert!(run(args(&out, "2")).status.success());
    let whole = t.elapsed();
    assert_eq!(assert_whole_tileset(&out), new);
    for k in 0..12u32 {
        let error = if k % 2 == 0 { "4" } else { "2" };
        let mut child = Command::new(env!("CARGO_BIN_EXE_terrachunk"))
            .args(args(&out, error))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(whole.mul_f64(f64::from(k) / 10.0));
        let _ = child.kill();
        let _ = child.wait();
        let now = assert_whole_tileset(&out);
        assert!(now == old || now == new, "kill {k}: OUT is neither the old nor the new tileset");
    }
    // The next build removes what the killed ones left.
    assert!(run(args(&out, "4")).status.success());
    assert_eq!(assert_whole_tileset(&out), old);
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
}

#[test]
fn an_output_that_appears_during_the_build_is_left_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    // Appears as a folder of the user's files, with and without --force.
    for force in [false, true] {
        let claimed = OutDir::claim(&out, &[], force).unwrap();
        std::fs::write(claimed.tmp().join("tileset.json"), "{}").unwrap();
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("p.txt"), "precious").unwrap();
        let e = claimed.commit().unwrap_err();
        let expected = if force { "not a tileset" } else { "appeared while" };
        assert!(e.to_string().contains(expected), "{e}");
        assert_eq!(e.exit_code(), 2);
        assert_eq!(std::fs::read_to_string(out.join("p.txt")).unwrap(), "precious");
        assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
        std::fs::remove_dir_all(&out).unwrap();
    }
    // Appears as an empty folder: a plain rename would replace it.
    let claimed = OutDir::claim(&out, &[], false).unwrap();
    std::fs::create_dir(&out).unwrap();
    assert!(matches!(claimed.commit(), Err(OutDirError::Appeared(_))));
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0);

    // Through the command line: whenever the folder appears, the build
    // leaves it alone and exits 2.
    let dem = fixture("mount_st_helens_30m.tif");
    for delay_ms in [0, 50, 200] {
        let out = tmp.path().join(format!("race{delay_ms}"));
        let child = Command::new(env!("CARGO_BIN_EXE_terrachunk"))
            .args(["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", "none"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        let made = std::fs::create_dir(&out).and_then(|_| std::fs::write(out.join("p.txt"), "precious")).is_ok();
        let o = child.wait_with_output().unwrap();
        if made {
            assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
            assert_eq!(std::fs::read_to_string(out.join("p.txt")).unwrap(), "precious");
        } else {
            assert!(o.status.success(), "the build won the race: {}", stderr(&o));
        }
    }
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
}

#[test]
fn of_two_builds_into_one_output_exactly_one_wins() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let first = OutDir::claim(&out, &[], false).unwrap();
    let second = OutDir::claim(&out, &[], false).unwrap();
    std::fs::write(first.tmp().join("tileset.json"), "first").unwrap();
    std::fs::write(second.tmp().join("tileset.json"), "second").unwrap();
    first.commit().unwrap();
    assert!(matches!(second.commit(), Err(OutDirError::Appeared(_))));
    assert_eq!(std::fs::read_to_string(out.join("tileset.json")).unwrap(), "first");
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));

    let dem = fixture("mount_st_helens_30m.tif");
    let out = tmp.path().join("both");
    let spawn = || {
        Command::new(env!("CARGO_BIN_EXE_terrachunk"))
            .args(["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", "none"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let codes = [a.wait_with_output().unwrap(), b.wait_with_output().unwrap()].map(|o| o.status.code());
    let mut sorted = codes;
    sorted.sort();
    assert_eq!(sorted, [Some(0), Some(2)], "{codes:?}");
    assert_whole_tileset(&out);
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
}

/// The process id of a process that has ended.
fn dead_pid() -> u32 {
    let mut child = Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn the_next_build_removes_dead_builds_temporary_folders() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = small_dem(tmp.path());
    let out = tmp.path().join("out");
    let dead = dead_pid();
    let alive = std::process::id();
    let make = |name: String, owner: Option<&str>| {
        let p = tmp.path().join(name);
        std::fs::create_dir_all(p.join("tiles/0/0")).unwrap();
        std::fs::write(p.join("tiles/0/0/0.glb"), vec![0u8; 1000]).unwrap();
        if let Some(o) = owner {
            std::fs::write(p.join(".terrachunk-owner"), o).unwrap();
        }
        p
    };
    let dead_tmp = make(format!(".out.terrachunk-tmp-{dead}"), None);
    let live_tmp = make(format!(".out.terrachunk-tmp-{alive}"), None);
    let elsewhere = make(format!(".out.terrachunk-tmp-{alive}0"), Some("another-machine.invalid\n1\n"));
    let other_out = make(format!(".other.terrachunk-tmp-{dead}"), None);
    let not_ours = make(".out.terrachunk-tmp-x".into(), None);
    let dem_s = dem.to_str().unwrap();
    let o = cli(&["build", dem_s, "-o", out.to_str().unwrap(), "--texture", "none"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!dead_tmp.exists(), "a dead build's folder is removed");
    assert!(!elsewhere.exists(), "another machine's folder is removed");
    assert!(live_tmp.exists(), "a running build's folder is kept");
    assert!(other_out.exists() && not_ours.exists(), "only OUT's own siblings are touched");

    // A swap interrupted after the old tileset was set aside: the next
    // build puts it back, and replaces it only with --force.
    let old = assert_whole_tileset(&out);
    let aside = tmp.path().join(format!(".out.terrachunk-old-{dead}"));
    std::fs::rename(&out, &aside).unwrap();
    let o = cli(&["build", dem_s, "-o", out.to_str().unwrap(), "--texture", "none", "--max-error", "0.5"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(!aside.exists());
    assert_eq!(assert_whole_tileset(&out), old, "the set-aside tileset is back at OUT");
    let o = cli(&["build", dem_s, "-o", out.to_str().unwrap(), "--texture", "none", "--max-error", "0.5", "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_ne!(assert_whole_tileset(&out), old);
}

#[test]
fn thread_counts_beyond_the_limit_are_refused_without_a_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = small_dem(tmp.path());
    let out = tmp.path().join("out");
    let (d, o) = (dem.to_str().unwrap(), out.to_str().unwrap());
    for threads in ["1025", "2000", "18446744073709551615"] {
        crate::common::assert_bad_input(&["build", d, "-o", o, "--threads", threads], &out, "threads");
    }
    let cfg = tmp.path().join("threads.toml");
    std::fs::write(&cfg, "threads = 10000\n").unwrap();
    crate::common::assert_bad_input(&["build", d, "-o", o, "--config", cfg.to_str().unwrap()], &out, "threads");
    // A pool that cannot start (no address space for the threads' stacks)
    // is a clear error, not a panic.
    #[cfg(target_os = "linux")]
    {
        let exe = env!("CARGO_BIN_EXE_terrachunk");
        let o = Command::new("sh")
            .arg("-c")
            .arg(format!("ulimit -v 1500000 && exec '{exe}' build '{d}' -o '{o}' --texture none --threads 1024"))
            .output()
            .unwrap();
        let err = stderr(&o);
        assert!(!err.contains("panicked"), "{err}");
        if !o.status.success() {
            assert_eq!(o.status.code(), Some(2), "{err}");
            assert!(err.contains("threads"), "{err}");
            assert!(!out.exists());
        }
    }
}

#[test]
fn spacings_beyond_what_f32_positions_carry_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = small_dem(tmp.path());
    let out = tmp.path().join("out");
    let (d, o) = (dem.to_str().unwrap(), out.to_str().unwrap());
    for s in ["1e15", "1e20", "1e38", "1e-12", "1e300", "1e-300", "inf", "NaN", "0.0009", "100001", "1,1e15"] {
        crate::common::assert_bad_input(&["build", d, "-o", o, "--spacing", s], &out, "spacing");
    }
    let cfg = tmp.path().join("spacing.toml");
    for value in ["[1e15, 1.0]", "[1.0, 1e-12]", "[1e300, 1e300]"] {
        std::fs::write(&cfg, format!("spacing_m = {value}\n")).unwrap();
        crate::common::assert_bad_input(&["build", d, "-o", o, "--config", cfg.to_str().unwrap()], &out, "spacing");
    }
    // The grid's extent: 501 samples 100 km apart span 50 000 km.
    let wide = write_asc(tmp.path(), "wide.asc", 501, 2, |_, j| j as f64);
    crate::common::assert_bad_input(&["build", wide.to_str().unwrap(), "-o", o, "--spacing", "1e5"], &out, "spans");
    // The ends of the range build, verify and write finite numbers.
    for s in ["0.001", "1e5"] {
        let o = cli(&["build", d, "-o", o, "--spacing", s, "--texture", "none", "--force"]);
        assert!(o.status.success(), "--spacing {s}: {}", stderr(&o));
        verified(&out);
        crate::common::assert_finite_output(&out);
    }
}

#[test]
fn the_report_path_is_checked_before_the_build_and_written_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = small_dem(tmp.path());
    let out = tmp.path().join("out");
    let (d, o) = (dem.to_str().unwrap(), out.to_str().unwrap());
    let missing = tmp.path().join("missing/report.json");
    crate::common::assert_bad_input(&["build", d, "-o", o, "--report", missing.to_str().unwrap()], &out, "report");
    let folder = tmp.path().join("folder");
    std::fs::create_dir(&folder).unwrap();
    crate::common::assert_bad_input(&["build", d, "-o", o, "--report", folder.to_str().unwrap()], &out, "report");
    crate::common::assert_bad_input(&["build", d, "-o", o, "--report", d], &out, "input");
    #[cfg(unix)]
    crate::common::assert_bad_input(&["build", d, "-o", o, "--report", "/dev/full"], &out, "report");
    let report = tmp.path().join("report.json");
    let r = report.to_str().unwrap();
    let run = cli(&["build", d, "-o", o, "--texture", "none", "--report", r]);
    assert!(run.status.success(), "{}", stderr(&run));
    let json: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(json["grid"], serde_json::json!([33, 33]));
    assert!(leftovers(tmp.path()).is_empty(), "{:?}", leftovers(tmp.path()));
}

#[test]
fn bench_leaves_no_output_folder_on_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bench-out");
    let missing = tmp.path().join("missing.tif");
    let o = cli(&["bench", missing.to_str().unwrap(), "--out", out.to_str().unwrap(), "--runs", "1", "--warmup", "0"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(!out.exists(), "bench left {}", out.display());
}
