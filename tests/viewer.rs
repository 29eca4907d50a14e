//! `terrachunk view`: the main binary hands over to the `terrachunk-view`
//! binary (the `viewer/` crate); without it, it says how to get it. (The
//! viewer's own tests are in `viewer/tests/gpu.rs`.)

use std::process::Command;

#[test]
fn view_without_the_viewer_binary_says_how_to_get_it() {
    let tmp = tempfile::tempdir().unwrap();
    let exe = tmp.path().join(format!("terrachunk{}", std::env::consts::EXE_SUFFIX));
    std::fs::copy(env!("CARGO_BIN_EXE_terrachunk"), &exe).unwrap();
    // Nothing beside the copy, and nothing on PATH.
    let o = Command::new(&exe).args(["view", "out"]).env("PATH", tmp.path()).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("needs the `terrachunk-view"), "{err}");
    assert!(err.contains("cargo build -p terrachunk-view"), "{err}");
}
