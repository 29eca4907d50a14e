//! Helpers every test module shares: fixtures, building into a temporary
//! directory, the independent checks (`verify`, the Khronos validator, no
//! NaN or infinity anywhere in the output), small DEM writers and the
//! command line.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use terrachunk::config::Config;
use terrachunk::pipeline::{BuildOptions, Report, build};
use terrachunk::texture::TextureSource;
use terrachunk::verify::{VerifyReport, verify};

pub(crate) fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

pub(crate) fn options(dem: &Path, out: &Path, max_error_m: f64, threads: usize) -> BuildOptions {
    with_config(dem, out, Config { max_error_m, threads, ..Config::default() })
}

pub(crate) fn with_config(dem: &Path, out: &Path, config: Config) -> BuildOptions {
    BuildOptions {
        inputs: vec![dem.to_path_buf()],
        out: out.to_path_buf(),
        force: false,
        config,
        texture: TextureSource::Generated,
        progress: false,
        geoid: None,
    }
}

pub(crate) fn build_ok(dem: &Path, max_error_m: f64) -> (tempfile::TempDir, PathBuf, Report) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let report = build(&options(dem, &out, max_error_m, 0)).unwrap_or_else(|e| panic!("{}: {e}", dem.display()));
    (tmp, out, report)
}

/// `verify` finds nothing wrong: every level within its δ, leaves within
/// `max_error_m`, every valid sample covered, borders shared, morph targets
/// on the parent surface.
#[track_caller]
pub(crate) fn verified(out: &Path) -> VerifyReport {
    verified_against(out, &dem_of(out))
}

/// [`verified`] against the DEM files `dem`.
#[track_caller]
pub(crate) fn verified_against(out: &Path, dem: &[PathBuf]) -> VerifyReport {
    let r = verify(out, Some(dem)).unwrap();
    assert!(r.failures.is_empty(), "verify failed for {}:\n{}", out.display(), r.failures.join("\n"));
    r
}

/// The DEM files a tileset names (`extras.terrachunk.source`), found
/// where the tests keep them: beside the tileset or the folder above it
/// (where `verify` itself looks), or among the fixtures, which tests build
/// from in place.
#[track_caller]
pub(crate) fn dem_of(out: &Path) -> Vec<PathBuf> {
    let ts = tileset(out);
    let names: Vec<&str> = ts["extras"]["terrachunk"]["source"]
        .as_array()
        .expect("extras.terrachunk.source")
        .iter()
        .map(|s| s["name"].as_str().expect("a source name"))
        .collect();
    names
        .iter()
        .map(|name| {
            [out.join(name), out.join("..").join(name), fixture(name), fixture("hgt_mosaic").join(name)]
                .into_iter()
                .find(|p| p.is_file())
                .unwrap_or_else(|| panic!("{}: its DEM {name} is nowhere the tests keep DEMs", out.display()))
        })
        .collect()
}

/// Runs the Khronos glTF validator (npm `gltf-validator`) over every .glb.
#[track_caller]
pub(crate) fn khronos_validate(out: &Path) -> Value {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    assert!(
        root.join("node_modules/gltf-validator").exists(),
        "the Khronos glTF validator is not installed: run `npm ci` in {}",
        root.display()
    );
    let o = Command::new("node").arg(root.join("tests/tools/validate_gltf.js")).arg(out).output().expect("node runs");
    assert!(o.status.success(), "validator failed: {}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["errors"], 0, "glTF validator errors: {}", v["messages"]);
    v
}

pub(crate) fn tileset(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("tileset.json")).unwrap()).unwrap()
}

/// Every number a client reads is finite: in each .glb the node translation
/// and every POSITION, NORMAL and morph-target value; in tileset.json every
/// bounding box, geometric error and the numeric extras. (serde_json writes
/// NaN and infinity as `null`, so a missing number is what a NaN looks like
/// there.) Returns the number of .glb files checked.
#[track_caller]
pub(crate) fn assert_finite_output(out: &Path) -> usize {
    let mut glbs = 0;
    for (path, bytes) in all_files(out).into_iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")) {
        glbs += 1;
        let p = path.display();
        let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap_or_else(|e| panic!("{p}: {e}"));
        let node = doc.nodes().next().unwrap_or_else(|| panic!("{p}: no node"));
        let (t, _, _) = node.transform().decomposed();
        assert!(t.iter().all(|v| v.is_finite()), "{p}: translation {t:?}");
        let glb = gltf::Glb::from_slice(&bytes).unwrap();
        let j: Value = serde_json::from_slice(&glb.json).unwrap();
        for (a, v) in j["nodes"][0]["translation"].as_array().unwrap().iter().enumerate() {
            assert!(v.is_f64() || v.is_i64() || v.is_u64(), "{p}: translation[{a}] is {v}");
        }
        for mesh in doc.meshes() {
            for prim in mesh.primitives() {
                let reader = prim.reader(|b| Some(&buffers[b.index()]));
                let pos: Vec<[f32; 3]> =
                    reader.read_positions().unwrap_or_else(|| panic!("{p}: no POSITION")).collect();
                let nrm: Vec<[f32; 3]> = reader.read_normals().unwrap_or_else(|| panic!("{p}: no NORMAL")).collect();
                assert!(!pos.is_empty(), "{p}: a primitive without vertices");
                assert!(pos.iter().flatten().all(|v| v.is_finite()), "{p}: non-finite POSITION");
                assert!(nrm.iter().flatten().all(|v| v.is_finite()), "{p}: non-finite NORMAL");
                for n in &nrm {
                    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                    assert!((len - 1.0).abs() < 1e-3, "{p}: NORMAL {n:?} is not unit length");
                }
                for (dpos, _, _) in reader.read_morph_targets() {
                    let d: Vec<[f32; 3]> =
                        dpos.unwrap_or_else(|| panic!("{p}: morph target without POSITION")).collect();
                    assert!(d.iter().flatten().all(|v| v.is_finite()), "{p}: non-finite morph target");
                }
            }
        }
    }
    let ts = tileset(out);
    let num = |v: &Value, what: &str| {
        assert!(v.as_f64().is_some_and(f64::is_finite), "tileset.json: {what} is {v}, not a finite number");
    };
    let ex = &ts["extras"]["terrachunk"];
    for key in ["max_error_m", "tau_max_px", "vertical_scale"] {
        num(&ex[key], key);
    }
    for (k, v) in ex["spacing_m"].as_array().unwrap().iter().enumerate() {
        num(v, &format!("spacing_m[{k}]"));
    }
    for (k, v) in ex["delta_m"].as_array().unwrap().iter().enumerate() {
        num(v, &format!("delta_m[{k}]"));
    }
    let mut stack = vec![&ts["root"]];
    let mut tiles = 0;
    while let Some(t) = stack.pop() {
        tiles += 1;
        num(&t["geometricError"], "geometricError");
        let bx = t["boundingVolume"]["box"].as_array().expect("a box");
        assert_eq!(bx.len(), 12);
        for v in bx {
            num(v, "boundingVolume.box");
        }
        if let Some(te) = t["extras"]["terrachunk"].as_object() {
            for (k, v) in te {
                num(v, k);
            }
        }
        if let Some(kids) = t["children"].as_array() {
            stack.extend(kids);
        }
    }
    assert!(tiles > 0);
    glbs
}

/// An ESRI ASCII grid of `w × h` samples 10 m apart; `-9999` is nodata.
pub(crate) fn write_asc(dir: &Path, name: &str, w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> PathBuf {
    write_asc_spaced(dir, name, w, h, 10.0, f)
}

/// As [`write_asc`], with the cell size in metres. Values are written in
/// Rust's shortest round-trip form (`NaN`, `inf` included).
pub(crate) fn write_asc_spaced(
    dir: &Path,
    name: &str,
    w: usize,
    h: usize,
    cellsize: f64,
    f: impl Fn(usize, usize) -> f64,
) -> PathBuf {
    let mut s = format!("ncols {w}\nnrows {h}\nxllcorner 0\nyllcorner 0\ncellsize {cellsize}\nNODATA_value -9999\n");
    for i in 0..h {
        let row: Vec<String> = (0..w).map(|j| f(i, j).to_string()).collect();
        s += &row.join(" ");
        s += "\n";
    }
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

pub(crate) fn all_files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

pub(crate) fn cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_terrachunk")).args(args).output().unwrap()
}

/// The command exits 2, says `says` on stderr, and leaves neither `out`
/// nor a temporary directory behind.
#[track_caller]
pub(crate) fn assert_bad_input(args: &[&str], out: &Path, says: &str) {
    let o = cli(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(says), "{args:?}: expected {says:?} in {err}");
    assert!(!out.exists(), "{args:?} left {}", out.display());
    let parent = out.parent().unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(parent)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("terrachunk-tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary directory left behind");
}

/// Rewrites a .glb in place: `edit` may change its JSON and its binary chunk
/// (a test that tampers with a file to see verify catch it).
pub(crate) fn rewrite_glb(path: &Path, edit: impl FnOnce(&mut Value, &mut Vec<u8>)) {
    let bytes = std::fs::read(path).unwrap();
    let glb = gltf::Glb::from_slice(&bytes).unwrap();
    let mut j: Value = serde_json::from_slice(&glb.json).unwrap();
    let mut bin = glb.bin.map(|b| b.into_owned()).unwrap_or_default();
    edit(&mut j, &mut bin);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    j["buffers"][0]["byteLength"] = serde_json::json!(bin.len());
    let mut json = serde_json::to_vec(&j).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    std::fs::write(path, out).unwrap();
}

/// Cut and flipped copies of a file's bytes, the same on every run
/// (xorshift from a fixed seed): what the loaders' never-panic tests feed
/// them. Every third copy is cut short; the others have four bytes flipped,
/// in every other copy within the first 512 bytes, where sizes live.
pub(crate) struct Mangler(u64);

impl Mangler {
    pub(crate) fn new(seed: u64) -> Self {
        Mangler(seed)
    }

    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Copy `k` of `bytes`.
    pub(crate) fn mangle(&mut self, bytes: &[u8], k: usize) -> Vec<u8> {
        let mut b = bytes.to_vec();
        if k.is_multiple_of(3) {
            b.truncate((self.next() as usize) % bytes.len());
        } else {
            for _ in 0..4 {
                let span = if k.is_multiple_of(2) { bytes.len().min(512) } else { bytes.len() };
                let i = (self.next() as usize) % span;
                b[i] ^= (self.next() as u8) | 1;
            }
        }
        b
    }
}

/// How many mangled copies of each file the never-panic tests load:
/// `TERRACHUNK_FUZZ_ROUNDS`, default 24.
pub(crate) fn mangle_rounds() -> usize {
    std::env::var("TERRACHUNK_FUZZ_ROUNDS").ok().and_then(|v| v.parse().ok()).unwrap_or(24)
}
