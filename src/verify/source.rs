//! The DEM a tileset was built from, found without trusting the tileset:
//! `extras.terrachunk.source` records each file's name, length and SHA-256,
//! never a path. Without `--dem`, each name is looked for in the tileset's
//! folder, then in the folder that holds it (where `build dem.tif -o out`
//! leaves it); a candidate is used only if it is a regular file (no link,
//! FIFO or device) of the recorded length whose content hashes to the
//! recorded value, so a tileset cannot make `verify` open or print a file
//! of its choosing. When no candidate matches, `verify` stops with an error
//! that says what it found and asks for `--dem`: checking the error bounds
//! against another DEM, or not at all, could report OK on a wrong tileset.

use std::path::{Component, Path, PathBuf};

use super::{VerifyError, file_err};
use crate::output::tileset::{SourceFile, sha256_of};

/// The files `sources` name, found beside the tileset at `dir` (see the
/// module comment); `index` is `tileset.json`, which errors name.
pub(super) fn locate(dir: &Path, index: &Path, sources: &[SourceFile]) -> Result<Vec<PathBuf>, VerifyError> {
    if sources.is_empty() {
        return Err(file_err(index, "extras.terrachunk.source names no DEM; give it with --dem"));
    }
    sources.iter().map(|s| locate_one(dir, index, s)).collect()
}

pub(super) fn locate_one(dir: &Path, index: &Path, s: &SourceFile) -> Result<PathBuf, VerifyError> {
    let mut parts = Path::new(&s.name).components();
    let plain = matches!((parts.next(), parts.next()), (Some(Component::Normal(_)), None))
        && !s.name.contains(['/', '\\', '\0']);
    let digest_ok = s.sha256.len() == 64 && s.sha256.bytes().all(|b| b.is_ascii_hexdigit());
    if !plain || !digest_ok {
        return Err(file_err(
            index,
            format!(
                "extras.terrachunk.source holds {:?} with hash {:?}: not a plain file name and a SHA-256; \
                 give the DEM with --dem",
                s.name, s.sha256
            ),
        ));
    }
    let mut seen = Vec::new();
    for folder in [dir.to_path_buf(), dir.join("..")] {
        let path = folder.join(&s.name);
        match matches(&path, s) {
            Ok(()) => return Ok(path),
            Err(Some(why)) => seen.push(format!("{}: {why}", path.display())),
            Err(None) => {}
        }
    }
    let found = if seen.is_empty() { "not found there".to_string() } else { seen.join("; ") };
    Err(file_err(
        index,
        format!(
            "the file it was built from, {} ({} bytes, SHA-256 {}), is looked for in the tileset's folder \
             and the one above it: {found}; give it with --dem (the DEM) or --geoid (a geoid model)",
            s.name, s.bytes, s.sha256
        ),
    ))
}

/// Whether `path` is the recorded file: `Err(None)` when there is nothing
/// there, `Err(Some(why))` when what is there is not it.
fn matches(path: &Path, s: &SourceFile) -> Result<(), Option<String>> {
    use std::io::Read;
    let meta = std::fs::symlink_metadata(path).map_err(|_| None)?;
    if meta.file_type().is_symlink() {
        return Err(Some("is a symbolic link (give it with --dem to use it)".into()));
    }
    if !meta.is_file() {
        return Err(Some("is not a regular file".into()));
    }
    if meta.len() != s.bytes {
        return Err(Some(format!("is {} bytes, not {}", meta.len(), s.bytes)));
    }
    let file = std::fs::File::open(path).map_err(|e| Some(format!("cannot read: {e}")))?;
    let opened = file.metadata().map_err(|e| Some(format!("cannot read: {e}")))?;
    if !opened.is_file() || opened.len() != s.bytes {
        return Err(Some("changed while it was being read".into()));
    }
    let (_, sha256) = sha256_of(file.take(s.bytes)).map_err(|e| Some(format!("cannot read: {e}")))?;
    if !sha256.eq_ignore_ascii_case(&s.sha256) {
        return Err(Some(format!("its content differs (SHA-256 {sha256})")));
    }
    Ok(())
}
