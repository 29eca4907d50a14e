//! Sharded builds: a plan's jobs, run in any order and at any thread count,
//! then merged, give the single-process build's bytes; jobs are idempotent
//! and atomic; a merge before every job finished, a changed input and a
//! foreign manifest are refused.

use std::path::{Path, PathBuf};

use terrachunk::config::Config;
use terrachunk::pipeline::{BuildOptions, build};
use terrachunk::shard::{self, ShardError, TreePart};

use crate::common::{all_files, cli, fixture, verified, with_config, write_asc};

/// Options for a small build whose tree has several levels below the shards.
fn opts(dem: &Path, out: &Path, threads: usize) -> BuildOptions {
    with_config(dem, out, Config { max_error_m: 2.0, threads, leaf_cells: Some(32), ..Config::default() })
}

/// Plans `shards` jobs into `work` and runs every job, last first, each on
/// its own thread count.
fn sharded(dem: &Path, out: &Path, work: &Path, shards: usize) -> PathBuf {
    let manifest = shard::plan(&opts(dem, out, 1), shards, work).unwrap();
    let m = shard::read_manifest(&manifest).unwrap();
    for job in (0..m.jobs.len()).rev() {
        let r = shard::run_job(&manifest, job, Some(1 + job % 2)).unwrap();
        assert!(!r.already_done);
    }
    manifest
}

#[test]
fn sharded_build_is_byte_identical_to_the_single_process_build() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let whole = tmp.path().join("whole");
    build(&opts(&dem, &whole, 2)).unwrap();
    for shards in [1, 3, 16] {
        let out = tmp.path().join(format!("sharded-{shards}"));
        let manifest = sharded(&dem, &out, &tmp.path().join(format!("work-{shards}")), shards);
        let m = shard::read_manifest(&manifest).unwrap();
        assert_eq!(m.jobs.len(), 1 + shards, "{shards} shards");
        assert!(
            (shards == 1 || m.shard_level >= 1) && matches!(m.jobs[0].part(), TreePart::Above(l) if l == m.shard_level)
        );
        assert!(!out.exists(), "nothing at OUT before the merge");
        let merged = shard::merge(&manifest).unwrap();
        let (a, b) = (all_files(&whole), all_files(&out));
        assert_eq!(a.len(), b.len(), "{shards} shards: file count");
        // The chunks, tileset.json and the marker.
        assert_eq!(merged.chunks + 2, b.len());
        for ((pa, ba), (pb, bb)) in a.iter().zip(&b) {
            assert_eq!(pa, pb);
            assert!(ba == bb, "{shards} shards: {} differs from the single-process build", pa.display());
        }
    }
    verified(&tmp.path().join("sharded-3"));
}

/// With the index split into external tilesets, the merge splits it as the
/// whole build does: the same files, byte for byte.
#[test]
fn a_sharded_build_splits_its_index_as_the_single_process_build_does() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let split = |out: &Path, threads: usize| {
        let mut o = opts(&dem, out, threads);
        o.config.index_tiles = 8;
        o
    };
    let whole = tmp.path().join("whole");
    let report = build(&split(&whole, 2)).unwrap();
    assert!(report.index_files > 2, "{} index files", report.index_files);
    let out = tmp.path().join("sharded");
    let manifest = shard::plan(&split(&out, 1), 3, &tmp.path().join("work")).unwrap();
    for job in 0..shard::read_manifest(&manifest).unwrap().jobs.len() {
        shard::run_job(&manifest, job, Some(1)).unwrap();
    }
    let merged = shard::merge(&manifest).unwrap();
    assert_eq!(merged.index_files, report.index_files);
    assert!(all_files(&whole) == all_files(&out), "the sharded index differs from the whole build's");
    verified(&out);
}

/// The tree's top is a forest (`root_cells`) and the DEM has a corner of
/// nodata: a shard holding only nodata writes nothing, and the others still
/// give the single-process bytes.
#[test]
fn sharded_forest_with_empty_shards_matches_the_single_process_build() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "corner.asc", 97, 81, |i, j| {
        if i < 60 && j < 60 { -9999.0 } else { 100.0 + 30.0 * ((i as f64) * 0.21).sin() * ((j as f64) * 0.13).cos() }
    });
    let config = Config { max_error_m: 1.0, root_cells: Some(48), leaf_cells: Some(16), ..Config::default() };
    let whole = tmp.path().join("whole");
    build(&with_config(&dem, &whole, config.clone())).unwrap();
    let out = tmp.path().join("out");
    let work = tmp.path().join("work");
    let manifest = shard::plan(&with_config(&dem, &out, config), 8, &work).unwrap();
    let m = shard::read_manifest(&manifest).unwrap();
    let mut empty = 0;
    for job in 0..m.jobs.len() {
        let r = shard::run_job(&manifest, job, None).unwrap();
        empty += usize::from(job > 0 && r.chunks == 0);
    }
    assert!(empty >= 1, "the nodata corner makes an empty shard");
    shard::merge(&manifest).unwrap();
    assert!(all_files(&whole) == all_files(&out), "forest: sharded bytes differ");
}

/// A job run again finds itself done; a killed run's temporary folder is
/// ignored, and the folder a job finishes appears whole or not at all.
#[test]
fn jobs_are_idempotent_and_a_killed_runs_leftovers_change_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let (out, work) = (tmp.path().join("out"), tmp.path().join("work"));
    let manifest = shard::plan(&opts(&dem, &out, 2), 2, &work).unwrap();
    // What a run killed midway leaves: a temporary folder with some chunks.
    let killed = work.join(".job-1.tmp-4000000");
    std::fs::create_dir_all(killed.join("tiles/1/0")).unwrap();
    std::fs::write(killed.join("tiles/1/0/0.glb"), b"half a chunk").unwrap();
    for job in 0..3 {
        assert!(!work.join(format!("job-{job}")).exists());
        shard::run_job(&manifest, job, None).unwrap();
        assert!(work.join(format!("job-{job}/job.json")).exists());
    }
    // The chunks, not job.json, whose report holds the run's times.
    let first = all_files(&work.join("job-1/tiles"));
    let again = shard::run_job(&manifest, 1, None).unwrap();
    assert!(again.already_done && again.chunks == 0);
    assert!(first == all_files(&work.join("job-1/tiles")));
    // A job folder whose result is gone (torn by hand) is built again, the same.
    std::fs::remove_file(work.join("job-1/job.json")).unwrap();
    assert!(!shard::run_job(&manifest, 1, None).unwrap().already_done);
    assert!(first == all_files(&work.join("job-1/tiles")));
    shard::merge(&manifest).unwrap();
    verified(&out);
}

#[test]
fn merge_before_every_job_finished_is_refused_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let (out, work) = (tmp.path().join("out"), tmp.path().join("work"));
    let manifest = shard::plan(&opts(&dem, &out, 2), 2, &work).unwrap();
    shard::run_job(&manifest, 0, None).unwrap();
    shard::run_job(&manifest, 2, None).unwrap();
    let e = shard::merge(&manifest).unwrap_err();
    assert!(matches!(e, ShardError::Unfinished { job: 1, .. }), "{e}");
    assert!(e.to_string().contains("--job 1"), "{e}");
    assert!(!out.exists());
    let o = cli(&["merge", manifest.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!out.exists());
    let stray: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("terrachunk-tmp"))
        .collect();
    assert!(stray.is_empty(), "a refused merge left a temporary folder");
}

#[test]
fn a_job_refuses_an_input_changed_since_the_plan() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "hill.asc", 40, 40, |i, j| (i * j) as f64 * 0.1);
    let (out, work) = (tmp.path().join("out"), tmp.path().join("work"));
    let manifest = shard::plan(&opts(&dem, &out, 1), 2, &work).unwrap();
    write_asc(tmp.path(), "hill.asc", 40, 40, |i, j| (i * j) as f64 * 0.2);
    let o = cli(&["build", "--manifest", manifest.to_str().unwrap(), "--job", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("changed since the plan"), "{err}");
    assert!(!work.join("job-1").exists());
}

#[test]
fn a_manifest_that_is_not_this_versions_is_refused_with_its_name() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "hill.asc", 40, 40, |i, j| (i + j) as f64);
    let (out, work) = (tmp.path().join("out"), tmp.path().join("work"));
    let manifest = shard::plan(&opts(&dem, &out, 1), 2, &work).unwrap();
    let text = std::fs::read_to_string(&manifest).unwrap();
    let cases = [
        ("not json", "not JSON".to_string()),
        (&*text.replacen("\"version\": 1", "\"version\": 99", 1), "manifest version 99".to_string()),
        (&*text.replacen("terrachunk ", "terrachunk 0.0.0-other ", 1), "plan again".to_string()),
    ];
    for (body, says) in cases {
        std::fs::write(&manifest, body).unwrap();
        for args in [
            vec!["build", "--manifest", manifest.to_str().unwrap(), "--job", "0"],
            vec!["merge", manifest.to_str().unwrap()],
        ] {
            let o = cli(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
            assert!(err.contains(&says) && err.contains("manifest.json"), "{args:?}: {err}");
        }
    }
    std::fs::write(&manifest, &text).unwrap();
    let o = cli(&["build", "--manifest", manifest.to_str().unwrap(), "--job", "7"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no such job"));
}

/// The command line: plan, jobs and merge as a user runs them.
#[test]
fn plan_jobs_and_merge_on_the_command_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    let (whole, out) = (tmp.path().join("whole"), tmp.path().join("out"));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let common = ["--max-error", "2", "--leaf-cells", "32", "--texture", "none"];
    let o = cli(&[&["build", &s(&dem), "-o", &s(&whole)][..], &common].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = cli(&[&["plan", "--shards", "4", &s(&dem), "-o", &s(&out)][..], &common].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let manifest = tmp.path().join("out.shards/manifest.json");
    assert!(String::from_utf8_lossy(&o.stdout).contains("5 jobs"), "{}", String::from_utf8_lossy(&o.stdout));
    for job in 0..5 {
        let o = cli(&["build", "--manifest", &s(&manifest), "--job", &job.to_string(), "--threads", "1"]);
        assert!(o.status.success(), "job {job}: {}", String::from_utf8_lossy(&o.stderr));
    }
    let o = cli(&["merge", &s(&manifest)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(all_files(&whole) == all_files(&out));
    // A second plan into the same folders needs --force, as a build does.
    let o = cli(&[&["plan", "--shards", "4", &s(&dem), "-o", &s(&out)][..], &common].concat());
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("already exists"));
    // --force replaces a work folder a plan made, never another folder.
    let mine = tmp.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), b"keep").unwrap();
    let o =
        cli(&[&["plan", "--shards", "2", "--work", &s(&mine), &s(&dem), "-o", &s(&out), "--force"][..], &common]
            .concat());
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a terrachunk work folder"));
    assert!(mine.join("notes.txt").exists());
}
