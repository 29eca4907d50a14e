//! Helpers the test modules share: fixtures, building, verifying, the
//! Khronos validator, tiny DEMs, and reading a tree of output files.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use terrachunk::config::Config;
use terrachunk::pipeline::{BuildOptions, Report, build};
use terrachunk::texture::TextureSource;
use terrachunk::verify::{VerifyReport, verify};

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

pub fn options(dem: &Path, out: &Path, max_error_m: f64, threads: usize) -> BuildOptions {
    BuildOptions {
        inputs: vec![dem.to_path_buf()],
        out: out.to_path_buf(),
        force: false,
        config: Config { max_error_m, threads, ..Config::default() },
        texture: TextureSource::Generated,
        progress: false,
    }
}

pub fn build_ok(dem: &Path, max_error_m: f64) -> (tempfile::TempDir, PathBuf, Report) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let report = build(&options(dem, &out, max_error_m, 0)).unwrap_or_else(|e| panic!("{}: {e}", dem.display()));
    (tmp, out, report)
}

pub fn verified(out: &Path) -> VerifyReport {
    let r = verify(out, None).unwrap();
    assert!(r.failures.is_empty(), "verify failed for {}:\n{}", out.display(), r.failures.join("\n"));
    r
}

/// Runs the Khronos glTF validator (npm `gltf-validator`) over every .glb.
pub fn khronos_validate(out: &Path) -> Value {
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

pub fn tileset(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("tileset.json")).unwrap()).unwrap()
}

pub fn write_asc(dir: &Path, name: &str, w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> PathBuf {
    let mut s = format!("ncols {w}\nnrows {h}\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n");
    for i in 0..h {
        let row: Vec<String> = (0..w).map(|j| f(i, j).to_string()).collect();
        s += &row.join(" ");
        s += "\n";
    }
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

pub fn all_files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
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

/// Rewrites a .glb in place: `edit` may change its JSON and its binary chunk
/// (a test that tampers with a file to see verify catch it).
pub fn rewrite_glb(path: &Path, edit: impl FnOnce(&mut Value, &mut Vec<u8>)) {
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
