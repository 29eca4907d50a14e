//! Sharded builds: one tileset as independent jobs that an existing
//! distributed engine runs (DESIGN.md, promise 10; `docs/distributed.md`).
//!
//! `plan` fixes the tree a single-process [`pipeline::build`] would make and
//! writes a manifest of jobs: job 0 the levels above the shard level, then
//! one job per block of shard-level chunks and everything below them. A job
//! needs nothing from another: a subtree's ancestors are meshed again from
//! the top, exactly as the whole build meshes them, rather than read from
//! files job 0 wrote (a mesh carries the mesher's per-triangle state, which
//! no file format keeps in step with the mesher; the few ancestors cost
//! little next to a subtree). Chunks are decided from their own footprint
//! and their parent's mesh alone, so each job writes the very bytes the whole
//! build writes for its chunks. `merge` gathers the jobs' chunks and writes
//! the one index over all of them, which is then byte-identical to the
//! whole build's `tileset.json`.
//!
//! Jobs are idempotent and atomic: a job writes into a temporary directory
//! in the work folder and renames it to `job-K` when complete, so a killed
//! job leaves no `job-K` and its rerun writes the same bytes; a job that
//! finds `job-K` already written for this manifest does nothing. `merge`
//! links the chunks into a temporary directory beside OUT and renames it
//! into place, like `build`: no partial tileset is ever visible at OUT.

use std::collections::BTreeSet;
use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::config::Config;
use crate::output::tileset::{IndexWritten, TileRecord, TilesetExtras, tileset_json, write_index};
use crate::pipeline::{BuildError, BuildOptions, Report, build_part, plan_fixed};
pub use crate::pipeline::{FixedPlan, PartBuilt, TreePart};
use crate::quadtree::{ChunkKey, ChunkTree};
use crate::texture::TextureSource;

/// The manifest layout this version reads and writes.
pub const MANIFEST_VERSION: u32 = 1;

/// The manifest's file name inside the work folder.
pub const MANIFEST_FILE: &str = "manifest.json";

/// What a finished job leaves in its folder besides its chunks.
const JOB_FILE: &str = "job.json";

/// Where a DEM or texture path given relative to the plan's working folder
/// is read from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", tag = "kind", content = "path")]
pub enum Texture {
    /// Generated from the DEM.
    Generated,
    /// None.
    None,
    /// This image, as given.
    Image(PathBuf),
}

/// One job of the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Job {
    /// Its index, 0 for the levels above the shards.
    pub job: usize,
    /// Job 0: the levels it builds are those above this one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub above_level: Option<u32>,
    /// Other jobs: the shard-level chunks `[level, x, y]` it builds, with
    /// everything below them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub roots: Vec<[u32; 3]>,
}

impl Job {
    /// The part of the tree this job builds.
    pub fn part(&self) -> TreePart {
        match self.above_level {
            Some(l) => TreePart::Above(l),
            None => TreePart::Under(self.roots.iter().map(|&[level, x, y]| ChunkKey { level, x, y }).collect()),
        }
    }
}

/// A sharded build: what every job and `merge` read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`MANIFEST_VERSION`].
    pub version: u32,
    /// The terrachunk that planned it; jobs of another version refuse it,
    /// since their bytes may differ.
    pub generator: String,
    /// SHA-256 (hex) of the input files' bytes, the settings and the plan:
    /// every job checks its input against it, and each job's result carries it.
    pub hash: String,
    /// The working folder relative paths are read from.
    pub cwd: PathBuf,
    /// DEM file(s) or folder, as given (the index names them so).
    pub inputs: Vec<PathBuf>,
    /// The colour source.
    pub texture: Texture,
    /// The geoid model, as given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geoid: Option<PathBuf>,
    /// The tileset to write (absolute).
    pub out: PathBuf,
    /// Replace an existing OUT.
    pub force: bool,
    /// Every setting, validated.
    pub config: Config,
    /// The tree.
    pub plan: FixedPlan,
    /// The level whose chunks are the shards' tops.
    pub shard_level: u32,
    /// Job 0 first, then one per shard.
    pub jobs: Vec<Job>,
}

/// A finished job's record of what it wrote (`job-K/job.json`).
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct JobResult {
    /// The manifest's hash.
    hash: String,
    job: usize,
    /// `[level, x, y]`, box min, box max, δ: one per chunk, in key order.
    records: Vec<RecordRow>,
    /// Job 0 only: the index's top-level extras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    extras: Option<TilesetExtras>,
    /// The job's figures, for people (peak memory, seconds).
    report: serde_json::Value,
}

/// One chunk in a job's result: `[level, x, y]`, box min, box max, δ.
type RecordRow = ([u32; 3], [f64; 3], [f64; 3], f64);

/// Why a sharded step failed.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    /// The build itself failed.
    #[error(transparent)]
    Build(#[from] BuildError),
    /// A chunk was too dense for the planned tree (a single-process build
    /// would have added a refine level and started again).
    #[error(
        "{source}: the planned tree has too few refine levels for this chunk; a sharded build cannot add \
         one while its jobs run (plan again with a larger --max-chunk-vertices or a coarser --max-error)"
    )]
    TreeTooDense {
        /// What the mesher said.
        source: BuildError,
    },
    /// A file or folder could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// Which.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The manifest or a job's result is not what this version reads.
    #[error("{path}: {reason}")]
    Bad {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A setting of the plan is out of range.
    #[error("{0}")]
    Usage(String),
    /// An input is not what the plan read.
    #[error(
        "{path}: changed since the plan (the manifest's hash is {planned}, the input now gives {found}); plan again"
    )]
    Changed {
        /// The manifest.
        path: PathBuf,
        /// Its hash.
        planned: String,
        /// The input's now.
        found: String,
    },
    /// `merge` ran before every job finished.
    #[error("job {job} has not finished ({path} is missing): run `terrachunk build --manifest {manifest} --job {job}`")]
    Unfinished {
        /// The job.
        job: usize,
        /// Its result file.
        path: PathBuf,
        /// The manifest.
        manifest: PathBuf,
    },
}

impl ShardError {
    /// Process exit code: 2 for bad input, settings or manifests, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            ShardError::Build(e) => e.exit_code(),
            ShardError::Bad { .. } | ShardError::Usage(_) | ShardError::Changed { .. } => 2,
            ShardError::TreeTooDense { .. } | ShardError::Io { .. } | ShardError::Unfinished { .. } => 1,
        }
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ShardError + '_ {
    move |source| ShardError::Io { path: path.to_path_buf(), source }
}

/// The work folder a plan for OUT uses unless told otherwise: `OUT.shards`
/// beside it.
pub fn default_work(out: &Path) -> PathBuf {
    let mut name = out.file_name().map(|n| n.to_os_string()).unwrap_or_else(|| "out".into());
    name.push(".shards");
    out.with_file_name(name)
}

/// Plans a sharded build of `opts` in `shards` jobs below job 0 (fewer where
/// the tree has fewer chunks), writes the manifest into `work` and returns
/// its path. An existing work folder is replaced only with `opts.force`.
pub fn plan(opts: &BuildOptions, shards: usize, work: &Path) -> Result<PathBuf, ShardError> {
    if shards == 0 {
        return Err(ShardError::Usage("--shards must be at least 1".into()));
    }
    if opts.out.exists() && !opts.force {
        return Err(BuildError::OutputExists(opts.out.clone()).into());
    }
    if work.exists() && !opts.force {
        return Err(BuildError::OutputExists(work.to_path_buf()).into());
    }
    let cwd = std::env::current_dir().map_err(io(Path::new(".")))?;
    let fixed = plan_fixed(opts)?;
    let tree = fixed.tree(&opts.config);
    let shard_level = shard_level(&tree, shards);
    let mut keys: Vec<ChunkKey> = (0..tree.zs[shard_level as usize].len() as u32)
        .flat_map(|y| (0..tree.xs[shard_level as usize].len() as u32).map(move |x| (x, y)))
        .map(|(x, y)| ChunkKey { level: shard_level, x, y })
        .collect();
    // Row-major blocks: each shard a band of whole rows where it can be, the
    // window of the DEM it reads.
    let n = shards.min(keys.len());
    let mut jobs = vec![Job { job: 0, above_level: Some(shard_level), roots: Vec::new() }];
    let total = keys.len();
    for k in 0..n {
        let take = (k + 1) * total / n - k * total / n;
        let block: Vec<ChunkKey> = keys.drain(..take).collect();
        jobs.push(Job { job: k + 1, above_level: None, roots: block.iter().map(|c| [c.level, c.x, c.y]).collect() });
    }
    let texture = match &opts.texture {
        TextureSource::Generated => Texture::Generated,
        TextureSource::None => Texture::None,
        TextureSource::Image(p) => Texture::Image(p.clone()),
    };
    let out = if opts.out.is_absolute() { opts.out.clone() } else { cwd.join(&opts.out) };
    let mut manifest = Manifest {
        version: MANIFEST_VERSION,
        generator: generator(),
        hash: String::new(),
        cwd,
        inputs: opts.inputs.clone(),
        texture,
        geoid: opts.geoid.clone(),
        out,
        force: opts.force,
        config: opts.config.clone(),
        plan: fixed,
        shard_level,
        jobs,
    };
    manifest.hash = manifest_hash(&manifest)?;
    if work.exists() {
        // Only a work folder a plan made is replaced: never a folder of the user's.
        if !work.join(MANIFEST_FILE).is_file() {
            return Err(ShardError::Usage(format!(
                "{}: exists and holds no {MANIFEST_FILE}: not a terrachunk work folder, left as it is",
                work.display()
            )));
        }
        std::fs::remove_dir_all(work).map_err(io(work))?;
    }
    std::fs::create_dir_all(work).map_err(io(work))?;
    let path = work.join(MANIFEST_FILE);
    let bytes = serde_json::to_vec_pretty(&manifest).expect("JSON of plain values");
    write_atomic(&path, &bytes)?;
    Ok(path)
}

/// The shallowest level with at least `shards` chunks (the deepest if none
/// has), so that job 0 holds as few levels as the shards allow.
fn shard_level(tree: &ChunkTree, shards: usize) -> u32 {
    (0..=tree.depth())
        .find(|&l| tree.xs[l as usize].len() * tree.zs[l as usize].len() >= shards)
        .unwrap_or(tree.depth())
}

/// Reads and checks a manifest.
pub fn read_manifest(path: &Path) -> Result<Manifest, ShardError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    let bad = |reason: String| ShardError::Bad { path: path.to_path_buf(), reason };
    let value: serde_json::Value =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a terrachunk manifest (not JSON: {e})")))?;
    match value.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == u64::from(MANIFEST_VERSION) => {}
        Some(v) => return Err(bad(format!("manifest version {v}; this terrachunk reads version {MANIFEST_VERSION}"))),
        None => return Err(bad("not a terrachunk manifest (no version)".into())),
    }
    let m: Manifest = serde_json::from_value(value).map_err(|e| bad(format!("not a terrachunk manifest: {e}")))?;
    if m.generator != generator() {
        return Err(bad(format!(
            "planned by {}; this is {} and may write other bytes: plan again",
            m.generator,
            generator()
        )));
    }
    m.config.validate().map_err(|e| bad(e.to_string()))?;
    if m.jobs.iter().enumerate().any(|(k, j)| j.job != k) || m.jobs.first().is_none_or(|j| j.above_level.is_none()) {
        return Err(bad("jobs are not numbered 0, 1, … with job 0 above the shards".into()));
    }
    Ok(m)
}

/// What a job run did.
#[derive(Debug)]
pub struct JobRun {
    /// Chunks the job wrote (0 when it found itself done).
    pub chunks: usize,
    /// Whether an earlier run had already finished it.
    pub already_done: bool,
    /// The job's figures (absent when already done).
    pub report: Option<Report>,
    /// Wall seconds, hashing and loading the input included.
    pub seconds: f64,
}

/// Runs job `job` of the manifest at `manifest_path`, unless an earlier run
/// finished it. Threads: the manifest's setting, or `threads` if given.
pub fn run_job(manifest_path: &Path, job: usize, threads: Option<usize>) -> Result<JobRun, ShardError> {
    let t0 = std::time::Instant::now();
    let m = read_manifest(manifest_path)?;
    let work = manifest_path.parent().unwrap_or(Path::new("."));
    let spec = m.jobs.get(job).ok_or_else(|| {
        ShardError::Usage(format!(
            "job {job}: no such job in {} (jobs 0..={})",
            manifest_path.display(),
            m.jobs.len() - 1
        ))
    })?;
    let done = work.join(job_dir(job));
    if read_result(&done, &m).is_ok() {
        return Ok(JobRun { chunks: 0, already_done: true, report: None, seconds: t0.elapsed().as_secs_f64() });
    }
    let found = manifest_hash(&m)?;
    if found != m.hash {
        return Err(ShardError::Changed { path: manifest_path.to_path_buf(), planned: m.hash, found });
    }
    let mut opts = options(&m);
    if let Some(t) = threads {
        opts.config.threads = t;
    }
    let tmp = work.join(format!(".{}.tmp-{}", job_dir(job), std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let built = match build_part(&opts, &m.plan, &spec.part(), &tmp) {
        Ok(b) => b,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(match e {
                BuildError::Mesh(_) => ShardError::TreeTooDense { source: e },
                e => e.into(),
            });
        }
    };
    let extras = built.extras;
    let result = JobResult {
        hash: m.hash.clone(),
        job,
        records: built.records.iter().map(|r| ([r.key.level, r.key.x, r.key.y], r.min, r.max, r.delta_m)).collect(),
        extras: (job == 0).then_some(extras),
        report: serde_json::to_value(&built.report).expect("JSON of plain values"),
    };
    let finish = || -> Result<(), ShardError> {
        let path = tmp.join(JOB_FILE);
        std::fs::write(&path, serde_json::to_vec(&result).expect("JSON of plain values")).map_err(io(&path))?;
        if done.exists() {
            // Written for another manifest, or unreadable: this run's replaces it.
            std::fs::remove_dir_all(&done).map_err(io(&done))?;
        }
        std::fs::rename(&tmp, &done).map_err(io(&done))
    };
    if let Err(e) = finish() {
        let _ = std::fs::remove_dir_all(&tmp);
        // Another run of the same job finished first: its bytes are these.
        if read_result(&done, &m).is_ok() {
            let seconds = t0.elapsed().as_secs_f64();
            return Ok(JobRun { chunks: built.records.len(), already_done: true, report: Some(built.report), seconds });
        }
        return Err(e);
    }
    let seconds = t0.elapsed().as_secs_f64();
    Ok(JobRun { chunks: built.records.len(), already_done: false, report: Some(built.report), seconds })
}

/// What `merge` wrote.
#[derive(Debug)]
pub struct Merged {
    /// The tileset.
    pub out: PathBuf,
    /// Chunks in it.
    pub chunks: usize,
    /// Bytes of its `tileset.json` and external tilesets.
    pub index_bytes: u64,
    /// How many index files: `tileset.json` and its external tilesets.
    pub index_files: usize,
}

/// Writes the tileset of a finished sharded build: every job's chunks and
/// the one index over them, into a temporary directory beside OUT that is
/// then renamed into place.
pub fn merge(manifest_path: &Path) -> Result<Merged, ShardError> {
    let m = read_manifest(manifest_path)?;
    let work = manifest_path.parent().unwrap_or(Path::new("."));
    if m.out.exists() && !m.force {
        return Err(BuildError::OutputExists(m.out.clone()).into());
    }
    let mut results = Vec::new();
    for job in 0..m.jobs.len() {
        let dir = work.join(job_dir(job));
        match read_result(&dir, &m) {
            Ok(r) => results.push((dir, r)),
            Err(ShardError::Io { path, source }) if source.kind() == std::io::ErrorKind::NotFound => {
                return Err(ShardError::Unfinished { job, path, manifest: manifest_path.to_path_buf() });
            }
            Err(e) => return Err(e),
        }
    }
    let extras = results[0].1.extras.clone().ok_or_else(|| ShardError::Bad {
        path: results[0].0.join(JOB_FILE),
        reason: "job 0's result has no tileset extras".into(),
    })?;
    let mut records: Vec<TileRecord> = results
        .iter()
        .flat_map(|(_, r)| &r.records)
        .map(|&([level, x, y], min, max, delta_m)| TileRecord { key: ChunkKey { level, x, y }, min, max, delta_m })
        .collect();
    records.sort_by_key(|r| r.key);
    let twice = records.windows(2).find(|w| w[0].key == w[1].key);
    if let Some(w) = twice {
        let k = w[0].key;
        return Err(ShardError::Bad {
            path: manifest_path.to_path_buf(),
            reason: format!("chunk {}/{}/{} was written by two jobs", k.level, k.x, k.y),
        });
    }
    let tree = m.plan.tree(&m.config);
    let doc = tileset_json(&tree, &records, &extras, m.config.index_tiles);
    let tmp = temp_beside(&m.out);
    let _ = std::fs::remove_dir_all(&tmp);
    let mut index = IndexWritten::default();
    let mut write = || -> Result<(), ShardError> {
        for (dir, _) in &results {
            link_tree(&dir.join("tiles"), &tmp.join("tiles"))?;
        }
        std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
        index = write_index(&tmp, &doc).map_err(|(path, e)| io(&path)(e))?;
        let marker = tmp.join(crate::pipeline::out_dir::MARKER);
        std::fs::write(&marker, crate::pipeline::out_dir::MARKER_TEXT).map_err(io(&marker))?;
        if m.out.exists() {
            std::fs::remove_dir_all(&m.out).map_err(io(&m.out))?;
        }
        std::fs::rename(&tmp, &m.out).map_err(io(&m.out))
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    Ok(Merged { out: m.out.clone(), chunks: records.len(), index_bytes: index.bytes, index_files: index.files })
}

/// `job-K`.
fn job_dir(job: usize) -> String {
    format!("job-{job}")
}

fn read_result(dir: &Path, m: &Manifest) -> Result<JobResult, ShardError> {
    let path = dir.join(JOB_FILE);
    let bytes = std::fs::read(&path).map_err(io(&path))?;
    let r: JobResult = serde_json::from_slice(&bytes)
        .map_err(|e| ShardError::Bad { path: path.clone(), reason: format!("not a job result: {e}") })?;
    if r.hash != m.hash {
        return Err(ShardError::Bad { path, reason: format!("written for another plan (hash {})", r.hash) });
    }
    Ok(r)
}

/// The build options a job runs with, paths read from the plan's folder.
fn options(m: &Manifest) -> BuildOptions {
    BuildOptions {
        inputs: m.inputs.iter().map(|p| m.cwd.join(p)).collect(),
        out: m.out.clone(),
        force: m.force,
        config: m.config.clone(),
        texture: match &m.texture {
            Texture::Generated => TextureSource::Generated,
            Texture::None => TextureSource::None,
            Texture::Image(p) => TextureSource::Image(m.cwd.join(p)),
        },
        progress: false,
        geoid: m.geoid.as_ref().map(|p| m.cwd.join(p)),
    }
}

fn generator() -> String {
    format!("terrachunk {}", env!("CARGO_PKG_VERSION"))
}

/// SHA-256 of everything a job's bytes depend on: the input files (a folder:
/// its files by name), the texture image, the settings and the plan.
fn manifest_hash(m: &Manifest) -> Result<String, ShardError> {
    let mut h = Sha256::new();
    let mut text = |s: &str| {
        h.update((s.len() as u64).to_le_bytes());
        h.update(s.as_bytes());
    };
    let mut unhashed = m.clone();
    unhashed.hash = String::new();
    text(&serde_json::to_string(&unhashed).expect("JSON of plain values"));
    let mut files: Vec<PathBuf> = Vec::new();
    let opts = options(m);
    let image = match &opts.texture {
        TextureSource::Image(p) => Some(p.clone()),
        _ => None,
    };
    for p in opts.inputs.iter().chain(&image).chain(&opts.geoid) {
        if p.is_dir() {
            let mut inside: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(io(p))?
                .map(|e| e.map(|e| e.path()).map_err(io(p)))
                .collect::<Result<_, _>>()?;
            inside.sort();
            files.extend(inside.into_iter().filter(|f| f.is_file()));
        } else {
            files.push(p.clone());
            // A VRT's tiles are input as much as the VRT itself.
            files.extend(crate::dem::vrt_sources(p).map_err(BuildError::from)?);
        }
    }
    for f in &files {
        h.update(f.file_name().map_or(0, |n| n.len() as u64).to_le_bytes());
        h.update(f.file_name().unwrap_or_default().as_encoded_bytes());
        let mut file = std::fs::File::open(f).map_err(io(f))?;
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = file.read(&mut buf).map_err(io(f))?;
            if n == 0 {
                break;
            }
            h.update(&buf[..n]);
        }
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Writes `bytes` to `path` through a temporary file beside it.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ShardError> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes).map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

/// A sibling of `out` for a tileset being assembled (named as `build`'s).
fn temp_beside(out: &Path) -> PathBuf {
    let name = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    out.with_file_name(format!(".{name}.terrachunk-tmp-{}", std::process::id()))
}

/// Hard-links every file under `from` to the same place under `to` (copies
/// where the two are on different file systems). A missing `from` (a job
/// that wrote no chunk) is nothing to link.
fn link_tree(from: &Path, to: &Path) -> Result<(), ShardError> {
    let entries = match std::fs::read_dir(from) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io(from)(e)),
    };
    std::fs::create_dir_all(to).map_err(io(to))?;
    let mut names = BTreeSet::new();
    for e in entries {
        names.insert(e.map_err(io(from))?.file_name());
    }
    for name in names {
        let (src, dst) = (from.join(&name), to.join(&name));
        if src.is_dir() {
            link_tree(&src, &dst)?;
        } else if std::fs::hard_link(&src, &dst).is_err() {
            std::fs::copy(&src, &dst).map_err(io(&dst))?;
        }
    }
    Ok(())
}
