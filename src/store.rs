//! Whole-grid arrays (the heights, their void fill, the bintree's error
//! field, a generated colour map) kept in memory, or, where a build's
//! memory limit is smaller than they are, in scratch files mapped into it.
//!
//! A mapped array is read and written like any slice, and holds the same
//! values, so the chunks come out byte for byte as an unlimited build's.
//! Its pages live in the kernel's page cache, which writes them back to the
//! scratch file and drops them when memory is short (in a cgroup with a
//! memory limit, for one); [`Memory`] also keeps this process's own
//! resident size under the limit by unmapping the arrays' pages from it
//! (`MADV_DONTNEED`: a shared file mapping keeps its contents) whenever it
//! passes 7/8 of the limit. Out-of-core work through mapped scratch files is
//! what tippecanoe does for the same reason.
//!
//! The scratch files are unlinked as soon as they are mapped: a killed build
//! leaves none behind.
#![allow(unsafe_code)]

use std::fs::OpenOptions;
use std::io;
use std::ops::{Deref, DerefMut};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

/// An element a mapped array may hold: plain bytes, any bit pattern valid,
/// no destructor.
pub trait Plain: Copy + Send + Sync + 'static {
    /// Whether every byte of it is 0 (what a new scratch file holds).
    fn is_zero_bits(&self) -> bool;
}
impl Plain for f32 {
    fn is_zero_bits(&self) -> bool {
        self.to_bits() == 0
    }
}
impl Plain for u8 {
    fn is_zero_bits(&self) -> bool {
        *self == 0
    }
}

/// A build's memory limit and where arrays past its share go.
#[derive(Clone)]
pub struct Memory {
    inner: Arc<Inner>,
}

struct Inner {
    limit: u64,
    scratch: PathBuf,
    /// (address, length) of every live mapping, for the governor.
    regions: Mutex<Vec<(usize, usize)>>,
    /// Bytes mapped so far (the build reports it).
    mapped: AtomicU64,
    /// The largest resident size a look found, bytes: VmHWM misses
    /// resident pages dropped before the kernel next updates it.
    most_resident: AtomicU64,
    governor: Mutex<bool>,
}

impl std::fmt::Debug for Memory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Memory").field("limit", &self.inner.limit).field("scratch", &self.inner.scratch).finish()
    }
}

/// How often the governor looks at the resident size.
const GOVERNOR_PERIOD: Duration = Duration::from_millis(2);

/// Bytes a bulk fill or copy into a mapping writes between looks at the
/// resident size: a memset fills pages faster than the governor wakes.
const BULK_STEP: usize = 8 << 20;

impl Memory {
    /// A limit of `limit_bytes` for the whole process, with scratch files
    /// in `scratch` (a folder on a disk, not a tmpfs, for the limit to hold).
    pub fn new(limit_bytes: u64, scratch: &Path) -> Memory {
        Memory {
            inner: Arc::new(Inner {
                limit: limit_bytes,
                scratch: scratch.to_path_buf(),
                regions: Mutex::new(Vec::new()),
                mapped: AtomicU64::new(0),
                most_resident: AtomicU64::new(0),
                governor: Mutex::new(false),
            }),
        }
    }

    /// The limit, bytes.
    pub fn limit(&self) -> u64 {
        self.inner.limit
    }

    /// Brings the resident size back under the governor's mark now, where
    /// it is over (see [`Grid::relieve`](crate::mesh::grid::Grid::relieve)).
    pub fn relieve(&self) {
        // Nothing to give back (and no resident size to read) until an
        // array is mapped.
        if self.inner.mapped.load(Ordering::Relaxed) > 0 {
            self.inner.relieve();
        }
    }

    /// The largest resident size the governor and [`Memory::relieve`]
    /// saw, bytes (0 before any array is mapped).
    pub fn most_resident_bytes(&self) -> u64 {
        self.inner.most_resident.load(Ordering::Relaxed)
    }

    /// Bytes of arrays placed in scratch files so far.
    pub fn mapped_bytes(&self) -> u64 {
        self.inner.mapped.load(Ordering::Relaxed)
    }

    /// Whether an array of `bytes` goes to a scratch file: one of more than
    /// an eighth of the limit (the heights, the error field and a colour map
    /// together stay within half of it in memory; the rest is for the
    /// chunks in flight).
    pub fn maps(&self, bytes: u64) -> bool {
        bytes > self.inner.limit / 8
    }

    fn register(&self, addr: usize, len: usize) {
        self.inner.regions.lock().unwrap_or_else(|e| e.into_inner()).push((addr, len));
        self.inner.mapped.fetch_add(len as u64, Ordering::Relaxed);
        let mut started = self.inner.governor.lock().unwrap_or_else(|e| e.into_inner());
        if !*started {
            *started = true;
            let weak = Arc::downgrade(&self.inner);
            std::thread::Builder::new()
                .name("terrachunk-memory".into())
                .spawn(move || govern(&weak))
                .map(drop)
                .unwrap_or_else(|_| *started = false);
        }
    }
}

/// Keeps the process's resident size under 7/8 of the limit while any
/// mapping lives: the mapped arrays' pages are the only ones it can give
/// back without losing anything.
fn govern(memory: &Weak<Inner>) {
    loop {
        std::thread::sleep(GOVERNOR_PERIOD);
        let Some(inner) = memory.upgrade() else { return };
        if !inner.relieve() {
            return;
        }
    }
}

impl Inner {
    /// Drops the mapped arrays' pages from this process where it holds more
    /// than 3/4 of the limit (the rest is headroom for what grows between
    /// two looks); false where the resident size cannot be read.
    fn relieve(&self) -> bool {
        let Some(resident) = resident_pages() else { return false };
        let resident = resident * rustix::param::page_size() as u64;
        self.most_resident.fetch_max(resident, Ordering::Relaxed);
        if resident <= self.limit / 4 * 3 {
            return true;
        }
        // Held while dropping: a mapping is unmapped only under this lock,
        // so no address here can have been reused by another allocation.
        let regions = self.regions.lock().unwrap_or_else(|e| e.into_inner());
        for &(addr, len) in regions.iter() {
            // SAFETY: (addr, len) is a live shared file mapping (removed
            // from the list before it is unmapped, under this lock); for
            // such a mapping MADV_DONTNEED only drops this process's page
            // table entries, and the next access reads the same bytes back
            // from the page cache or the file.
            let _ = unsafe { rustix::mm::madvise(addr as *mut _, len, rustix::mm::Advice::LinuxDontNeed) };
        }
        true
    }
}

/// `values` as atomics, for a pass whose threads each write their own
/// elements and read others' (the bintree's error field).
pub fn as_atomic(values: &mut [f32]) -> &[AtomicU32] {
    // SAFETY: `AtomicU32` has the size and bit validity of `u32` and an
    // alignment of 4, as `f32` has; the exclusive borrow makes the atomics
    // the only view for as long as they live.
    unsafe { &*(std::ptr::from_mut::<[f32]>(values) as *const [AtomicU32]) }
}

/// This process's resident pages (`/proc/self/statm`).
fn resident_pages() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    statm.split_whitespace().nth(1)?.parse().ok()
}

/// A whole-grid array: a `Vec`, or a mapped scratch file.
pub struct Big<T: Plain> {
    backing: Backing<T>,
}

enum Backing<T: Plain> {
    Heap(Vec<T>),
    Mapped { ptr: NonNull<T>, len: usize, bytes: usize, memory: Memory },
}

// SAFETY: a mapped `Big` owns its mapping exclusively, as a `Vec` owns its
// buffer; `T` is `Send + Sync`.
unsafe impl<T: Plain> Send for Big<T> {}
// SAFETY: as above; shared access only reads.
unsafe impl<T: Plain> Sync for Big<T> {}

static SCRATCH_COUNT: AtomicU64 = AtomicU64::new(0);

impl<T: Plain> Big<T> {
    /// Gives mapped pages back where the process is over its share of the
    /// limit, as [`Memory::relieve`] (nothing for an array in memory): for
    /// a scan of the whole array to call between parts.
    pub fn relieve(&self) {
        if let Backing::Mapped { memory, .. } = &self.backing {
            memory.relieve();
        }
    }

    /// `len` copies of `value`: in a scratch file where `memory` says an
    /// array this size goes to one, else a `Vec`.
    pub fn filled(len: usize, value: T, memory: Option<&Memory>) -> io::Result<Self> {
        let bytes = len.checked_mul(size_of::<T>()).ok_or_else(|| io::Error::other("array too large"))?;
        match memory {
            Some(m) if bytes > 0 && m.maps(bytes as u64) => {
                let mut big = Self::mapped(len, bytes, m)?;
                // A new scratch file reads as zeros already.
                if !value.is_zero_bits() {
                    for part in big.chunks_mut(BULK_STEP / size_of::<T>()) {
                        part.fill(value);
                        m.inner.relieve();
                    }
                }
                Ok(big)
            }
            _ => Ok(Big { backing: Backing::Heap(vec![value; len]) }),
        }
    }

    /// A copy of `values`: in a scratch file where `memory` says an array
    /// this size goes to one, else a `Vec`.
    pub fn copied_from(values: &[T], memory: Option<&Memory>) -> io::Result<Self> {
        let bytes = std::mem::size_of_val(values);
        match memory {
            Some(m) if bytes > 0 && m.maps(bytes as u64) => {
                let mut big = Self::mapped(values.len(), bytes, m)?;
                let step = BULK_STEP / size_of::<T>();
                for (part, from) in big.chunks_mut(step).zip(values.chunks(step)) {
                    part.copy_from_slice(from);
                    m.inner.relieve();
                }
                Ok(big)
            }
            _ => Ok(Big { backing: Backing::Heap(values.to_vec()) }),
        }
    }

    /// `v` moved into a scratch file where `memory` says so (its memory is
    /// freed once copied), else kept.
    pub fn from_vec_in(v: Vec<T>, memory: Option<&Memory>) -> io::Result<Self> {
        match memory {
            Some(m) if m.maps(std::mem::size_of_val(v.as_slice()) as u64) => Self::copied_from(&v, memory),
            _ => Ok(Big { backing: Backing::Heap(v) }),
        }
    }

    /// The values as a `Vec` (moved where they are one, else copied).
    pub fn into_vec(mut self) -> Vec<T> {
        match &mut self.backing {
            Backing::Heap(v) => std::mem::take(v),
            Backing::Mapped { .. } => self.to_vec(),
        }
    }

    /// Whether it lives in a scratch file.
    pub fn is_mapped(&self) -> bool {
        matches!(self.backing, Backing::Mapped { .. })
    }

    fn mapped(len: usize, bytes: usize, memory: &Memory) -> io::Result<Self> {
        let dir = &memory.inner.scratch;
        let n = SCRATCH_COUNT.fetch_add(1, Ordering::Relaxed);
        let path = dir.join(format!(".terrachunk-scratch-{}-{n}", std::process::id()));
        let named = |e: io::Error| io::Error::new(e.kind(), format!("scratch file {}: {e}", path.display()));
        let file = OpenOptions::new().read(true).write(true).create_new(true).open(&path).map_err(named)?;
        let _ = std::fs::remove_file(&path);
        file.set_len(bytes as u64).map_err(named)?;
        // SAFETY: a fresh mapping of a file of `bytes` bytes that only this
        // process has (it is unlinked), page-aligned, so aligned for `T`.
        let ptr = unsafe {
            rustix::mm::mmap(
                std::ptr::null_mut(),
                bytes,
                rustix::mm::ProtFlags::READ | rustix::mm::ProtFlags::WRITE,
                rustix::mm::MapFlags::SHARED,
                &file,
                0,
            )
        }
        .map_err(|e| named(e.into()))?;
        // One page per fault: reading ahead maps 16 at a time, fast enough
        // to outrun the governor by 100 MB on a sequential scan.
        // SAFETY: advice on the mapping just made; it changes no contents.
        let _ = unsafe { rustix::mm::madvise(ptr, bytes, rustix::mm::Advice::Random) };
        let ptr = NonNull::new(ptr.cast::<T>()).ok_or_else(|| io::Error::other("mmap gave a null pointer"))?;
        memory.register(ptr.as_ptr() as usize, bytes);
        Ok(Big { backing: Backing::Mapped { ptr, len, bytes, memory: memory.clone() } })
    }
}

impl<T: Plain> Default for Big<T> {
    fn default() -> Self {
        Big { backing: Backing::Heap(Vec::new()) }
    }
}

impl<T: Plain> From<Vec<T>> for Big<T> {
    fn from(v: Vec<T>) -> Self {
        Big { backing: Backing::Heap(v) }
    }
}

impl<T: Plain> Deref for Big<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.backing {
            Backing::Heap(v) => v,
            // SAFETY: the mapping holds `len` initialised `T`s (any bit
            // pattern is a valid `Plain`) and lives as long as `self`.
            Backing::Mapped { ptr, len, .. } => unsafe { std::slice::from_raw_parts(ptr.as_ptr(), *len) },
        }
    }
}

impl<T: Plain> DerefMut for Big<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.backing {
            Backing::Heap(v) => v,
            // SAFETY: as in `deref`, and `&mut self` makes this the only view.
            Backing::Mapped { ptr, len, .. } => unsafe { std::slice::from_raw_parts_mut(ptr.as_ptr(), *len) },
        }
    }
}

impl<T: Plain> Drop for Big<T> {
    fn drop(&mut self) {
        if let Backing::Mapped { ptr, bytes, memory, .. } = &self.backing {
            let addr = ptr.as_ptr() as usize;
            let mut regions = memory.inner.regions.lock().unwrap_or_else(|e| e.into_inner());
            regions.retain(|&(a, _)| a != addr);
            // SAFETY: the mapping made in `mapped`, no longer listed for the
            // governor, and no slice of it outlives `self`.
            let _ = unsafe { rustix::mm::munmap(addr as *mut _, *bytes) };
        }
    }
}

impl<T: Plain> Clone for Big<T> {
    /// A copy in memory, whatever the original's backing.
    fn clone(&self) -> Self {
        Big { backing: Backing::Heap(self.to_vec()) }
    }
}

impl<T: Plain + std::fmt::Debug> std::fmt::Debug for Big<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        (**self).fmt(f)
    }
}

impl<T: Plain + PartialEq> PartialEq<Vec<T>> for Big<T> {
    fn eq(&self, other: &Vec<T>) -> bool {
        **self == **other
    }
}

impl<T: Plain + PartialEq> PartialEq<Big<T>> for Vec<T> {
    fn eq(&self, other: &Big<T>) -> bool {
        **self == **other
    }
}

impl<T: Plain + PartialEq> PartialEq for Big<T> {
    fn eq(&self, other: &Big<T>) -> bool {
        **self == **other
    }
}

impl<'a, T: Plain> IntoIterator for &'a Big<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

/// Reads a size such as `256MB`, `2GB`, `1.5GiB` or `4000000000`: KB, MB
/// and GB are powers of 1000, KiB, MiB and GiB (and K, M, G) of 1024.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let unit = unit.trim();
    let scale: f64 = match unit.to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "kb" => 1e3,
        "mb" => 1e6,
        "gb" => 1e9,
        "tb" => 1e12,
        "k" | "kib" => 1024.0,
        "m" | "mib" => 1024.0 * 1024.0,
        "g" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tib" => 1024f64.powi(4),
        _ => return Err(format!("{s:?}: unknown unit {unit:?} (use B, KB, MB, GB, KiB, MiB or GiB)")),
    };
    let n: f64 = number.parse().map_err(|_| format!("{s:?}: not a size (such as 256MB or 2GB)"))?;
    let bytes = n * scale;
    if !(1.0..=1e18).contains(&bytes) {
        return Err(format!("{s:?}: out of range"));
    }
    Ok(bytes.round() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mapped_array_holds_what_a_vec_does_and_leaves_no_file() {
        let dir = std::env::temp_dir().join(format!("terrachunk-store-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let memory = Memory::new(8 << 10, &dir);
        let mut a = Big::filled(100_000, f32::NAN, Some(&memory)).unwrap();
        assert!(a.is_mapped() && a.iter().all(|h| h.is_nan()));
        for (k, h) in a.iter_mut().enumerate() {
            *h = k as f32 * 0.5;
        }
        // Dropping the pages from this process keeps their contents.
        let regions = memory.inner.regions.lock().unwrap().clone();
        for (addr, len) in regions {
            unsafe { rustix::mm::madvise(addr as *mut _, len, rustix::mm::Advice::LinuxDontNeed) }.unwrap();
        }
        assert!(a.iter().enumerate().all(|(k, &h)| h == k as f32 * 0.5));
        let b = Big::from_vec_in(vec![7u8; 1 << 20], Some(&memory)).unwrap();
        assert!(b.is_mapped() && b.iter().all(|&v| v == 7));
        assert_eq!(memory.mapped_bytes(), 400_000 + (1 << 20));
        // The copy looked at the resident size, which held at least the
        // part it had written: the build's peak reports it where VmHWM
        // missed it.
        let before = memory.most_resident_bytes();
        memory.relieve();
        assert!(memory.most_resident_bytes() >= before && before > 0);
        let small = Big::filled(10, 1.0f32, Some(&memory)).unwrap();
        assert!(!small.is_mapped(), "an array within an eighth of the limit stays in memory");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "scratch files are unlinked once mapped");
        drop((a, b));
        assert!(memory.inner.regions.lock().unwrap().is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn sizes_read_with_their_units() {
        assert_eq!(parse_bytes("256MB"), Ok(256_000_000));
        assert_eq!(parse_bytes("2GB"), Ok(2_000_000_000));
        assert_eq!(parse_bytes("1.5GiB"), Ok(1_610_612_736));
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert!(parse_bytes("lots").is_err() && parse_bytes("12 parsecs").is_err() && parse_bytes("0").is_err());
    }
}
