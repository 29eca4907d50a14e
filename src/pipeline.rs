//! The orchestrator: load → plan → mesh → skirt → morph → texture → write,
//! one call each, with plain data between them (DESIGN.md, "The pipeline").
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
use crate::config::{Config, ConfigError, Mesher, dense_leaf_cells};
use crate::dem::{self, DemError, LoadOptions};
use crate::geodesy::Placement;
use crate::heightfield::{Heightfield, void_fill};
use crate::mesh::decimate::{CUT_SHARE, ChunkSpec, DividingLines, Grid, U16_INDEXED, build_chunk};
use crate::mesh::rtin::{self, Rtin};
use crate::mesh::skirt::build_skirt;
use crate::mesh::{ChunkMesh, MeshError, dem_normal};
use crate::output::compress::{Quantization, QuantizeError};
use crate::output::gltf::{GlbContext, encode_glb};
use crate::output::tileset::{GridSize, MorphConvention, TileRecord, TilesetExtras, tile_uri, tileset_json};
use crate::progress;
use crate::quadtree::estimate::{Estimate, Planned, plan_tree};
use crate::quadtree::{ChunkKey, ChunkTree, MAX_REFINE_LEVELS};
use crate::texture::source::{generate, generated_to_px, load_image};
use crate::texture::{ColourSource, Limit, NormalSource, TextureError, TextureExtras, TextureSource, Texturer};

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
    /// Where the chunks' colour comes from (default: generated from the DEM).
    pub texture: TextureSource,
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
    /// A chunk could not meet its δ within `max_chunk_vertices` even with many refine levels.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The texture image could not be used, or a tile could not be encoded.
    #[error(transparent)]
    Texture(#[from] TextureError),
    /// The mesher returned a chunk farther from a sample than its δ: a bug,
    /// refused rather than written as a tileset that breaks its promise.
    #[error(
        "chunk {level}/{x}/{y}: the mesher left a sample {error_m} m from the surface, beyond the chunk's \
         δ {delta_m} m (a terrachunk bug: please report it with the DEM and settings)"
    )]
    MissedDelta {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// What the mesher measured, metres.
        error_m: f64,
        /// δ(L), metres.
        delta_m: f64,
    },
    /// A `leaf_cells` setting above [`dense_leaf_cells`] left a leaf that
    /// cannot meet its δ within `max_chunk_vertices` (refine levels keep
    /// the leaf's footprint, so they cannot help).
    #[error(
        "leaf_cells = {leaf_cells}: {source}; leaves of at most {dense} cells always fit \
         (or leave leaf_cells unset to choose from the data)"
    )]
    LeafTooWide {
        /// The setting.
        leaf_cells: u32,
        /// The widest leaf that always fits, [`dense_leaf_cells`].
        dense: u32,
        /// The chunk that did not fit.
        source: MeshError,
    },
    /// Vertex data cannot be quantized as `compress` asks.
    #[error(transparent)]
    Quantize(#[from] QuantizeError),
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
            BuildError::LeafTooWide { .. } => 2,
            BuildError::Texture(TextureError::Encode { .. }) => 1,
            BuildError::Texture(_) => 2,
            BuildError::Quantize(QuantizeError::Range { .. }) => 1,
            BuildError::Quantize(_) => 2,
            BuildError::Mesh(_) | BuildError::MissedDelta { .. } | BuildError::Io { .. } => 1,
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
    /// Bytes of the level's .glb files.
    pub bytes: u64,
    /// The level's texture tiles (absent when untextured).
    pub texture: Option<LevelTexture>,
}

/// Per-level figures of the texture tiles.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelTexture {
    /// Largest T_g (texel spacing on the ground, either axis) of the level's
    /// chunks, metres.
    pub texel_m: f64,
    /// δ(L)/τ_max, metres: the bound T_g should keep.
    pub bound_m: f64,
    /// Chunks whose tile the bound sized (T_g ≤ δ/τ_max, power of two).
    pub limited_by_bound: usize,
    /// Chunks whose tile the source's resolution stopped (as fine as the source).
    pub limited_by_source: usize,
    /// Chunks whose tile `max_texture_px` stopped.
    pub limited_by_cap: usize,
    /// Chunks with T_g > δ/τ_max.
    pub over_bound: usize,
    /// Largest tile, texels `[across, down]`.
    pub largest: [u32; 2],
    /// Texels written, all chunks of the level (colour only).
    pub texels: u64,
    /// Bytes of encoded images (colour and normal map) in the level's .glb files.
    pub texture_bytes: u64,
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
    /// Wall seconds per stage: load, plan, texture source, chunks (mesh,
    /// skirt, morph, texture, write), index.
    pub seconds: StageTimes,
    /// Thread-seconds spent inside each per-chunk stage (summed over threads).
    pub thread_seconds: ChunkStageTimes,
    /// Peak resident memory, bytes (Linux VmHWM), if known.
    pub peak_rss_bytes: Option<u64>,
    /// Threads used.
    pub threads: usize,
    /// Levels added at the bottom (same footprint, half the δ) so that the
    /// coarser chunks fit `max_chunk_vertices`.
    pub refine_levels: u32,
    /// Of `refine_levels`, those taken from the estimate alone (a top chunk
    /// surely too dense with fewer: [`Estimate::refine_levels`]), not from
    /// an attempt.
    pub refine_estimated: u32,
    /// Wall seconds of the attempts with fewer refine levels that stopped at
    /// a chunk too dense for `max_chunk_vertices` (part of `seconds.chunks`).
    pub discarded_s: f64,
    /// The bound on a deepest-level chunk's width, in cells (set, or chosen
    /// from the data).
    pub leaf_cells: u32,
    /// The widest deepest-level chunk, in cells (at most `leaf_cells`: the
    /// tree halves the grid, so California's 8 400 cells with `leaf_cells =
    /// 256` make leaves of 131 × 150).
    pub leaf_width_cells: u32,
    /// The top-level footprints' count (those with no valid sample
    /// included: they make no chunk) and the widest, in cells (one unless
    /// the grid is elongated or `root_cells` is set).
    pub roots: (usize, u32),
    /// Quantized output: chunks meshed again with a wider margin next to
    /// cut points, so that rounding those sideways to the grid keeps δ.
    pub remeshed_for_cut_points: usize,
    /// Quantized output: chunks that miss δ as written even with no error
    /// left next to their cut points (each written at the margin that came
    /// closest; `verify` reports them).
    pub over_delta_as_written: Vec<OverDelta>,
}

/// A chunk whose error as written is beyond its δ.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct OverDelta {
    /// `L/x/y`.
    pub chunk: String,
    /// Its error as written, metres.
    pub error_m: f64,
    /// Its level's δ, metres.
    pub delta_m: f64,
}

/// Wall time per pipeline stage, seconds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StageTimes {
    /// Reading the DEM.
    pub load: f64,
    /// Void fill and tree plan (the leaf width and refine levels
    /// [`Estimate`] measures on sample windows).
    pub plan: f64,
    /// Loading or generating the texture source. A generated one is made
    /// while the plan runs, so the two overlap (`total` is wall time).
    pub texture_source: f64,
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
    /// Quantized output only: each chunk measured again as it will be
    /// written ([`crate::output::compress::Quantization::cut_error`]).
    pub check: f64,
    /// Resampling and encoding texture tiles.
    pub texture: f64,
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
    let (mut report, tree, records, texture, [t_plan, t_source, t_chunks]) = match result {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    let t_idx = Instant::now();
    let finish = || -> Result<u64, BuildError> {
        let mut extras = tileset_extras(&hf, opts, &tree);
        extras.texture = texture;
        let doc = tileset_json(&tree, &records, &extras);
        // Compact: a client reads the whole index before it draws anything,
        // and indentation was four fifths of it (California at 1 m, 27 270
        // tiles: 42.0 MB pretty, 7.9 MB compact). `jq . tileset.json` reads it.
        let bytes = serde_json::to_vec(&doc).expect("JSON of plain values");
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
        texture_source: t_source.as_secs_f64(),
        chunks: t_chunks.as_secs_f64(),
        index: t_idx.elapsed().as_secs_f64(),
        total: t0.elapsed().as_secs_f64(),
    };
    report.peak_rss_bytes = peak_rss();
    Ok(report)
}

type Built = (Report, ChunkTree, Vec<TileRecord>, Option<TextureExtras>, [Duration; 3]);

fn build_into(hf: &Heightfield, opts: &BuildOptions, tmp: &Path) -> Result<Built, BuildError> {
    let t = Instant::now();
    let filled = void_fill(hf);
    let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref());
    let t_fill = t.elapsed();
    // The plan needs only the colour source's scale, which a generated
    // map's size gives before it is made: the map is generated while the
    // plan's estimate meshes its windows (both in parallel inside, each
    // filling the other's idle moments). An image is loaded first.
    let plan = |to_px| timed(|| plan_tree(hf, &grid, &opts.config, to_px));
    let (colour, (plan, t_estimate)) = match &opts.texture {
        TextureSource::None => (None, plan(None)),
        TextureSource::Image(path) => {
            let (colour, t) = timed(|| load_image(path, hf));
            let colour = colour?;
            let to_px = colour.to_px;
            (Some((colour, t)), plan(Some(to_px)))
        }
        TextureSource::Generated => {
            let ((colour, t), plan) = rayon::join(
                || timed(|| generate(hf, filled.as_deref(), &opts.config)),
                || plan(Some(generated_to_px(hf, &opts.config))),
            );
            (Some((colour?, t)), plan)
        }
    };
    let (colour, t_source) = colour.map_or((None, Duration::ZERO), |(c, t)| (Some(c), t));
    let t_plan = t_fill + t_estimate;
    // A coarse chunk that cannot meet its δ in `max_chunk_vertices` (noise, huge
    // relief against a small error) gets a larger δ: one more level at the
    // bottom refines the leaves in place, and every δ above doubles.
    let Planned { mut estimate, mut leaf_cells, mut refine } = plan;
    let mut estimated = refine;
    let dense = dense_leaf_cells(opts.config.max_chunk_vertices);
    let t = Instant::now();
    let attempts = Instant::now();
    loop {
        let tree = match opts.config.mesher {
            Mesher::Tin => estimate.tree(leaf_cells, refine),
            Mesher::Rtin => {
                rtin::plan(hf.width, hf.height, opts.config.max_error_m, opts.config.root_cells, leaf_cells, refine)
            }
        };
        let _ = std::fs::remove_dir_all(tmp);
        std::fs::create_dir_all(tmp).map_err(|source| BuildError::Io { path: tmp.into(), source })?;
        let discarded = attempts.elapsed();
        let lone_parts = lone_parts(&tree, &mut estimate);
        match build_levels(hf, &grid, &tree, colour.as_ref(), opts, tmp, lone_parts) {
            Ok((mut report, records, texture)) => {
                report.refine_levels = refine;
                report.refine_estimated = estimated;
                report.discarded_s = discarded.as_secs_f64();
                report.leaf_cells = leaf_cells;
                report.leaf_width_cells = tree.widest_cells(tree.depth()).into_iter().max().unwrap_or(0);
                report.roots = (tree.roots().len(), tree.widest_cells(0).into_iter().max().unwrap_or(0));
                return Ok((report, tree, records, texture, [t_plan, t_source, t.elapsed()]));
            }
            // Leaves wider than a dense leaf may be: refine levels keep their
            // footprint and cannot help, narrower leaves do.
            Err(BuildError::Mesh(_)) if opts.config.leaf_cells.is_none() && leaf_cells > dense => {
                (leaf_cells, refine) = estimate.leaf_cells(dense);
                estimated = refine;
            }
            // A chosen wide leaf that is too dense at max_error_m: the last
            // level always has the leaves' footprint and δ, so refine levels
            // cannot help.
            Err(BuildError::Mesh(source @ MeshError::TooDense { level, .. }))
                if leaf_cells > dense && level == tree.depth() =>
            {
                return Err(BuildError::LeafTooWide { leaf_cells, dense, source });
            }
            Err(BuildError::Mesh(_)) if refine < MAX_REFINE_LEVELS => refine += 1,
            Err(e) => return Err(e),
        }
    }
}

/// What `f` returns and how long it took.
fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let t = Instant::now();
    (f(), t.elapsed())
}

struct Timers {
    mesh: AtomicU64,
    skirt_morph: AtomicU64,
    check: AtomicU64,
    texture: AtomicU64,
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
    colour: Option<&ColourSource>,
    opts: &BuildOptions,
    tmp: &Path,
    lone_parts: bool,
) -> Result<(Report, Vec<TileRecord>, Option<TextureExtras>), BuildError> {
    let cfg = &opts.config;
    let generator = format!("terrachunk {}", env!("CARGO_PKG_VERSION"));
    let planned: usize = (0..tree.delta_m.len()).map(|l| tree.xs[l].len() * tree.zs[l].len()).sum();
    let normals = (cfg.normal_map && colour.is_some()).then(|| NormalSource::new(grid, hf.spacing_m));
    let texturer = colour.map(|c| Texturer::new(c, normals.as_ref(), tree, hf.spacing_m, cfg));
    let quantization = cfg.compress.quantizes().then(|| Quantization::plan(hf, tree, cfg.max_error_m)).transpose()?;
    let t = Instant::now();
    let rtin = (cfg.mesher == Mesher::Rtin).then(|| Rtin::new(grid, tree, quantization.as_ref().map(|q| q.step_y_m)));
    let run = Run {
        hf,
        grid,
        tree,
        opts,
        tmp,
        ctx: GlbContext {
            spacing_m: hf.spacing_m,
            generator: &generator,
            vertex_cache: cfg.triangle_order(),
            quantization: quantization.as_ref(),
            meshopt: cfg.compress.meshopt(),
            normals: cfg.normal_encoding(),
        },
        texturer: texturer.as_ref(),
        lone_parts,
        rtin: rtin.as_ref(),
        timers: Timers {
            mesh: AtomicU64::new(0),
            skirt_morph: AtomicU64::new(0),
            check: AtomicU64::new(0),
            texture: AtomicU64::new(0),
            write: AtomicU64::new(0),
        },
        bytes: AtomicU64::new(0),
        failed: std::sync::atomic::AtomicBool::new(false),
        bar: progress::bar(opts.progress, planned as u64, "chunks at most"),
    };
    Timers::add(&run.timers.mesh, t);
    let chunks = run.all_chunks();
    run.bar.finish_and_clear();
    let mut chunks = chunks?;
    chunks.sort_by_key(|c| c.record.key);
    let mut report = Report {
        samples: hf.width * hf.height,
        valid_samples: hf.valid_count(),
        grid: [hf.width, hf.height],
        spacing_m: hf.spacing_m,
        ..Report::default()
    };
    for c in &chunks {
        let level = c.record.key.level;
        let delta = tree.delta_m[level as usize];
        if report.levels.last().is_none_or(|l| l.level != level) {
            report.levels.push(LevelReport { level, delta_m: delta, ..LevelReport::default() });
        }
        let lr = report.levels.last_mut().expect("pushed above");
        let figures = &c.figures;
        lr.chunks += 1;
        lr.triangles += figures.triangles;
        lr.skirt_triangles += figures.skirt_triangles;
        lr.vertices += figures.vertices;
        lr.bytes += figures.bytes;
        if let Some(tf) = &figures.texture {
            let bound_m = delta / cfg.tau_max_px;
            let lt = lr.texture.get_or_insert_with(|| LevelTexture { bound_m, ..LevelTexture::default() });
            lt.texel_m = lt.texel_m.max(tf.texel_m);
            match tf.limit {
                Limit::Bound => lt.limited_by_bound += 1,
                Limit::Source => lt.limited_by_source += 1,
                Limit::MaxTexturePx => lt.limited_by_cap += 1,
            }
            lt.over_bound += usize::from(tf.texel_m > bound_m * (1.0 + 1e-9));
            lt.largest = [0, 1].map(|a| lt.largest[a].max(tf.texels[a]));
            lt.texels += u64::from(tf.texels[0]) * u64::from(tf.texels[1]);
            lt.texture_bytes += tf.bytes;
        }
        lr.max_error_m = lr.max_error_m.max(c.max_error_m);
        lr.leaves += usize::from(c.leaf);
        report.remeshed_for_cut_points += usize::from(c.remeshed);
        if let Some(e) = c.over_delta_m {
            let k = c.record.key;
            let chunk = format!("{}/{}/{}", k.level, k.x, k.y);
            report.over_delta_as_written.push(OverDelta { chunk, error_m: e, delta_m: delta });
        }
    }
    report.bytes = run.bytes.load(Ordering::Relaxed);
    let s = |a: &AtomicU64| a.load(Ordering::Relaxed) as f64 * 1e-9;
    let t = &run.timers;
    report.thread_seconds = ChunkStageTimes {
        mesh: s(&t.mesh),
        skirt_morph: s(&t.skirt_morph),
        check: s(&t.check),
        texture: s(&t.texture),
        write: s(&t.write),
    };
    let generated = opts.texture == TextureSource::Generated;
    Ok((report, chunks.into_iter().map(|c| c.record).collect(), texturer.map(|t| t.extras(cfg, generated))))
}

fn is_cancel(e: &BuildError) -> bool {
    matches!(e, BuildError::Mesh(MeshError::Cancelled))
}

/// The first error in `results` that is not a cancellation (which another
/// chunk's failure caused), taken out.
fn take_error<T>(results: &mut Vec<Result<T, BuildError>>) -> Option<BuildError> {
    let k = results.iter().position(|r| r.as_ref().is_err_and(|e| !is_cancel(e)))?;
    results.swap_remove(k).err()
}

/// The most chunks a level may have to be built level-first
/// ([`Run::all_chunks`]): at most this many meshes are kept at once. Real
/// terrain's top chunks are sparse (California's 2 roots at 1 m: 254 000
/// and 193 000 vertices, the 8 below them about 180 000 each); noise at a
/// small error, at most `max_chunk_vertices` each, is the worst case.
const LEVEL_FIRST_CHUNKS: usize = 16;

/// What one chunk adds to the report and the index.
struct BuiltChunk {
    record: TileRecord,
    figures: LevelFigures,
    max_error_m: f64,
    /// Meshed again for its cut points (quantized output), and, where even
    /// that missed δ, its error as written.
    remeshed: bool,
    over_delta_m: Option<f64>,
    /// No children: already within max_error, or at the deepest level.
    leaf: bool,
}

/// A chunk meshed and assembled, not yet written.
struct Meshed {
    chunk: Chunk,
    remeshed: bool,
    over_delta_m: Option<f64>,
    max_error_m: f64,
    leaf: bool,
}

/// One build's shared state.
struct Run<'a> {
    hf: &'a Heightfield,
    grid: &'a Grid<'a>,
    tree: &'a ChunkTree,
    opts: &'a BuildOptions,
    tmp: &'a Path,
    ctx: GlbContext<'a>,
    texturer: Option<&'a Texturer<'a>>,
    /// The lone chunks are filled by parts ([`lone_parts`]).
    lone_parts: bool,
    /// The bintree's error field, where it meshes the chunks.
    rtin: Option<&'a Rtin>,
    timers: Timers,
    bytes: AtomicU64,
    /// Set on the first error, so the other subtrees stop early.
    failed: std::sync::atomic::AtomicBool,
    bar: indicatif::ProgressBar,
}

impl Run<'_> {
    /// Whether chunk `k` has any data to mesh.
    fn worth_building(&self, k: ChunkKey) -> bool {
        self.grid.filled.is_none() || has_valid(self.grid, self.tree, k)
    }

    /// Builds every chunk. A chunk whose footprint holds more samples than
    /// one mesh may have vertices can fail to meet its δ, and then the whole
    /// build starts again with one more level ([`build_into`]). Such chunks
    /// fail most often at the top, so the top levels are built first, one
    /// level at a time, while their chunks hold more samples than u16
    /// indices could (whatever `max_chunk_vertices`) and are few enough
    /// that keeping a level's meshes costs little ([`LEVEL_FIRST_CHUNKS`]):
    /// a failure there wastes only them, not whole subtrees built depth
    /// first before it, and a level's textures and files are written while
    /// the next is meshed. (Bounding this by `max_chunk_vertices` instead
    /// left Fuji's 513² grid with no level-first level at 2^20 − 1: its
    /// root then wrote while the other thread waited, 11 % slower at 1 m.) Below them the tree is built depth first, subtrees in
    /// parallel: a chunk's mesh lives only while its children are built, so
    /// memory holds a few root-to-leaf paths rather than whole levels.
    fn all_chunks(&self) -> Result<Vec<BuiltChunk>, BuildError> {
        let tree = self.tree;
        let level_first = (0..=tree.depth())
            .take_while(|&l| {
                let [wx, wz] = tree.widest_cells(l).map(|c| c as usize + 1);
                let l = l as usize;
                wx * wz > U16_INDEXED && tree.xs[l].len() * tree.zs[l].len() <= LEVEL_FIRST_CHUNKS
            })
            .count();
        let mut done = Vec::new();
        // (parent mesh, its children to build)
        let mut frontier: Vec<(Option<ChunkMesh>, Vec<ChunkKey>)> =
            vec![(None, tree.roots().into_iter().filter(|&k| self.worth_building(k)).collect())];
        // A level's chunks are textured and written while the next level is
        // meshed: its meshes are all the next level needs (the root alone
        // would otherwise keep the other threads waiting while it writes).
        let mut unwritten: Vec<Meshed> = Vec::new();
        let write_all = |unwritten: Vec<Meshed>| -> Vec<Result<BuiltChunk, BuildError>> {
            unwritten.into_par_iter().map(|m| self.write_chunk(m).inspect_err(|_| self.fail())).collect()
        };
        for _ in 0..level_first {
            let jobs: Vec<(Option<&ChunkMesh>, ChunkKey)> =
                frontier.iter().flat_map(|(p, kids)| kids.iter().map(move |&k| (p.as_ref(), k))).collect();
            let (mut written, mut level) = rayon::join(
                || write_all(std::mem::take(&mut unwritten)),
                || -> Vec<Result<(ChunkMesh, Meshed), BuildError>> {
                    jobs.par_iter().map(|&(p, k)| self.mesh_chunk(k, p).inspect_err(|_| self.fail())).collect()
                },
            );
            // The error to report is one that is not a cancellation it caused.
            if let Some(e) = take_error(&mut written).or_else(|| take_error(&mut level)) {
                return Err(e);
            }
            done.extend(written.into_iter().map(|r| r.expect("no error above")));
            frontier = level
                .into_iter()
                .map(|r| {
                    let (mesh, meshed) = r.expect("no error above");
                    let kids = self.kids(meshed.chunk.key, meshed.leaf);
                    unwritten.push(meshed);
                    (Some(mesh), kids)
                })
                .collect();
        }
        let (mut written, mut below) = rayon::join(
            || write_all(unwritten),
            || -> Vec<Result<Vec<BuiltChunk>, BuildError>> {
                frontier
                    .into_par_iter()
                    .map(|(mesh, kids)| {
                        let mut all = Vec::new();
                        for b in kids.par_iter().map(|&k| self.subtree(k, mesh.as_ref())).collect::<Vec<_>>() {
                            all.extend(b?);
                        }
                        Ok(all)
                    })
                    .collect()
            },
        );
        if let Some(e) = take_error(&mut written).or_else(|| take_error(&mut below)) {
            return Err(e);
        }
        done.extend(written.into_iter().map(|r| r.expect("no error above")));
        for b in below {
            done.extend(b.expect("no error above"));
        }
        Ok(done)
    }

    /// Marks this build as failed: other chunks stop early.
    fn fail(&self) {
        self.failed.store(true, Ordering::Relaxed);
    }

    /// The children of a chunk that are worth building.
    fn kids(&self, key: ChunkKey, leaf: bool) -> Vec<ChunkKey> {
        match leaf {
            true => Vec::new(),
            false => self.tree.children(key).into_iter().filter(|&c| self.worth_building(c)).collect(),
        }
    }

    /// Builds chunk `key` and everything below it.
    fn subtree(&self, key: ChunkKey, parent: Option<&ChunkMesh>) -> Result<Vec<BuiltChunk>, BuildError> {
        if self.failed.load(Ordering::Relaxed) {
            return Ok(Vec::new()); // another subtree failed: its error is returned
        }
        let (mesh, built) = match self.chunk(key, parent) {
            Ok(built) => built,
            // Another chunk failed and returns its own error.
            Err(e) if is_cancel(&e) => return Ok(Vec::new()),
            Err(e) => {
                self.fail();
                return Err(e);
            }
        };
        let kids = self.kids(built.record.key, built.leaf);
        let mut all = vec![built];
        let below: Vec<Result<Vec<BuiltChunk>, BuildError>> =
            kids.par_iter().map(|&k| self.subtree(k, Some(&mesh))).collect();
        drop(mesh);
        for b in below {
            all.extend(b?);
        }
        Ok(all)
    }

    /// Meshes, assembles, textures and writes one chunk.
    fn chunk(&self, key: ChunkKey, parent: Option<&ChunkMesh>) -> Result<(ChunkMesh, BuiltChunk), BuildError> {
        let (mesh, meshed) = self.mesh_chunk(key, parent)?;
        Ok((mesh, self.write_chunk(meshed)?))
    }

    /// Meshes and assembles one chunk: what its children need (the mesh)
    /// and what is left to write.
    fn mesh_chunk(&self, key: ChunkKey, parent: Option<&ChunkMesh>) -> Result<(ChunkMesh, Meshed), BuildError> {
        let (tree, grid, timers) = (self.tree, self.grid, &self.timers);
        let level = key.level;
        let delta = tree.delta_m[level as usize];
        let few = few_chunks(tree, level);
        // A quantized chunk is measured again as it will be written (cut
        // points move sideways to the grid) and, where that misses δ,
        // meshed again with a wider margin next to cut points.
        let mut shares = CUT_SHARES.iter();
        // The attempt whose written error came closest, while none is within δ.
        let mut closest: Option<(f64, ChunkMesh, Chunk)> = None;
        let (mesh, chunk, remeshed, over_delta_m) = loop {
            let Some(&share) = shares.next() else {
                let (e, mesh, chunk) = closest.expect("one attempt at least");
                break (mesh, chunk, true, Some(e));
            };
            let t = Instant::now();
            let spec = ChunkSpec {
                key,
                footprint: tree.footprint(key),
                delta_m: delta,
                parent,
                keep_parent_edges: true,
                max_vertices: self.opts.config.max_chunk_vertices as usize,
                dividing_lines: match (tree.splits(level), few && self.lone_parts) {
                    (true, _) => DividingLines::Children,
                    (false, true) => DividingLines::Parts,
                    (false, false) => DividingLines::None,
                },
                split_insertion: few,
                cancel: Some(&self.failed),
                cut_share: share,
                cut_lattice: self.ctx.quantization.as_ref().map(|q| q.shift[level as usize]),
                // Quantized output: each triangle is meshed to δ less what
                // its corners' heights round by (output::compress).
                height_step: self.ctx.quantization.as_ref().map(|q| q.step_y_m),
                thin: self.opts.config.thin.level(!tree.splits(level)),
            };
            let mesh = match self.rtin {
                Some(r) => r.build_chunk(grid, tree, key, spec.max_vertices, spec.cancel)?,
                None => build_chunk(grid, &spec)?,
            };
            if mesh.max_error_m > spec.delta_m {
                return Err(BuildError::MissedDelta {
                    level: key.level,
                    x: key.x,
                    y: key.y,
                    error_m: mesh.max_error_m,
                    delta_m: spec.delta_m,
                });
            }
            Timers::add(&timers.mesh, t);
            let t = Instant::now();
            let margin = tree.delta_m[(level as usize).saturating_sub(2)];
            let chunk = Chunk { delta_m: delta, ..assemble(grid, self.hf.spacing_m, &mesh, margin) };
            Timers::add(&timers.skirt_morph, t);
            let Some(q) = self.ctx.quantization else { break (mesh, chunk, false, None) };
            // Within f64 rounding of δ is δ, as `verify` takes it (a sample
            // exactly δ off, which the mesher leaves out, reads a few ulps over).
            let t = Instant::now();
            let (lo, hi) = chunk
                .surface
                .positions
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[1]), hi.max(p[1])));
            let slack = if lo > hi { 0.0 } else { 256.0 * f64::EPSILON * (lo.abs().max(hi.abs()) + (hi - lo)) };
            let written = q.cut_error(&chunk, grid, delta + slack)?;
            Timers::add(&timers.check, t);
            if written <= delta + slack {
                break (mesh, chunk, share != CUT_SHARE, None);
            }
            if closest.as_ref().is_none_or(|c| written < c.0) {
                closest = Some((written, mesh, chunk));
            }
        };
        let stops = !self.opts.config.complete_tree && mesh.meets(self.opts.config.max_error_m);
        let leaf = stops || tree.children(key).is_empty();
        let max_error_m = mesh.max_error_m;
        Ok((mesh, Meshed { chunk, remeshed, over_delta_m, max_error_m, leaf }))
    }

    /// Textures and writes a meshed chunk.
    fn write_chunk(&self, meshed: Meshed) -> Result<BuiltChunk, BuildError> {
        let Meshed { chunk, remeshed, over_delta_m, max_error_m, leaf } = meshed;
        let (key, delta) = (chunk.key, chunk.delta_m);
        let timers = &self.timers;
        let t = Instant::now();
        let texture = self.texturer.map(|tx| tx.tile(key)).transpose()?;
        Timers::add(&timers.texture, t);
        let t = Instant::now();
        let glb = encode_glb(&chunk, texture.as_ref(), &self.ctx)?;
        let path = self.tmp.join(tile_uri(key));
        std::fs::create_dir_all(path.parent().expect("tile path has a parent"))
            .and_then(|_| std::fs::write(&path, &glb))
            .map_err(|source| BuildError::Io { path: path.clone(), source })?;
        self.bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
        Timers::add(&timers.write, t);
        self.bar.inc(1);
        let (min, max) = bounds(&chunk);
        let figures = LevelFigures {
            triangles: chunk.surface.triangle_count(),
            skirt_triangles: chunk.skirt.triangle_count(),
            vertices: chunk.surface.positions.len(),
            bytes: glb.len() as u64,
            texture: texture.map(|t| TileFigures {
                texel_m: t.colour.texel_size_m(),
                texels: t.colour.texels,
                limit: t.colour.limit[0].max(t.colour.limit[1]),
                bytes: (t.colour.bytes.len() + t.normal.as_ref().map_or(0, |n| n.bytes.len())) as u64,
            }),
        };
        Ok(BuiltChunk {
            record: TileRecord { key, min, max, delta_m: delta },
            figures,
            max_error_m,
            remeshed,
            over_delta_m,
            leaf,
        })
    }
}

/// The shares of δ a quantized chunk is meshed to next to cut points, tried
/// in turn until the chunk as written (cut points rounded sideways to the
/// grid) is within δ ([`Quantization::cut_error`]). At 0 every sample
/// under a cut-point triangle is on the surface before rounding; a chunk
/// still over δ then is written as the attempt that came closest and
/// reported (`Report::over_delta_as_written`).
const CUT_SHARES: [f64; 5] = [CUT_SHARE, 0.9, 0.75, 0.5, 0.0];

/// A level of fewer chunks than this (the root) fills the parts its
/// dividing lines make in parallel (`ChunkSpec::split_insertion`): alone,
/// its one chunk would keep every other thread waiting. The rule is the
/// tree's, not the thread count's, so the output is the same at any count.
const SPLIT_BELOW_CHUNKS: usize = 4;

/// Whether `level` of `tree` has fewer than [`SPLIT_BELOW_CHUNKS`] chunks,
/// so that its chunks fill their parts in parallel.
fn few_chunks(tree: &ChunkTree, level: u32) -> bool {
    tree.xs[level as usize].len() * tree.zs[level as usize].len() < SPLIT_BELOW_CHUNKS
}

/// Whether the lone chunks of `tree` (those of a level of fewer than
/// [`SPLIT_BELOW_CHUNKS`] that does not split: a root that is a leaf, and
/// the refine levels below it) get dividing lines so that their parts fill
/// and thin in parallel ([`DividingLines::Parts`]). The lines cost each
/// chunk the vertices that refine them, so only chunks the estimate puts
/// at [`PARTS_VERTICES`] or more take them: Fuji 513² at 30 m (3 162
/// vertices), not a small or flat grid's few triangles. Decided by the
/// tree and the data, never the thread count.
fn lone_parts(tree: &ChunkTree, estimate: &mut Estimate) -> bool {
    let lone = (0..=tree.depth()).any(|l| few_chunks(tree, l) && !tree.splits(l));
    lone && estimate.vertices_per_chunk(tree, 0) >= PARTS_VERTICES
}

/// The fewest vertices a lone chunk is estimated to hold to be filled by
/// parts ([`lone_parts`]).
const PARTS_VERTICES: f64 = 2000.0;

/// What a level's summary needs from one written chunk.
struct LevelFigures {
    triangles: usize,
    skirt_triangles: usize,
    vertices: usize,
    bytes: u64,
    texture: Option<TileFigures>,
}

/// What a level's summary needs from one chunk's texture.
struct TileFigures {
    texel_m: f64,
    texels: [u32; 2],
    limit: Limit,
    bytes: u64,
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
        surface_grid: grid_xz,
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
        placement: Placement::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m),
        morph: MorphConvention {
            target: "parent".into(),
            delta: "POSITION y offset: base + delta lies on the parent chunk's surface; x and z offsets 0; \
                    skirt bottom vertices have delta 0"
                .into(),
            schedule: "blend weight toward the parent w = clamp(tau/rho - 1, 0, 1) keeps the screen error <= tau; \
                       Ulrich's t = clamp(2 rho/tau - 1, 0, 1) (w = 1 - t) can reach 9/8 tau"
                .into(),
        },
        texture: None,
        skirt: "bottom = lowest valid sample, vertex or parent height between the neighbouring border vertices, \
                minus delta(max(L-2, 0)): below any neighbour of level >= L-1 in any morph state"
            .into(),
    }
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
