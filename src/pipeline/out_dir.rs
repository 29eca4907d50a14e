//! Where a build writes (DESIGN.md, promise 7): OUT is claimed before the
//! build, filled in a temporary sibling, and put in place at the end by one
//! rename, so that OUT holds the old tileset or the new one, whole, at every
//! moment, and nothing else is ever replaced.
//!
//! - OUT must be a folder name of its own: never `.`, `..`, a root, the
//!   current directory or a folder above it, nor a folder that holds an
//!   input.
//! - An existing OUT is replaced only with `force`, and only if it holds
//!   [`MARKER`] (a tileset this tool wrote) or is empty.
//! - The temporary folder, `.NAME.terrachunk-tmp-PID`, is made in OUT's
//!   canonical parent, so the final rename never crosses a file system.
//! - The final rename is exclusive: a new OUT is moved in with
//!   `RENAME_NOREPLACE`, so an OUT that appeared during the build (another
//!   build, another program) is never replaced without `force`, and of two
//!   builds into one OUT exactly one wins; an old tileset is swapped with
//!   the new one by `RENAME_EXCHANGE`, then deleted from the temporary name.
//! - A build killed at any moment leaves its temporary folder behind (the
//!   new tileset, or the old one being deleted); the next build into the
//!   same place removes those whose process is gone, and where OUT itself
//!   is missing after a swap interrupted half way (`.NAME.terrachunk-old-PID`,
//!   on systems without `RENAME_EXCHANGE`) it moves the old tileset back.

use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};

/// The file that marks a folder as a tileset this tool wrote, in its root.
pub const MARKER: &str = ".terrachunk";

/// [`MARKER`]'s contents: a format tag, the same in every tileset so that
/// output bytes do not depend on when or where they were built.
pub const MARKER_TEXT: &str = "terrachunk-tileset 1\n";

/// The file in a temporary folder that says which build owns it:
/// `HOST\nPID\n`. It is removed before the folder becomes OUT.
const OWNER: &str = ".terrachunk-owner";

/// Why the output folder cannot be used. Every case leaves the file system
/// as it was.
#[derive(Debug, thiserror::Error)]
pub enum OutDirError {
    /// `.`, `..` or a root: a path with no folder name of its own.
    #[error(
        "{0}: names no folder of its own; give the tileset a new folder name (e.g. `-o tiles`), \
         never `.` or `..`"
    )]
    NoName(PathBuf),
    /// The folder OUT would be made in cannot be found.
    #[error("{path}: the folder to write the tileset into cannot be used: {source}")]
    Parent {
        /// OUT's parent as given.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// OUT is the current directory or one above it.
    #[error("{0}: is the current directory or a folder above it; refusing to replace it")]
    HoldsCurrentDir(PathBuf),
    /// OUT holds one of the build's inputs.
    #[error("{out}: holds the input {input}; write the tileset to another folder")]
    HoldsInput {
        /// OUT as given.
        out: PathBuf,
        /// The input inside it.
        input: PathBuf,
    },
    /// OUT exists and is a file, a symbolic link or something else than a folder.
    #[error("{0}: exists and is not a folder (a file or a symbolic link); refusing to replace it")]
    NotAFolder(PathBuf),
    /// OUT exists and `force` was not given.
    #[error("{0}: already exists (use --force to replace a tileset terrachunk wrote)")]
    Exists(PathBuf),
    /// OUT exists, `force` was given, but it is not a tileset this tool wrote.
    #[error(
        "{0}: is not a tileset terrachunk wrote (it has no `.terrachunk` file), so --force does not \
         replace it; move it away or choose another output folder"
    )]
    NotATileset(PathBuf),
    /// OUT did not exist when the build started and does now.
    #[error("{0}: appeared while the tileset was being built; it was left as it is and nothing was written")]
    Appeared(PathBuf),
    /// A file operation failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

impl OutDirError {
    /// Process exit code: 2 where nothing was written (every refusal), 1
    /// where a file operation failed.
    pub fn exit_code(&self) -> i32 {
        match self {
            OutDirError::Io { .. } => 1,
            _ => 2,
        }
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutDirError + '_ {
    move |source| OutDirError::Io { path: path.to_path_buf(), source }
}

/// An output folder claimed for one build: the checks passed and the
/// temporary folder exists. Dropped without [`OutDir::commit`], it removes
/// the temporary folder, so a failed build leaves nothing behind.
#[derive(Debug)]
pub struct OutDir {
    /// OUT as the user gave it (for messages).
    given: PathBuf,
    /// OUT in its canonical parent.
    path: PathBuf,
    /// The temporary folder beside it.
    tmp: PathBuf,
    force: bool,
    done: bool,
    /// Folders above OUT this claim made, outermost first.
    created: Vec<PathBuf>,
}

impl OutDir {
    /// Checks `out` against the rules of this module (`inputs` are the
    /// files the build reads), cleans up after dead builds into the same
    /// place, and creates the temporary folder.
    pub fn claim(out: &Path, inputs: &[&Path], force: bool) -> Result<OutDir, OutDirError> {
        let name = out.file_name().ok_or_else(|| OutDirError::NoName(out.into()))?;
        let given_parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let parent_error = |source| OutDirError::Parent { path: given_parent.into(), source };
        // Missing folders above OUT are made, and removed again if the build fails.
        let created = make_parents(given_parent).map_err(parent_error)?;
        let mut claimed =
            OutDir { given: out.into(), path: PathBuf::new(), tmp: PathBuf::new(), force, done: false, created };
        let parent = std::fs::canonicalize(given_parent).map_err(parent_error)?;
        if !parent.is_dir() {
            return Err(parent_error(std::io::Error::new(std::io::ErrorKind::NotADirectory, "not a folder")));
        }
        let path = parent.join(name);
        if let Ok(cwd) = std::env::current_dir().and_then(std::fs::canonicalize)
            && cwd.starts_with(&path)
        {
            return Err(OutDirError::HoldsCurrentDir(out.into()));
        }
        for input in inputs {
            if let Ok(c) = std::fs::canonicalize(input)
                && c.starts_with(&path)
            {
                return Err(OutDirError::HoldsInput { out: out.into(), input: input.to_path_buf() });
            }
        }
        recover(&parent, name, &path)?;
        if let Some(existing) = existing(&path, out)? {
            if !force {
                return Err(OutDirError::Exists(out.into()));
            }
            if existing == Existing::Other {
                return Err(OutDirError::NotATileset(out.into()));
            }
        }
        let tmp = parent.join(sibling(name, "tmp", &build_tag()));
        std::fs::create_dir(&tmp).map_err(io(&tmp))?;
        (claimed.path, claimed.tmp) = (path, tmp);
        std::fs::write(claimed.tmp.join(OWNER), format!("{}\n{}\n", host(), std::process::id()))
            .map_err(io(&claimed.tmp))?;
        Ok(claimed)
    }

    /// The temporary folder the build writes into.
    pub fn tmp(&self) -> &Path {
        &self.tmp
    }

    /// OUT, in its canonical parent.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Marks the temporary folder as a whole tileset and puts it at OUT:
    /// moved in where OUT is missing, swapped with the tileset there where
    /// `force` allows replacing it (which is then deleted). An OUT that
    /// appeared during the build, or that is no longer a tileset this tool
    /// wrote, is left as it is, and the temporary folder is removed.
    pub fn commit(mut self) -> Result<(), OutDirError> {
        let _ = std::fs::remove_file(self.tmp.join(OWNER));
        let marker = self.tmp.join(MARKER);
        std::fs::write(&marker, MARKER_TEXT).map_err(io(&marker))?;
        match existing(&self.path, &self.given)? {
            None => {}
            Some(_) if !self.force => return Err(OutDirError::Appeared(self.given.clone())),
            Some(Existing::Other) => return Err(OutDirError::NotATileset(self.given.clone())),
            Some(Existing::Empty) => {
                // Fails where something was written into it meanwhile.
                std::fs::remove_dir(&self.path).map_err(|_| OutDirError::NotATileset(self.given.clone()))?;
            }
            Some(Existing::Tileset) => {
                exchange(&self.tmp, &self.path).map_err(io(&self.path))?;
                self.done = true;
                // The old tileset now sits at the temporary name; a build
                // killed while deleting it leaves the rest to the next one.
                let _ = std::fs::remove_dir_all(&self.tmp);
                return Ok(());
            }
        }
        match rename_new(&self.tmp, &self.path) {
            Ok(()) => {
                self.done = true;
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Err(OutDirError::Appeared(self.given.clone())),
            Err(source) => Err(OutDirError::Io { path: self.given.clone(), source }),
        }
    }
}

impl Drop for OutDir {
    fn drop(&mut self) {
        if !self.done {
            if !self.tmp.as_os_str().is_empty() {
                let _ = std::fs::remove_dir_all(&self.tmp);
            }
            // Only while empty: whatever else appeared in them stays.
            for dir in self.created.iter().rev() {
                let _ = std::fs::remove_dir(dir);
            }
        }
    }
}

/// Makes `dir` and the folders above it that are missing; returns those it
/// made, outermost first.
fn make_parents(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut missing: Vec<PathBuf> =
        dir.ancestors().take_while(|a| !a.as_os_str().is_empty() && !a.exists()).map(Path::to_path_buf).collect();
    missing.reverse();
    let mut made = Vec::new();
    for d in missing {
        match std::fs::create_dir(&d) {
            Ok(()) => made.push(d),
            // Made by someone else meanwhile: theirs, not removed.
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e),
        }
    }
    Ok(made)
}

/// What is at OUT already.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Existing {
    /// A tileset this tool wrote ([`MARKER`]).
    Tileset,
    /// An empty folder: nothing to lose.
    Empty,
    /// Anything else in a folder.
    Other,
}

/// What is at `path` (`given` names it in messages); not a folder (a file,
/// a symbolic link) is an error.
fn existing(path: &Path, given: &Path) -> Result<Option<Existing>, OutDirError> {
    let meta = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(OutDirError::Io { path: given.into(), source }),
    };
    if !meta.is_dir() {
        return Err(OutDirError::NotAFolder(given.into()));
    }
    if is_tileset(path) {
        return Ok(Some(Existing::Tileset));
    }
    let mut entries = std::fs::read_dir(path).map_err(|source| OutDirError::Io { path: given.into(), source })?;
    Ok(Some(if entries.next().is_none() { Existing::Empty } else { Existing::Other }))
}

/// Whether `dir` holds [`MARKER`] as a small regular file with the format tag.
pub fn is_tileset(dir: &Path) -> bool {
    let marker = dir.join(MARKER);
    let small_file = std::fs::symlink_metadata(&marker).is_ok_and(|m| m.is_file() && m.len() <= 256);
    let tag = MARKER_TEXT.split(' ').next().unwrap_or(MARKER_TEXT);
    small_file && std::fs::read_to_string(&marker).is_ok_and(|t| t.starts_with(tag))
}

/// `PID`, or `PID-N` for the Nth build of this process (builds of one
/// process, e.g. a library's user, into one place need their own folders).
fn build_tag() -> String {
    static BUILDS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    match BUILDS.fetch_add(1, std::sync::atomic::Ordering::Relaxed) {
        0 => std::process::id().to_string(),
        n => format!("{}-{n}", std::process::id()),
    }
}

/// `.NAME.terrachunk-KIND-TAG`: a build's temporary (`tmp`) or set-aside
/// (`old`) folder beside OUT, `TAG` from [`build_tag`].
fn sibling(name: &OsStr, kind: &str, tag: &str) -> OsString {
    let mut s = OsString::from(".");
    s.push(name);
    s.push(format!(".terrachunk-{kind}-{tag}"));
    s
}

/// The kind and process id of a [`sibling`] of OUT `name`, if `entry` is one.
fn parse_sibling<'a>(name: &OsStr, entry: &'a OsStr) -> Option<(&'a str, u32)> {
    let entry = entry.to_str()?;
    let mut prefix = OsString::from(".");
    prefix.push(name);
    prefix.push(".terrachunk-");
    let rest = entry.strip_prefix(prefix.to_str()?)?;
    let (kind, tag) = rest.split_once('-')?;
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    let pid = tag.split_once('-').filter(|(_, n)| digits(n)).map_or(tag, |(pid, _)| pid);
    let pid = pid.parse().ok().filter(|_| digits(pid))?;
    matches!(kind, "tmp" | "old").then_some((kind, pid))
}

/// Removes the temporary folders of dead builds into `parent/name`, and
/// where OUT is missing after a swap interrupted half way, moves the old
/// tileset back first.
fn recover(parent: &Path, name: &OsStr, out: &Path) -> Result<(), OutDirError> {
    let entries = std::fs::read_dir(parent).map_err(io(parent))?;
    let mut stale: Vec<(PathBuf, &str)> = Vec::new();
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some((kind, pid)) = parse_sibling(name, &file_name) else { continue };
        let path = entry.path();
        let is_dir = std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir());
        if is_dir && !owner_alive(&path, pid) {
            stale.push((path, if kind == "old" { "old" } else { "tmp" }));
        }
    }
    // A set-aside tileset is put back where OUT is missing; any other
    // leftover is a tileset being written or being deleted.
    stale.sort();
    for (path, kind) in stale {
        let restored = kind == "old"
            && std::fs::symlink_metadata(out).is_err()
            && is_tileset(&path)
            && std::fs::rename(&path, out).is_ok();
        if !restored {
            std::fs::remove_dir_all(&path).map_err(io(&path))?;
        }
    }
    Ok(())
}

/// Whether the build that made the temporary folder `dir` may still be
/// running: its owner file names this machine (or is missing) and process
/// `pid` is alive (this one included: its other builds may be running).
/// Another machine's folder counts as dead: its build cannot be asked.
fn owner_alive(dir: &Path, pid: u32) -> bool {
    if let Ok(text) = std::fs::read_to_string(dir.join(OWNER))
        && text.lines().next().is_some_and(|h| h != host())
    {
        return false;
    }
    pid == std::process::id() || process_alive(pid)
}

#[cfg(unix)]
fn process_alive(pid: u32) -> bool {
    let Some(pid) = i32::try_from(pid).ok().and_then(rustix::process::Pid::from_raw) else { return false };
    match rustix::process::test_kill_process(pid) {
        Ok(()) => true,
        Err(e) => e != rustix::io::Errno::SRCH,
    }
}

#[cfg(not(unix))]
fn process_alive(_pid: u32) -> bool {
    true // cannot be asked: kept
}

#[cfg(unix)]
fn host() -> String {
    rustix::system::uname().nodename().to_string_lossy().into_owned()
}

#[cfg(not(unix))]
fn host() -> String {
    std::env::var("COMPUTERNAME").unwrap_or_default()
}

/// Renames `from` to `to`, failing where `to` exists (even as an empty folder,
/// which a plain rename would replace).
#[cfg(any(target_os = "linux", target_os = "android"))]
fn rename_new(from: &Path, to: &Path) -> std::io::Result<()> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    renameat_with(CWD, from, CWD, to, RenameFlags::NOREPLACE).map_err(std::io::Error::from)
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn rename_new(from: &Path, to: &Path) -> std::io::Result<()> {
    if std::fs::symlink_metadata(to).is_ok() {
        return Err(std::io::ErrorKind::AlreadyExists.into());
    }
    std::fs::rename(from, to)
}

/// Swaps folders `a` and `b` in one step.
#[cfg(any(target_os = "linux", target_os = "android"))]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    match renameat_with(CWD, a, CWD, b, RenameFlags::EXCHANGE) {
        // File systems without RENAME_EXCHANGE: in two steps.
        Err(rustix::io::Errno::INVAL | rustix::io::Errno::NOSYS) => exchange_in_two(a, b),
        r => r.map_err(std::io::Error::from),
    }
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    exchange_in_two(a, b)
}

/// [`exchange`] where the system cannot swap: `b` is set aside under an
/// `old` name (which [`recover`] moves back if the build dies before `a`
/// is in), `a` is moved in, and the old folder ends at `a`'s name.
fn exchange_in_two(a: &Path, b: &Path) -> std::io::Result<()> {
    let (Some(parent), Some(name)) = (b.parent(), b.file_name()) else {
        return Err(std::io::ErrorKind::InvalidInput.into());
    };
    let aside = parent.join(sibling(name, "old", &build_tag()));
    std::fs::rename(b, &aside)?;
    if let Err(e) = rename_new(a, b) {
        let _ = std::fs::rename(&aside, b);
        return Err(e);
    }
    std::fs::rename(&aside, a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn siblings_are_told_apart_from_other_names() {
        let name = OsStr::new("out");
        assert_eq!(sibling(name, "tmp", "42"), OsStr::new(".out.terrachunk-tmp-42"));
        assert_eq!(parse_sibling(name, OsStr::new(".out.terrachunk-tmp-42")), Some(("tmp", 42)));
        assert_eq!(parse_sibling(name, OsStr::new(".out.terrachunk-tmp-42-3")), Some(("tmp", 42)));
        assert_eq!(parse_sibling(name, OsStr::new(".out.terrachunk-old-7")), Some(("old", 7)));
        for other in [
            ".out.terrachunk-tmp-",
            ".out.terrachunk-tmp-+4",
            ".out2.terrachunk-tmp-4",
            ".o.terrachunk-x-4",
            ".out.terrachunk-tmp-4-",
        ] {
            assert_eq!(parse_sibling(name, OsStr::new(other)), None, "{other}");
        }
    }
}
