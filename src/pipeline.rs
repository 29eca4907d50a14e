//! The orchestrator: load → plan → mesh → skirt → morph → write, one call
//! each, with plain data between them (DESIGN.md, "The pipeline").
//!
//! The tree is built top-down, one level at a time: a chunk needs its
//! parent's mesh, and siblings are independent, so each level's chunks run in
//! parallel (rayon) and are collected in key order. Output therefore does not
//! depend on the thread count. Everything is written into a temporary
//! directory beside the target, renamed into place only when complete.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;
use serde::Serialize;

use crate::chunk::{Chunk, Part};
use crate::config::{Config, ConfigError};
use crate::dem::{self, DemError, LoadOptions};
use crate::heightfield::{Heightfield, void_fill};
use crate::mesh::decimate::{ChunkSpec, Grid, MAX_VERTICES, build_chunk};
use crate::mesh::skirt::build_skirt;
use crate::mesh::{ChunkMesh, MeshError, dem_normal};
use crate::output::gltf::{GlbContext, encode_glb};
use crate::output::tileset::{GridSize, MorphConvention, TileRecord, TilesetExtras, tile_uri, tileset_json};
use crate::quadtree::{ChunkKey, ChunkTree};

/// What `build` needs.
#[derive(Clone, Debug)]
pub struct BuildOptions {
    /// DEM file(s); several `.hgt` tiles (or one folder of them) make a mosaic.
    pub inputs: Vec<PathBuf>,
    /// Output directory (the tileset root).
    pub out: PathBuf,
    /// Replace an existing output directory.
    pub force: bool,
    /// Validated settings.
    pub config: Config,
    /// Draw a progress bar (when stderr is a terminal).
    pub progress: bool,
}

/// Why a build failed.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The DEM could not be used.
    #[error(transparent)]
    Dem(#[from] DemError),
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The output directory exists and `--force` was not given.
    #[error("{0}: already exists (use --force to replace it)")]
    OutputExists(PathBuf),
    /// A chunk could not meet its δ within u16 indices even with many refine levels.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

impl BuildError {
    /// Process exit code: 2 for bad input or settings, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            BuildError::Dem(_) | BuildError::Config(_) | BuildError::OutputExists(_) => 2,
            BuildError::Mesh(_) | BuildError::Io { .. } => 1,
        }
    }
}

/// Per-level figures of a build.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelReport {
    /// Level.
    pub level: u32,
    /// δ(L), metres.
    pub delta_m: f64,
    /// Chunks written.
    pub chunks: usize,
    /// Surface triangles.
    pub triangles: usize,
    /// Skirt triangles.
    pub skirt_triangles: usize,
    /// Surface vertices.
    pub vertices: usize,
    /// Largest measured error of any chunk of the level, metres.
    pub max_error_m: f64,
    /// Chunks of this level that have no children (already within max_error).
    pub leaves: usize,
}

/// What a build did and cost.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    /// Input samples (width × height).
    pub samples: usize,
    /// Samples holding data.
    pub valid_samples: usize,
    /// Grid size.
    pub grid: [usize; 2],
    /// Spacing, metres.
    pub spacing_m: [f64; 2],
    /// Levels by level.
    pub levels: Vec<LevelReport>,
    /// Bytes written (all .glb plus tileset.json).
    pub bytes: u64,
    /// Bytes per input sample.
    pub bytes_per_sample: f64,
    /// Wall seconds per stage: load, plan, mesh (incl. skirt, morph, write), index.
    pub seconds: StageTimes,
    /// Thread-seconds spent inside each per-chunk stage (summed over threads).
    pub thread_seconds: ChunkStageTimes,
    /// Peak resident memory, bytes (Linux VmHWM), if known.
    pub peak_rss_bytes: Option<u64>,
    /// Threads used.
    pub threads: usize,
    /// Levels added at the bottom (same footprint, half the δ) so that the
    /// coarser chunks fit u16 indices.
    pub refine_levels: u32,
    /// Widest deepest-level chunk, in cells (set, or chosen from the data).
    pub leaf_cells: u32,
}

/// Wall time per pipeline stage, seconds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StageTimes {
    /// Reading the DEM.
    pub load: f64,
    /// Void fill and tree plan.
    pub plan: f64,
    /// All chunks: mesh, skirt, morph, encode, write.
    pub chunks: f64,
    /// tileset.json and the final rename.
    pub index: f64,
    /// Everything.
    pub total: f64,
}

/// Thread-seconds per per-chunk stage.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ChunkStageTimes {
    /// Greedy insertion.
    pub mesh: f64,
    /// Normals, morph targets and skirts.
    pub skirt_morph: f64,
    /// glTF encoding and file writes.
    pub write: f64,
}

/// Runs the whole pipeline. On error nothing is left at `opts.out`.
pub fn build(opts: &BuildOptions) -> Result<Report, BuildError> {
    let t0 = Instant::now();
    opts.config.validate()?;
    if opts.out.exists() && !opts.force {
        return Err(BuildError::OutputExists(opts.out.clone()));
    }
    let cfg = &opts.config;
    let hf =
        dem::load(&opts.inputs, &LoadOptions { vertical_scale: Some(cfg.vertical_scale), spacing_m: cfg.spacing_m })?;
    let t_load = t0.elapsed();
    let threads = if cfg.threads == 0 { rayon::current_num_threads() } else { cfg.threads };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");

    let tmp = temp_dir_for(&opts.out);
    let result = pool.install(|| build_into(&hf, opts, &tmp));
    let (mut report, tree, records, t_plan, t_chunks) = match result {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    let t_idx = Instant::now();
    let finish = || -> Result<u64, BuildError> {
        let extras = tileset_extras(&hf, opts, &tree);
        let doc = tileset_json(&tree, &records, &extras);
        let bytes = serde_json::to_vec_pretty(&doc).expect("JSON of plain values");
        let path = tmp.join("tileset.json");
        std::fs::write(&path, &bytes).map_err(|source| BuildError::Io { path, source })?;
        if opts.out.exists() {
            std::fs::remove_dir_all(&opts.out).map_err(|source| BuildError::Io { path: opts.out.clone(), source })?;
        }
        std::fs::rename(&tmp, &opts.out).map_err(|source| BuildError::Io { path: opts.out.clone(), source })?;
        Ok(bytes.len() as u64)
    };
    let index_bytes = match finish() {
        Ok(b) => b,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    report.bytes += index_bytes;
    report.bytes_per_sample = report.bytes as f64 / report.samples as f64;
    report.threads = threads;
    report.seconds = StageTimes {
        load: t_load.as_secs_f64(),
        plan: t_plan.as_secs_f64(),
        chunks: t_chunks.as_secs_f64(),
        index: t_idx.elapsed().as_secs_f64(),
        total: t0.elapsed().as_secs_f64(),
    };
    report.peak_rss_bytes = peak_rss();
    Ok(report)
}

type Built = (Report, ChunkTree, Vec<TileRecord>, Duration, Duration);

fn build_into(hf: &Heightfield, opts: &BuildOptions, tmp: &Path) -> Result<Built, BuildError> {
    let t = Instant::now();
    let filled = void_fill(hf);
    let grid = Grid { width: hf.width, height: hf.height, heights: &hf.heights, filled: filled.as_deref() };
    let t_plan = t.elapsed();
    let t = Instant::now();
    // A coarse chunk that cannot meet its δ in 65 535 vertices (noise, huge
    // relief against a small error) gets a larger δ: one more level at the
    // bottom refines the leaves in place, and every δ above doubles.
    let leaf_cells = match opts.config.leaf_cells {
        Some(c) => c,
        None => auto_leaf_cells(&grid, opts.config.max_error_m),
    };
    let mut refine = 0;
    loop {
        let tree = ChunkTree::plan(hf.width, hf.height, opts.config.max_error_m, leaf_cells, refine);
        let _ = std::fs::remove_dir_all(tmp);
        std::fs::create_dir_all(tmp).map_err(|source| BuildError::Io { path: tmp.into(), source })?;
        match build_levels(hf, &grid, &tree, opts, tmp) {
            Ok((mut report, records)) => {
                report.refine_levels = refine;
                report.leaf_cells = leaf_cells;
                return Ok((report, tree, records, t_plan, t.elapsed()));
            }
            Err(BuildError::Mesh(_)) if refine < 24 => refine += 1,
            Err(e) => return Err(e),
        }
    }
}

/// Surface vertices an average chunk should hold when `leaf_cells` is left
/// to the data: inside the 1 000–8 000 that keeps draw calls few and chunks
/// small enough to cull and page finely.
pub const CHUNK_VERTICES: f64 = 4000.0;

/// The leaf width, in cells, whose tree has about [`CHUNK_VERTICES`]
/// vertices per chunk on average. A level of δ holds about (valid samples ×
/// vertices per sample at δ) vertices whatever its chunking, so the average
/// follows from the planned tree and the density at each level's δ, measured
/// with one greedy TIN on each of up to 4 × 4 windows of 64 × 64 cells
/// spread over the grid.
pub fn auto_leaf_cells(grid: &Grid, max_error_m: f64) -> u32 {
    let cells = 64.min(grid.width - 1).min(grid.height - 1);
    let starts = |n: usize| {
        let k = ((n - 1) / cells).clamp(1, 4);
        (0..k).map(move |w| if k == 1 { 0 } else { w * (n - 1 - cells) / (k - 1) }).collect::<Vec<_>>()
    };
    let mut windows = Vec::new();
    for &z in &starts(grid.height) {
        for &x in &starts(grid.width) {
            let valid = (z..=z + cells)
                .map(|i| {
                    grid.heights[i * grid.width + x..=i * grid.width + x + cells].iter().filter(|h| !h.is_nan()).count()
                })
                .sum::<usize>();
            if valid > 0 {
                windows.push(((x as u32, (x + cells) as u32), (z as u32, (z + cells) as u32), valid));
            }
        }
    }
    let density = |delta_m: f64| {
        let (mut vertices, mut samples) = (0usize, 0usize);
        for &(xs, zs, valid) in &windows {
            let spec = ChunkSpec {
                key: ChunkKey { level: 0, x: 0, y: 0 },
                footprint: (xs, zs),
                delta_m,
                parent: None,
                max_vertices: usize::MAX,
                dividing_lines: false,
            };
            if let Ok(mesh) = build_chunk(grid, &spec) {
                vertices += mesh.vertices.len();
                samples += valid;
            }
        }
        if samples == 0 { 0.0 } else { vertices as f64 / samples as f64 }
    };
    let valid = grid.heights.iter().filter(|h| !h.is_nan()).count() as f64;
    // Density by k, for δ = max_error_m · 2^k.
    let mut by_k: Vec<Option<f64>> = vec![None; 32];
    let mut average = |c: u32| {
        let tree = ChunkTree::plan(grid.width, grid.height, max_error_m, c, 0);
        let levels = tree.delta_m.len();
        let chunks: usize = (0..levels).map(|l| tree.xs[l].len() * tree.zs[l].len()).sum();
        let vertices: f64 = (0..levels)
            .map(|l| {
                let k = (levels - 1 - l).min(31);
                *by_k[k].get_or_insert_with(|| density(tree.delta_m[l])) * valid
            })
            .sum();
        vertices / chunks as f64
    };
    let mut best = (f64::INFINITY, 250);
    for c in 32..=250 {
        let miss = (average(c) / CHUNK_VERTICES).ln().abs();
        if miss < best.0 {
            best = (miss, c);
        }
    }
    best.1
}

struct Timers {
    mesh: AtomicU64,
    skirt_morph: AtomicU64,
    write: AtomicU64,
}

impl Timers {
    fn add(a: &AtomicU64, since: Instant) {
        a.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}

fn build_levels(
    hf: &Heightfield,
    grid: &Grid,
    tree: &ChunkTree,
    opts: &BuildOptions,
    tmp: &Path,
) -> Result<(Report, Vec<TileRecord>), BuildError> {
    let cfg = &opts.config;
    let timers = Timers { mesh: AtomicU64::new(0), skirt_morph: AtomicU64::new(0), write: AtomicU64::new(0) };
    let generator = format!("terrachunk {}", env!("CARGO_PKG_VERSION"));
    let ctx = GlbContext { spacing_m: hf.spacing_m, generator: &generator, vertex_cache: cfg.vertex_cache };
    let has_voids = grid.filled.is_some();
    let mut report = Report {
        samples: hf.width * hf.height,
        valid_samples: hf.valid_count(),
        grid: [hf.width, hf.height],
        spacing_m: hf.spacing_m,
        ..Report::default()
    };
    let mut records = Vec::new();
    let mut bytes = AtomicU64::new(0);
    // Each level's work: groups of sibling keys with their parent's mesh,
    // which is dropped as soon as its children are built (memory holds about
    // one level of meshes, not two).
    let mut work: Vec<(Option<ChunkMesh>, Vec<ChunkKey>)> =
        tree.roots().into_iter().filter(|&k| !has_voids || has_valid(grid, tree, k)).map(|k| (None, vec![k])).collect();
    while !work.is_empty() {
        let level = work[0].1[0].level;
        let delta = tree.delta_m[level as usize];
        let count: usize = work.iter().map(|g| g.1.len()).sum();
        let bar = progress_bar(opts.progress, count as u64, level, tree.depth());
        let build_one = |key: ChunkKey, parent: Option<&ChunkMesh>| {
            let t = Instant::now();
            let spec = ChunkSpec {
                key,
                footprint: tree.footprint(key),
                delta_m: delta,
                parent,
                max_vertices: MAX_VERTICES,
                dividing_lines: tree.splits(level),
            };
            let mesh = build_chunk(grid, &spec)?;
            Timers::add(&timers.mesh, t);
            let t = Instant::now();
            let margin = tree.delta_m[(level as usize).saturating_sub(2)];
            let chunk = assemble(grid, hf.spacing_m, &mesh, margin);
            Timers::add(&timers.skirt_morph, t);
            let t = Instant::now();
            let glb = encode_glb(&chunk, &ctx);
            let path = tmp.join(tile_uri(key));
            std::fs::create_dir_all(path.parent().expect("tile path has a parent"))
                .and_then(|_| std::fs::write(&path, &glb))
                .map_err(|source| BuildError::Io { path: path.clone(), source })?;
            bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
            Timers::add(&timers.write, t);
            bar.inc(1);
            let (min, max) = bounds(&chunk);
            let figures = LevelFigures {
                triangles: chunk.surface.triangle_count(),
                skirt_triangles: chunk.skirt.triangle_count(),
                vertices: chunk.surface.positions.len(),
            };
            // A leaf's mesh is dropped here, not kept for a level that will not need it.
            let leaf = mesh.meets(cfg.max_error_m) || tree.children(key).is_empty();
            let (max_error_m, relief_m) = (mesh.max_error_m, mesh.relief_m);
            let mesh = if leaf { ChunkMesh { max_error_m, relief_m, ..ChunkMesh::empty(key) } } else { mesh };
            Ok((mesh, leaf, figures, TileRecord { key, min, max, delta_m: delta }))
        };
        let results: Vec<Result<(ChunkMesh, bool, LevelFigures, TileRecord), BuildError>> = std::mem::take(&mut work)
            .into_par_iter()
            .flat_map_iter(|(parent, keys)| {
                let out: Vec<_> = keys.par_iter().map(|&k| build_one(k, parent.as_ref())).collect();
                drop(parent);
                out
            })
            .collect();
        bar.finish_and_clear();
        let mut lr = LevelReport { level, delta_m: delta, ..LevelReport::default() };
        let mut next = Vec::new();
        for r in results {
            let (mesh, leaf, figures, rec) = r?;
            lr.chunks += 1;
            lr.triangles += figures.triangles;
            lr.skirt_triangles += figures.skirt_triangles;
            lr.vertices += figures.vertices;
            lr.max_error_m = lr.max_error_m.max(mesh.max_error_m);
            records.push(rec);
            let kids = if leaf { Vec::new() } else { tree.children(mesh.key) };
            if kids.is_empty() {
                lr.leaves += 1;
            }
            let kids: Vec<ChunkKey> = kids.into_iter().filter(|&c| !has_voids || has_valid(grid, tree, c)).collect();
            if !kids.is_empty() {
                next.push((Some(mesh), kids));
            }
        }
        report.levels.push(lr);
        work = next;
    }
    records.sort_by_key(|r| r.key);
    report.bytes = *bytes.get_mut();
    let s = |a: &AtomicU64| a.load(Ordering::Relaxed) as f64 * 1e-9;
    report.thread_seconds =
        ChunkStageTimes { mesh: s(&timers.mesh), skirt_morph: s(&timers.skirt_morph), write: s(&timers.write) };
    Ok((report, records))
}

/// What a level's summary needs from one written chunk.
struct LevelFigures {
    triangles: usize,
    skirt_triangles: usize,
    vertices: usize,
}

/// Surface (written triangles only) with normals and morph targets, then skirts.
/// Public for the `.glb` micro-benchmark (`benches/stages.rs`).
pub fn assemble(grid: &Grid, spacing: [f64; 2], mesh: &ChunkMesh, margin_m: f64) -> Chunk {
    let mut remap = vec![u32::MAX; mesh.vertices.len()];
    let mut used = Vec::new();
    let mut indices = Vec::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if !mesh.kept[t] {
            continue;
        }
        for &v in tri {
            if remap[v as usize] == u32::MAX {
                remap[v as usize] = used.len() as u32;
                used.push(mesh.vertices[v as usize]);
            }
            indices.push(remap[v as usize]);
        }
    }
    let parent_h: Vec<f64> = used.iter().map(|v| v.ph).collect();
    let surface = Part {
        positions: used.iter().map(|v| [v.x * spacing[0], v.h, v.z * spacing[1]]).collect(),
        normals: used.iter().map(|v| dem_normal(grid, spacing, v.x, v.z)).collect(),
        morph_dy: used.iter().zip(&parent_h).map(|(v, p)| p - v.h).collect(),
        indices,
    };
    let grid_xz: Vec<(f64, f64)> = used.iter().map(|v| (v.x, v.z)).collect();
    let skirt = build_skirt(grid, mesh.footprint, &surface, &grid_xz, &parent_h, margin_m);
    Chunk {
        key: mesh.key,
        footprint: mesh.footprint,
        delta_m: mesh.delta_m,
        max_error_m: mesh.max_error_m,
        surface,
        skirt,
    }
}

fn bounds(c: &Chunk) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in c.surface.positions.iter().chain(&c.skirt.positions) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

fn has_valid(grid: &Grid, tree: &ChunkTree, k: ChunkKey) -> bool {
    let ((x0, x1), (z0, z1)) = tree.footprint(k);
    (z0..=z1).any(|i| {
        let row = &grid.heights[i as usize * grid.width..];
        (x0..=x1).any(|j| !row[j as usize].is_nan())
    })
}

fn tileset_extras(hf: &Heightfield, opts: &BuildOptions, tree: &ChunkTree) -> TilesetExtras {
    TilesetExtras {
        generator: format!("terrachunk {}", env!("CARGO_PKG_VERSION")),
        grid: GridSize { width: hf.width as u32, height: hf.height as u32 },
        spacing_m: hf.spacing_m,
        vertical_scale: opts.config.vertical_scale,
        max_error_m: opts.config.max_error_m,
        tau_max_px: opts.config.tau_max_px,
        levels: tree.depth() + 1,
        delta_m: tree.delta_m.clone(),
        source: opts.inputs.iter().map(|p| p.display().to_string()).collect(),
        georef: hf.georef.clone(),
        morph: MorphConvention {
            target: "parent".into(),
            delta: "POSITION y offset: base + delta lies on the parent chunk's surface; x and z offsets 0; \
                    skirt bottom vertices have delta 0"
                .into(),
            schedule: "blend weight toward the parent w = clamp(tau/rho - 1, 0, 1) keeps the screen error <= tau; \
                       Ulrich's t = clamp(2 rho/tau - 1, 0, 1) (w = 1 - t) can reach 9/8 tau"
                .into(),
        },
        skirt: "bottom = lowest valid sample, vertex or parent height between the neighbouring border vertices, \
                minus delta(max(L-2, 0)): below any neighbour of level >= L-1 in any morph state"
            .into(),
    }
}

fn progress_bar(enabled: bool, len: u64, level: u32, depth: u32) -> indicatif::ProgressBar {
    if !enabled {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} chunks {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(format!("level {level}/{depth}"));
    bar
}

/// A sibling of `out` that a failed or killed run leaves instead of a partial tileset.
fn temp_dir_for(out: &Path) -> PathBuf {
    let name = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    parent.join(format!(".{name}.terrachunk-tmp-{}", std::process::id()))
}

/// Peak resident set size of this process, bytes (Linux only).
pub fn peak_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
