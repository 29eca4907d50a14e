//! Bench: speed against error, measured the same way for terrachunk and for
//! the tools it is compared with.
//!
//! - [`ladder`]: for each DEM and each `max_error_m`, a warm-up and N timed
//!   runs of the whole pipeline, each in its own `terrachunk build` child
//!   process (so its peak memory, VmHWM, is its own), into a scratch folder
//!   deleted afterwards. Medians of the stage times go to `bench.csv` with
//!   the tree's figures and the *measured* error of the finest surface
//!   ([`measure`] rasterises the leaf `.glb` files back onto the DEM).
//!   Optionally the same for one unconstrained greedy TIN over the grid
//!   (`terrachunk-single-tin`, in process), the baseline the nested
//!   hierarchy is judged against.
//! - [`import_peers`]: rows for other tools (pymartini, pydelatin, run by
//!   `bench/peers.sh` on the grid [`export_grid`] wrote), whose meshes are
//!   measured by the same [`measure`] code.
//! - [`scaling`]: time and peak memory for centred windows holding 1/16,
//!   1/4, ... of a DEM's samples, per thread count (`scaling.csv`).
//! - `plot`: triangles and time against max error, log–log (PNG, SVG),
//!   with the `plots` feature (on by default; the viewer builds without it,
//!   so it never compiles plotters or the font).
//! - [`savings`]: chunks, triangles and bytes of the error-bounded tree
//!   against a complete tree to the same leaf error (`savings.csv`).

pub mod grid;
pub mod measure;
mod peers;
#[cfg(feature = "plots")]
pub mod plot;
pub mod savings;
mod scaling;
pub mod table;

pub use peers::*;
pub use scaling::*;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use serde::Deserialize;

use crate::config::{Config, ConfigError};
use crate::dem::{self, DemError, LoadOptions};
use crate::heightfield::{Heightfield, void_fill};
use crate::mesh::decimate::{ChunkSpec, build_chunk};
use crate::mesh::grid::Grid;
use crate::mesh::quality::ShapeSummary;
use crate::mesh::{ChunkMesh, MeshError};
use crate::verify::VerifyError;
use measure::ErrorStats;
use table::Row;

/// Why a benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A DEM could not be loaded.
    #[error(transparent)]
    Dem(#[from] DemError),
    /// The settings file is unusable.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A file the bench reads (mesh, manifest, CSV, tileset) is malformed.
    #[error("{path}: {what}")]
    Input {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A file could not be encoded.
    #[error("{path}: cannot write: {what}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
    /// A chunk file could not be read back.
    #[error(transparent)]
    Verify(#[from] VerifyError),
    /// The single-TIN baseline failed.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A `terrachunk build` child process failed.
    #[error("terrachunk build of {dem} at {max_error_m} m failed ({status}): {stderr}")]
    Build {
        /// DEM label.
        dem: String,
        /// The error setting.
        max_error_m: f64,
        /// Exit status.
        status: String,
        /// What it said.
        stderr: String,
    },
    /// The plot could not be drawn.
    #[error("plot: {0}")]
    Plot(String),
    /// A setting of the bench itself is out of range.
    #[error("{0}")]
    Usage(String),
}

impl BenchError {
    fn tiff(path: &Path, e: impl std::fmt::Display) -> Self {
        BenchError::Write { path: path.into(), what: e.to_string() }
    }

    /// Process exit code: 2 for bad input or settings, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            BenchError::Dem(_) | BenchError::Config(_) | BenchError::Input { .. } | BenchError::Usage(_) => 2,
            _ => 1,
        }
    }
}

/// Which part of a DEM a benchmark runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cut {
    /// All of it, straight from its file.
    Whole,
    /// The top-left n × n samples, padded by repeating the last row or
    /// column where the grid is smaller ([`grid::square`]): pymartini needs
    /// n = 2^k + 1.
    Square(usize),
    /// The centred window with 1/f of the samples ([`grid::centred_window`]).
    Window(u32),
}

/// A grid ready to benchmark: the heights in memory (for the error
/// measurement and the in-process baselines) and a file `build` reads them
/// from exactly.
pub struct Prepared {
    /// DEM label for the CSV and plot: file name, plus the cut.
    pub label: String,
    /// The heights as every tool sees them.
    pub hf: Heightfield,
    /// What `terrachunk build` is given.
    pub build_input: PathBuf,
    /// Extra `build` arguments that make it read `build_input` as `hf`.
    pub build_args: Vec<String>,
}

/// Load options from a settings file (vertical scale, spacing).
pub fn load_options(config: Option<&Path>) -> Result<LoadOptions, BenchError> {
    let cfg = match config {
        Some(p) => Config::from_file(p)?,
        None => Config::default(),
    };
    Ok(LoadOptions { vertical_scale: Some(cfg.vertical_scale), spacing_m: cfg.spacing_m, geoid: None, memory: None })
}

/// Loads `dem` and cuts it; returns its label (file name, plus the cut) and
/// the heights every tool of the benchmark sees.
pub fn cut_grid(dem: &Path, cut: Cut, load: &LoadOptions) -> Result<(String, Heightfield), BenchError> {
    let full = dem::load(&[dem.to_path_buf()], load)?;
    let name = dem.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| dem.display().to_string());
    let (label, hf) = match cut {
        Cut::Whole => (name, full),
        Cut::Square(n) => {
            if n < 2 {
                return Err(BenchError::Usage(format!("--square {n}: needs at least 2 samples a side")));
            }
            let (hf, change) = grid::square(&full, n);
            let how = |d: i64, what: &str| match d {
                0 => String::new(),
                d if d > 0 => format!(", {d} {what} cropped"),
                d => format!(", {} {what} added by repeating the last", -d),
            };
            eprintln!(
                "{name}: top-left {n}×{n} of {}×{}{}{}",
                full.width,
                full.height,
                how(change.columns, "columns"),
                how(change.rows, "rows")
            );
            (format!("{name} {n}x{n}"), hf)
        }
        Cut::Window(f) => {
            let hf = grid::centred_window(&full, f);
            (format!("{name} 1/{f} {}x{}", hf.width, hf.height), hf)
        }
    };
    Ok((table::clean(&label), hf))
}

/// [`cut_grid`], and for a cut a float32 TIFF of it under `work` that
/// `build` reads with the original spacing and a vertical scale of 1 (the
/// heights written are already scaled).
pub fn prepare(dem: &Path, cut: Cut, load: &LoadOptions, work: &Path) -> Result<Prepared, BenchError> {
    let (label, hf) = cut_grid(dem, cut, load)?;
    if cut == Cut::Whole {
        return Ok(Prepared { label, hf, build_input: dem.into(), build_args: vec![] });
    }
    std::fs::create_dir_all(work).map_err(|source| BenchError::Io { path: work.into(), source })?;
    let path = work.join(format!("{}.tif", label.replace([' ', '/'], "_")));
    grid::write_f32_tiff(&hf, &path)?;
    let args = vec![
        "--spacing".into(),
        format!("{},{}", hf.spacing_m[0], hf.spacing_m[1]),
        "--vertical-scale".into(),
        "1".into(),
    ];
    Ok(Prepared { label, hf, build_input: path, build_args: args })
}

/// The parts of `build --report` JSON the bench reads.
#[derive(Clone, Debug, Deserialize)]
pub struct ChildReport {
    /// Per level.
    pub levels: Vec<ChildLevel>,
    /// Bytes written.
    pub bytes: u64,
    /// Bytes per input sample.
    pub bytes_per_sample: f64,
    /// Wall seconds per stage.
    pub seconds: ChildSeconds,
    /// Thread-seconds per per-chunk stage.
    pub thread_seconds: ChildThreadSeconds,
    /// VmHWM of the build process.
    pub peak_rss_bytes: Option<u64>,
    /// Threads used.
    pub threads: usize,
}

/// One level of a [`ChildReport`].
#[derive(Clone, Debug, Deserialize)]
pub struct ChildLevel {
    /// Chunks.
    pub chunks: usize,
    /// Surface triangles.
    pub triangles: usize,
    /// Surface vertices.
    pub vertices: usize,
}

/// Wall seconds of a [`ChildReport`].
#[derive(Clone, Debug, Deserialize)]
pub struct ChildSeconds {
    /// Load.
    pub load: f64,
    /// Void fill and plan.
    pub plan: f64,
    /// All chunks: mesh, skirt, morph, encode, write.
    pub chunks: f64,
    /// tileset.json and rename.
    pub index: f64,
    /// Everything.
    pub total: f64,
}

/// Thread-seconds of a [`ChildReport`].
#[derive(Clone, Debug, Deserialize)]
pub struct ChildThreadSeconds {
    /// Greedy insertion.
    pub mesh: f64,
    /// Normals, morph targets, skirts.
    pub skirt_morph: f64,
    /// Quantized output's as-written check (counted with meshing, whose
    /// loop it closes; absent from older reports).
    #[serde(default)]
    pub check: f64,
    /// Encoding and writing.
    pub write: f64,
}

impl ChildReport {
    /// Wall seconds load, plan, mesh, skirt+morph, write, index, total. The
    /// chunk stage runs its three parts interleaved on every thread, so its
    /// wall time is split in proportion to their thread-seconds.
    pub fn stage_seconds(&self) -> [f64; 7] {
        let s = &self.seconds;
        let t = &self.thread_seconds;
        let sum = t.mesh + t.check + t.skirt_morph + t.write;
        let share = |x: f64| if sum > 0.0 { s.chunks * x / sum } else { 0.0 };
        [s.load, s.plan, share(t.mesh + t.check), share(t.skirt_morph), share(t.write), s.index, s.total]
    }
}

/// A scratch folder removed when dropped, however the bench ends.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn scratch(out: &Path) -> Result<Scratch, BenchError> {
    let dir = out.join(format!(".runs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|source| BenchError::Io { path: dir.clone(), source })?;
    Ok(Scratch(dir))
}

/// Build outputs kept on disk before the oldest are removed, bytes.
const KEEP_BYTES: u64 = 8 << 30;

/// Where the timed builds write: a new folder each, kept until
/// [`KEEP_BYTES`] of them pile up, so that a build does not pay for
/// deleting the one before it (ext4 searches past the inodes freed in the
/// last minutes when it creates files: Fuji at 0.25 m, about 600 files,
/// took 1.17 s a build when each followed the deletion of the previous
/// output, 0.77–0.88 s when none did).
struct Outputs {
    dir: PathBuf,
    next: usize,
    kept: Vec<(PathBuf, u64)>,
}

impl Outputs {
    fn new(dir: &Path) -> Self {
        Outputs { dir: dir.to_path_buf(), next: 0, kept: Vec::new() }
    }

    /// A folder for the next build, after removing the oldest outputs if
    /// more than [`KEEP_BYTES`] are kept.
    fn fresh(&mut self) -> PathBuf {
        let mut total: u64 = self.kept.iter().map(|k| k.1).sum();
        while total > KEEP_BYTES && self.kept.len() > 1 {
            let (old, bytes) = self.kept.remove(0);
            let _ = std::fs::remove_dir_all(old);
            total -= bytes;
        }
        self.next += 1;
        self.dir.join(format!("run-{}", self.next))
    }

    /// The latest build's tileset.
    fn last(&self) -> PathBuf {
        self.kept.last().expect("a build ran").0.join("tileset")
    }
}

/// Runs `exe build` once into a fresh folder of `outputs` and returns its
/// report.
fn build_once(
    exe: &Path,
    p: &Prepared,
    config: Option<&Path>,
    max_error_m: f64,
    threads: usize,
    outputs: &mut Outputs,
) -> Result<ChildReport, BenchError> {
    let dir = outputs.fresh();
    // The report's folder exists before the build, which checks it first.
    std::fs::create_dir_all(&dir).map_err(|source| BenchError::Io { path: dir.clone(), source })?;
    let out = dir.join("tileset");
    let report = dir.join("report.json");
    let mut cmd = Command::new(exe);
    cmd.arg("build").arg(&p.build_input).arg("-o").arg(&out).arg("--report").arg(&report);
    cmd.args(["--max-error", &max_error_m.to_string(), "--threads", &threads.to_string()]);
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    cmd.args(&p.build_args);
    let o = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|source| BenchError::Io { path: exe.into(), source })?;
    if !o.status.success() {
        return Err(BenchError::Build {
            dem: p.label.clone(),
            max_error_m,
            status: o.status.to_string(),
            stderr: String::from_utf8_lossy(&o.stderr).trim().to_string(),
        });
    }
    let text = std::fs::read(&report).map_err(|source| BenchError::Io { path: report.clone(), source })?;
    let parsed: ChildReport =
        serde_json::from_slice(&text).map_err(|e| BenchError::Input { path: report, what: format!("report: {e}") })?;
    outputs.kept.push((dir, parsed.bytes));
    Ok(parsed)
}

/// Runs a warm-up and `runs` timed builds; returns the reports of the timed ones.
fn timed_builds(
    r: &Runs,
    p: &Prepared,
    max_error_m: f64,
    threads: usize,
    outputs: &mut Outputs,
) -> Result<Vec<ChildReport>, BenchError> {
    let config = r.config.as_deref();
    for _ in 0..r.warmup {
        build_once(&r.exe, p, config, max_error_m, threads, outputs)?;
    }
    (0..r.runs.max(1)).map(|_| build_once(&r.exe, p, config, max_error_m, threads, outputs)).collect()
}

/// The median (mean of the middle two for an even count).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Medians per stage over the reports.
fn median_stages(reports: &[ChildReport]) -> [f64; 7] {
    let all: Vec<[f64; 7]> = reports.iter().map(ChildReport::stage_seconds).collect();
    std::array::from_fn(|k| median(all.iter().map(|s| s[k]).collect()))
}

/// What every bench mode that runs `terrachunk build` children is given.
#[derive(Clone, Debug)]
pub struct Runs {
    /// The `terrachunk` binary that runs each build.
    pub exe: PathBuf,
    /// DEMs, each benchmarked on its own (a folder of `.hgt` tiles is one).
    pub dems: Vec<PathBuf>,
    /// `max_error_m` values, metres.
    pub errors: Vec<f64>,
    /// Timed runs per configuration (medians are taken over them).
    pub runs: usize,
    /// Untimed runs first.
    pub warmup: usize,
    /// Thread counts (0 = one per core).
    pub threads: Vec<usize>,
    /// Where the CSV files (and plots) go.
    pub out: PathBuf,
    /// Base settings for every build.
    pub config: Option<PathBuf>,
}

/// What [`ladder`] runs.
#[derive(Clone, Debug)]
pub struct LadderOptions {
    /// DEMs, errors, runs, threads, output.
    pub base: Runs,
    /// Which part of each DEM.
    pub cut: Cut,
    /// Also time one unconstrained greedy TIN over the grid.
    pub single_tin: bool,
    /// Add to an existing `bench.csv` instead of starting a new one.
    pub append: bool,
}

/// Runs the ladder (module comment), writes `bench.csv` and the plot, and
/// returns the new rows.
pub fn ladder(o: &LadderOptions) -> Result<Vec<Row>, BenchError> {
    check_errors(&o.base.errors)?;
    std::fs::create_dir_all(&o.base.out).map_err(|source| BenchError::Io { path: o.base.out.clone(), source })?;
    let work = scratch(&o.base.out)?;
    let mut outputs = Outputs::new(&work.0);
    let load = load_options(o.base.config.as_deref())?;
    let mut rows = Vec::new();
    for dem in &o.base.dems {
        let p = prepare(dem, o.cut, &load, &work.0)?;
        let samples = p.hf.width * p.hf.height;
        let base = Row {
            dem: p.label.clone(),
            width: p.hf.width,
            height: p.hf.height,
            samples,
            runs: o.base.runs.max(1),
            ..Row::default()
        };
        for &e in &o.base.errors {
            let mut measured = None;
            for &t in &o.base.threads {
                let reports = timed_builds(&o.base, &p, e, t, &mut outputs)?;
                // Every run writes the same bytes (tested), so the last one's
                // files stand for all of them.
                let leaves = match measured {
                    Some(m) => m,
                    None => *measured.insert(measure::leaf_errors(&outputs.last(), &p.hf)?),
                };
                let last = reports.last().expect("at least one run");
                let seconds = median_stages(&reports);
                eprintln!(
                    "terrachunk {} at {e} m on {} threads: {} leaf triangles ({:.4} % slivers, {} needles, smallest angle {:.2e}°), measured max error {:.4} m, median {:.3} s",
                    p.label,
                    last.threads,
                    leaves.leaf_triangles,
                    100.0 * leaves.shape.sliver_share(),
                    leaves.shape.needles,
                    leaves.shape.min_angle_deg,
                    leaves.errors.max_error_m,
                    seconds[6]
                );
                rows.push(
                    Row {
                        tool: "terrachunk".into(),
                        max_error_m: e,
                        levels: Some(last.levels.len()),
                        chunks: Some(last.levels.iter().map(|l| l.chunks).sum()),
                        triangles: Some(last.levels.iter().map(|l| l.triangles).sum()),
                        leaf_triangles: Some(leaves.leaf_triangles),
                        vertices: Some(last.levels.iter().map(|l| l.vertices).sum()),
                        bytes: Some(last.bytes),
                        bytes_per_sample: Some(last.bytes_per_sample),
                        measured_max_error_m: Some(leaves.errors.max_error_m),
                        measured_rms_error_m: Some(leaves.errors.rms_error_m),
                        uncovered_samples: Some(leaves.errors.uncovered_samples),
                        seconds: seconds.map(Some),
                        peak_rss_bytes: reports.iter().filter_map(|r| r.peak_rss_bytes).max(),
                        threads: last.threads,
                        ..base.clone()
                    }
                    .with_shape(&leaves.shape),
                );
            }
            if o.single_tin {
                let s = single_tin_timed(&p.hf, e, o.base.warmup, o.base.runs)?;
                eprintln!(
                    "terrachunk-single-tin {} at {e} m: {} triangles, measured max error {:.4} m, median {:.3} s",
                    p.label, s.triangles, s.errors.max_error_m, s.seconds
                );
                rows.push(single_tin_row(&base, e, &s));
            }
        }
    }
    let csv = o.base.out.join("bench.csv");
    table::write(&csv, &rows, o.append)?;
    #[cfg(feature = "plots")]
    replot(&o.base.out)?;
    Ok(rows)
}

fn check_errors(errors: &[f64]) -> Result<(), BenchError> {
    if errors.is_empty() || !errors.iter().all(|e| e.is_finite() && *e > 0.0) {
        return Err(BenchError::Usage(format!(
            "--errors {errors:?}: every max error must be a finite number of metres > 0"
        )));
    }
    Ok(())
}

/// The single greedy TIN baseline at one error.
#[derive(Clone, Copy, Debug)]
pub struct SingleTin {
    /// Triangles written (those over data).
    pub triangles: usize,
    /// Vertices.
    pub vertices: usize,
    /// Median seconds of `build_chunk` (the grid in memory, nothing written).
    pub seconds: f64,
    /// Measured against the grid.
    pub errors: ErrorStats,
    /// Its triangles' shapes in plan.
    pub shape: ShapeSummary,
}

/// One unconstrained greedy TIN over the whole grid (no chunks, no dividing
/// lines, no vertex limit): the mesher terrachunk nests, on its own.
pub fn single_tin(hf: &Heightfield, max_error_m: f64) -> Result<ChunkMesh, MeshError> {
    let filled = void_fill(hf);
    let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref());
    let spec = ChunkSpec::unconstrained(((0, hf.width as u32 - 1), (0, hf.height as u32 - 1)), max_error_m);
    build_chunk(&grid, &spec)
}

fn single_tin_timed(hf: &Heightfield, max_error_m: f64, warmup: usize, runs: usize) -> Result<SingleTin, BenchError> {
    for _ in 0..warmup {
        single_tin(hf, max_error_m)?;
    }
    let mut secs = Vec::new();
    let mut mesh = None;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let m = single_tin(hf, max_error_m)?;
        secs.push(t.elapsed().as_secs_f64());
        mesh = Some(m);
    }
    let mesh = mesh.expect("at least one run");
    let tris: Vec<[u32; 3]> = mesh.triangles.iter().zip(&mesh.kept).filter(|(_, k)| **k).map(|(t, _)| *t).collect();
    Ok(SingleTin {
        triangles: tris.len(),
        vertices: mesh.vertices.len(),
        seconds: median(secs),
        errors: measure::mesh_errors(hf, &mesh.vertices, &tris),
        shape: measure::grid_shape(&mesh.vertices, &tris, hf.spacing_m),
    })
}

fn single_tin_row(base: &Row, e: f64, s: &SingleTin) -> Row {
    let mut seconds = [None; 7];
    seconds[2] = Some(s.seconds);
    seconds[6] = Some(s.seconds);
    Row {
        tool: "terrachunk-single-tin".into(),
        max_error_m: e,
        levels: Some(1),
        chunks: Some(1),
        triangles: Some(s.triangles),
        leaf_triangles: Some(s.triangles),
        vertices: Some(s.vertices),
        measured_max_error_m: Some(s.errors.max_error_m),
        measured_rms_error_m: Some(s.errors.rms_error_m),
        uncovered_samples: Some(s.errors.uncovered_samples),
        seconds,
        threads: 1,
        ..base.clone()
    }
    .with_shape(&s.shape)
}

/// Redraws `dir/bench.png` and `dir/bench.svg` from `dir/bench.csv`; a
/// build without the `plots` feature says it cannot.
pub fn replot(dir: &Path) -> Result<(), BenchError> {
    draw(&table::read(&dir.join("bench.csv"))?, dir)
}

#[cfg(feature = "plots")]
fn draw(rows: &[table::Row], dir: &Path) -> Result<(), BenchError> {
    plot::plot(rows, &dir.join("bench.png"), &dir.join("bench.svg"))
}

#[cfg(not(feature = "plots"))]
fn draw(_: &[table::Row], _: &Path) -> Result<(), BenchError> {
    Err(BenchError::Plot("this terrachunk was built without the `plots` feature".into()))
}

/// Whether two scaling labels name the same DEM file (they differ in the window).
fn same_dem(a: &str, b: &str) -> bool {
    a.split(' ').next() == b.split(' ').next()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn build_outputs_are_kept_until_the_budget_and_the_oldest_go_first() {
        let tmp = tempfile::tempdir().unwrap();
        let mut outputs = Outputs::new(tmp.path());
        for _ in 0..3 {
            let dir = outputs.fresh();
            assert!(!dir.exists(), "every build gets a folder of its own");
            std::fs::create_dir_all(dir.join("tileset")).unwrap();
            outputs.kept.push((dir, KEEP_BYTES / 2));
        }
        assert_eq!(outputs.last(), tmp.path().join("run-3/tileset"));
        // Three halves of the budget: the oldest goes before the next build,
        // and only as many as bring it back within the budget.
        let next = outputs.fresh();
        let run = |k: u32| tmp.path().join(format!("run-{k}"));
        assert!(!run(1).exists() && run(2).exists() && run(3).exists() && next == run(4));
    }
}
