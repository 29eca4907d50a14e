//! Byte goldens: every output mode (textured f32, `quantize`, `meshopt`,
//! `meshopt-v1`) of one small real fixture, pinned by a fingerprint of each
//! written file in `tests/golden/`. A change to any byte of any mode fails
//! here; a deliberate one regenerates them with `TERRACHUNK_UPDATE_GOLDEN=1`
//! and says why in its commit.

use std::path::Path;

use serde_json::Value;
use terrachunk::config::{Compress, Config};
use terrachunk::pipeline::build;

use crate::common::{all_files, fixture, with_config};

/// FNV-1a, 64 bits: a dependency-free fingerprint.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// One line per file (path, length, fingerprint). The tileset's record of
/// where its input came from is left out: it names the input as found on
/// the machine that built it, which is not what these files pin.
fn fingerprints(out: &Path) -> String {
    let mut lines = Vec::new();
    for (p, mut bytes) in all_files(out) {
        if p.ends_with("tileset.json") {
            let mut j: Value = serde_json::from_slice(&bytes).unwrap();
            j["extras"]["terrachunk"].as_object_mut().unwrap().remove("source");
            bytes = serde_json::to_vec(&j).unwrap();
        }
        lines.push(format!("{} {} {:016x}", p.display(), bytes.len(), fnv1a(&bytes)));
    }
    lines.join("\n") + "\n"
}

#[test]
fn every_output_mode_matches_its_golden_fingerprints() {
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("salish_sea_topobathy_f32.tif");
    let mut changed = Vec::new();
    for (name, compress) in [
        ("textured", Compress::None),
        ("quantize", Compress::Quantize),
        ("meshopt", Compress::Meshopt),
        ("meshopt-v1", Compress::MeshoptV1),
    ] {
        let out = tmp.path().join(name);
        let cfg = Config { max_error_m: 2.0, leaf_cells: Some(32), threads: 2, compress, ..Config::default() };
        build(&with_config(&dem, &out, cfg)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let text = fingerprints(&out);
        assert!(text.lines().count() > 5, "{name}: {text}");
        let path = golden.join(format!("salish_sea_{name}.fnv"));
        if std::env::var_os("TERRACHUNK_UPDATE_GOLDEN").is_some() {
            std::fs::write(&path, &text).unwrap();
        }
        let want = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        if text != want {
            changed.push(format!("{name}:\n{text}"));
        }
    }
    assert!(changed.is_empty(), "output bytes changed:\n{}", changed.join("\n"));
}
