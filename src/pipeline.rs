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
use crate::config::{Config, ConfigError, dense_leaf_cells};
use crate::dem::{self, DemError, LoadOptions};
use crate::geodesy::Placement;
use crate::heightfield::{Heightfield, void_fill};
use crate::mesh::decimate::{CUT_SHARE, ChunkSpec, DividingLines, Grid, U16_INDEXED, build_chunk};
use crate::mesh::skirt::build_skirt;
use crate::mesh::{ChunkMesh, MeshError, MeshVertex, dem_normal};
use crate::output::compress::{Quantization, QuantizeError};
use crate::output::gltf::{GlbContext, encode_glb};
use crate::output::tileset::{GridSize, MorphConvention, TileRecord, TilesetExtras, tile_uri, tileset_json};
use crate::quadtree::{ChunkKey, ChunkTree, MAX_REFINE_LEVELS, Span};
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
    let plan = |to_px| timed(|| plan_tree(hf, &grid, opts, to_px));
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
        let tree = ChunkTree::plan(hf.width, hf.height, opts.config.max_error_m, leaf_cells, refine);
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

/// One estimate window's chain: (vertices on its border, all its
/// vertices) at each δ, `None` where its TIN failed, and its last TIN.
type WindowChain = (Vec<Option<(usize, usize)>>, Option<ChunkMesh>);

/// What [`plan_tree`] chose: the leaf width and the refine levels to try
/// first, and the estimate that measured them (asked again if the build
/// needs narrower leaves).
struct Planned<'g> {
    estimate: Estimate<'g>,
    leaf_cells: u32,
    refine: u32,
}

/// Chooses the leaf width (unless set) and the refine levels. `to_px`: the
/// colour source's DEM-to-pixel scale, if textured.
///
/// A wide leaf's texture may hit `max_texture_px` only where its texels
/// still keep the bound T_g ≤ δ/τ_max, or where the source's own texels
/// are reached first: wider leaves must not blur what narrower ones showed.
fn plan_tree<'g>(
    hf: &Heightfield,
    grid: &'g Grid<'g>,
    opts: &BuildOptions,
    to_px: Option<[(f64, f64); 2]>,
) -> Planned<'g> {
    let cfg = &opts.config;
    let widest_leaf = to_px.map_or(u32::MAX, |to_px| {
        let texels = f64::from(cfg.max_texture_px.saturating_sub(1));
        let by_source = texels / to_px[0].1.abs().max(to_px[1].1.abs()).max(1e-9);
        let by_bound = texels * cfg.max_error_m / cfg.tau_max_px / hf.spacing_m[0].max(hf.spacing_m[1]);
        by_source.max(by_bound).floor().min(f64::from(u32::MAX)) as u32
    });
    let mut estimate = Estimate::new(grid, cfg.max_error_m, cfg.max_chunk_vertices as usize);
    let (leaf_cells, refine) = match cfg.leaf_cells {
        Some(c) => (c, estimate.refine_levels(c)),
        None => estimate.leaf_cells(widest_leaf),
    };
    Planned { estimate, leaf_cells, refine }
}

/// What `f` returns and how long it took.
fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let t = Instant::now();
    (f(), t.elapsed())
}

/// Most surface vertices an average chunk may hold when `leaf_cells` is left
/// to the data: the top of the 1 000–8 000 that keeps draw calls few and
/// chunks small enough to cull and page finely.
pub const CHUNK_VERTICES: f64 = 8000.0;

/// Vertex densities of greedy TINs on sample windows, by δ: what the leaf
/// width and the refine levels are chosen from before anything is built.
///
/// A level of δ holds about (valid samples × vertices per sample at δ)
/// vertices whatever its chunking, so a tree's chunk sizes follow from its
/// plan and the density at each level's δ, measured with one greedy TIN on
/// each of up to 4 × 4 windows of 64 × 64 cells spread over the grid (up to
/// 8 × 8 of 32 × 32 for a close call, see [`Estimate::leaf_cells`]). Each δ =
/// max_error_m · 2^k is measured once per window set, when first asked for,
/// and a smaller δ continues the windows' TINs at twice it
/// (`Estimate::density_on`).
pub struct Estimate<'g> {
    grid: &'g Grid<'g>,
    max_error_m: f64,
    /// `max_chunk_vertices`.
    max_vertices: usize,
    /// Up to 4 × 4 windows of 64² cells, then (for a close call) up to
    /// 8 × 8 of 32² cells: the same samples, spread over twice as many places.
    windows: [Vec<(Span, Span, usize)>; 2],
    by_k: [Vec<Option<Density>>; 2],
    /// Per window set, the smallest k measured as a chain (each δ
    /// continued from the window's TIN at twice it) and those TINs, which
    /// a smaller k continues from.
    chains: [Option<(usize, Vec<Option<ChunkMesh>>)>; 2],
    /// The k a set's chain starts from: the most levels a tree of the
    /// narrowest leaves the estimate considers can ask for.
    top: usize,
    valid: f64,
    /// Valid samples of the footprints [`Estimate::refine_levels`] counted:
    /// the top levels keep their footprints whatever the refine levels.
    valid_by_footprint: Vec<((Span, Span), usize)>,
    /// Per footprint, its lowest and highest valid height (`None`: no valid
    /// sample): which chunks end where they are flat ([`Self::built`]).
    extents: std::collections::HashMap<(Span, Span), Option<(f32, f32)>>,
}

impl<'g> Estimate<'g> {
    /// Chooses the windows; measures nothing yet.
    pub fn new(grid: &'g Grid<'g>, max_error_m: f64, max_vertices: usize) -> Self {
        let windows = [(4, 64), (8, 32)].map(|(most, cells): (usize, usize)| {
            let cells = cells.min(grid.width - 1).min(grid.height - 1);
            let starts = |n: usize| {
                let k = ((n - 1) / cells).clamp(1, most);
                (0..k).map(move |w| if k == 1 { 0 } else { w * (n - 1 - cells) / (k - 1) }).collect::<Vec<_>>()
            };
            let mut windows = Vec::new();
            for &z in &starts(grid.height) {
                for &x in &starts(grid.width) {
                    let (xs, zs) = ((x as u32, (x + cells) as u32), (z as u32, (z + cells) as u32));
                    let valid = valid_in(grid, xs, zs);
                    if valid > 0 {
                        windows.push((xs, zs, valid));
                    }
                }
            }
            windows
        });
        let valid = grid.heights.iter().filter(|h| !h.is_nan()).count() as f64;
        let narrowest = *leaf_candidates(grid, max_error_m).last().expect("one candidate");
        let top = ChunkTree::plan(grid.width, grid.height, max_error_m, narrowest, 0).depth() as usize;
        Estimate {
            grid,
            max_error_m,
            max_vertices,
            windows,
            by_k: [vec![None; 32], vec![None; 32]],
            chains: [None, None],
            top: top.min(31),
            valid,
            valid_by_footprint: Vec::new(),
            extents: Default::default(),
        }
    }

    /// The density at δ = max_error_m · 2^k: interior vertices per valid
    /// sample, border vertices per cell of border, and the densest window's
    /// vertices per valid sample. A window's border is refined in 1-D as a
    /// chunk's is, and costs a 64-cell window far more per sample than a
    /// wide chunk: counting it per sample (as this did first) put Fuji's
    /// 2-level tree at 10 m at 9 200 vertices per chunk where the build
    /// makes 7 700 (now 8 200 on 4 × 4 windows and 7 100 on 8 × 8; 3 levels
    /// at 5 m: 5 200 estimated, 5 100 built). The windows' TINs are
    /// independent: meshed in parallel, summed in order.
    fn density(&mut self, k: usize) -> Density {
        self.density_on(k, 0)
    }

    /// [`Self::density`] on the first (`set` 0) or the denser (1) windows.
    ///
    /// The first δ asked of a set measures a chain: each window's free TIN
    /// at the set's top δ, then each smaller δ in turn continued from the
    /// TIN at twice it ([`ChunkSpec::continued`]), down to the δ asked. A
    /// smaller δ asked later continues the chain; a larger one below the
    /// top is already measured, one above it is a TIN of its own. A fresh
    /// TIN at each δ spent most of its time scanning the first, largest
    /// triangles again: Fuji's plan at 0.25 m took 0.16 s of a 0.64 s
    /// build.
    fn density_on(&mut self, k: usize, set: usize) -> Density {
        let k = k.min(31);
        if let Some(d) = self.by_k[set][k] {
            return d;
        }
        // Everything from the chain's finest δ up to its top is measured, so
        // a δ not yet measured lies either below the chain, which continues,
        // or above its top: a TIN of its own.
        if self.chains[set].as_ref().is_some_and(|c| c.0 < k) {
            let d = self.measure(&[k], set, None).0[0];
            self.by_k[set][k] = Some(d);
            return d;
        }
        let (finest, tins) = match self.chains[set].take() {
            Some((finest, tins)) => (finest, Some(tins)),
            None => (k.max(self.top) + 1, None),
        };
        let ks: Vec<usize> = (k..finest).rev().collect();
        let (densities, tins) = self.measure(&ks, set, tins.as_deref());
        for (&k, d) in ks.iter().zip(densities) {
            self.by_k[set][k] = Some(d);
        }
        self.chains[set] = Some((k, tins));
        self.by_k[set][k].expect("measured above")
    }

    /// The densities at δ = max_error_m · 2^k for each k of `ks` in turn
    /// (largest first) on window set `set`, and the windows' TINs at the
    /// last. Each window's TIN at the first k is fresh or continued from
    /// `from` (the same windows' TINs at a larger δ), and each later one
    /// continued from the one before. The windows are independent: each
    /// walks its whole chain as one parallel task (one task per δ waited
    /// for the slowest window at every δ), and the counts are summed in
    /// window order.
    fn measure(
        &self,
        ks: &[usize],
        set: usize,
        from: Option<&[Option<ChunkMesh>]>,
    ) -> (Vec<Density>, Vec<Option<ChunkMesh>>) {
        let grid = self.grid;
        // Per window: its vertex count on and off its border at each k, and its last TIN.
        let walked: Vec<WindowChain> = self.windows[set]
            .par_iter()
            .enumerate()
            .map(|(w, &(xs, zs, _))| {
                let mut tin: Option<ChunkMesh> = None;
                let counts = ks
                    .iter()
                    .enumerate()
                    .map(|(n, &k)| {
                        let delta_m = self.max_error_m * 2f64.powi(k as i32);
                        let before = if n == 0 { from.and_then(|f| f[w].as_ref()) } else { tin.as_ref() };
                        let spec = match before {
                            Some(tin) => ChunkSpec::continued((xs, zs), delta_m, tin),
                            None => ChunkSpec::unconstrained((xs, zs), delta_m),
                        };
                        tin = build_chunk(grid, &spec).ok();
                        tin.as_ref().map(|mesh| {
                            let on_border = |v: &&MeshVertex| {
                                v.x == f64::from(xs.0)
                                    || v.x == f64::from(xs.1)
                                    || v.z == f64::from(zs.0)
                                    || v.z == f64::from(zs.1)
                            };
                            (mesh.vertices.iter().filter(on_border).count(), mesh.vertices.len())
                        })
                    })
                    .collect();
                (counts, tin)
            })
            .collect();
        let densities = (0..ks.len())
            .map(|n| {
                let (mut interior, mut border, mut samples, mut edge_cells, mut densest) =
                    (0usize, 0usize, 0usize, 0usize, 0.0f64);
                for (&(xs, zs, valid), (counts, _)) in self.windows[set].iter().zip(&walked) {
                    let Some((b, all)) = counts[n] else { continue };
                    border += b;
                    interior += all - b;
                    edge_cells += 2 * (xs.1 - xs.0 + zs.1 - zs.0) as usize;
                    samples += valid;
                    densest = densest.max(all as f64 / valid as f64);
                }
                if samples == 0 {
                    Density::default()
                } else {
                    Density {
                        interior: interior as f64 / samples as f64,
                        border: border as f64 / edge_cells as f64,
                        densest,
                    }
                }
            })
            .collect();
        (densities, walked.into_iter().map(|(_, tin)| tin).collect())
    }

    /// The leaf width, in cells, of the shallowest tree whose chunks hold at
    /// most [`CHUNK_VERTICES`] vertices on average (leaves no narrower than
    /// 32 cells). Fewer levels nest fewer constraints into the leaves: on
    /// Fuji at 10 m, two levels instead of three take the leaves from 1.24
    /// to 1.06 times the triangles of one unconstrained TIN. Each candidate
    /// is judged as it would be built: over the chunks a build makes of it
    /// (none below flat ground, `Self::built`), with the refine levels
    /// [`Self::refine_levels`] gives it. Judged without them (as until stop
    /// 29), Fuji's 64-cell tree at 0.25 m counted a root of some 138 000
    /// vertices, a chunk no build makes, and lost to 32-cell leaves: 597
    /// chunks of 1 600 vertices on average against 213 of 4 300, 2 % more
    /// leaf triangles, and a build 19 % slower. A tree whose
    /// estimate is within `CLOSE_CALL` of the bound is measured again on
    /// up to 8 × 8 windows of 32² cells, which decides. Leaves wider
    /// than [`dense_leaf_cells`] are chosen only up to `widest` cells and
    /// where the densest window says they hold under half of
    /// `max_chunk_vertices` (see `build_into`). Returns the width and
    /// the refine levels it was judged with, the ones to build it with
    /// first.
    pub fn leaf_cells(&mut self, widest: u32) -> (u32, u32) {
        let grid = self.grid;
        let candidates = leaf_candidates(grid, self.max_error_m);
        let deepest = *candidates.last().expect("one candidate");
        for &c in &candidates {
            let fits = c <= dense_leaf_cells(self.max_vertices as u32)
                || c <= widest && {
                    let side = f64::from(c + 1);
                    self.density(0).densest * side * side <= self.max_vertices as f64 / 2.0
                };
            if !fits {
                continue;
            }
            let refine = self.refine_levels(c);
            let tree = ChunkTree::plan(grid.width, grid.height, self.max_error_m, c, refine);
            // 16 windows of 64² cells miss by up to 13 % (Fuji's root at
            // 20 m: 11 300 estimated, 10 233 built, where 64 windows of 64²,
            // the whole grid, say 9 600): they sample a quarter of Fuji and
            // may sample its rough part. A close call is measured again on
            // 64 windows of 32² cells: as many samples (as much time), from
            // four times as many places. On the 17 close calls among the
            // shared DEMs at 0.25, 1, 5 and 20 m (and Fuji's ladder) they
            // decided as 64 windows of 64² cells did, at a quarter of the cost.
            let mut estimate = self.vertices_per_chunk(&tree, 0);
            if (estimate / CHUNK_VERTICES - 1.0).abs() <= CLOSE_CALL {
                estimate = self.vertices_per_chunk(&tree, 1);
            }
            if estimate <= CHUNK_VERTICES {
                return (c, refine);
            }
        }
        (deepest, self.refine_levels(deepest))
    }

    /// The estimated surface vertices per chunk of `tree` (a plan over this
    /// grid at this `max_error_m`), measured on window set `set` (0: the
    /// first, 1: the close call's), over the chunks a build would make of
    /// it (`Self::built`). A level holds its interior at the interior
    /// density, and every chunk's four borders (a border two chunks share
    /// counted by both) at the border density, scaled by the share of valid
    /// samples.
    pub fn vertices_per_chunk(&mut self, tree: &ChunkTree, set: usize) -> f64 {
        let grid = self.grid;
        let valid_share = self.valid / (grid.width * grid.height) as f64;
        let built = self.built(tree);
        let chunks: usize = built.iter().map(Vec::len).sum();
        let vertices: f64 = (0..built.len())
            .map(|l| {
                let d = self.density_on(built.len() - 1 - l, set);
                let perimeter: u32 = built[l].iter().map(|&(xs, zs)| 2 * (xs.1 - xs.0 + zs.1 - zs.0)).sum();
                d.vertices(self.valid, f64::from(perimeter), valid_share)
            })
            .sum();
        vertices / chunks as f64
    }

    /// Per level of `tree`, how many chunks a build makes (`Self::built`).
    pub fn chunks_built(&mut self, tree: &ChunkTree) -> Vec<usize> {
        self.built(tree).iter().map(Vec::len).collect()
    }

    /// Per level of `tree`, the footprints of the chunks a build makes: all
    /// but those below a chunk that ends where it is, flat to within
    /// `max_error_m` (its relief, highest less lowest valid height, is
    /// within it, so any mesh of its samples is, and the build stops there:
    /// Kattegat's sea at 0 m, or N43E007's, 73 % of that tile). Counting
    /// them as built put N43E007's 150-cell tree at 1 m within 8 000
    /// vertices per chunk, where the build made 81 of its 213 chunks at 12 700
    /// on average. Chunks with no valid sample stay counted, as the
    /// densities count valid samples only.
    fn built(&mut self, tree: &ChunkTree) -> Vec<Vec<(Span, Span)>> {
        let mut built = vec![Vec::new(); tree.delta_m.len()];
        let mut level = tree.roots();
        while !level.is_empty() {
            let mut next = Vec::new();
            for k in level {
                let fp = tree.footprint(k);
                built[k.level as usize].push(fp);
                let flat = self.extent(fp).is_some_and(|(lo, hi)| f64::from(hi) - f64::from(lo) <= self.max_error_m);
                if !flat {
                    next.extend(tree.children(k));
                }
            }
            level = next;
        }
        built
    }

    /// The lowest and highest valid height in a footprint, measured once.
    /// The first call measures every chunk of the narrowest candidate
    /// tree's deepest level, and each chunk above from its children (which
    /// tile it): every candidate's tree is that tree's top levels. Any other
    /// footprint is measured on its own.
    fn extent(&mut self, fp: (Span, Span)) -> Option<(f32, f32)> {
        if self.extents.is_empty() {
            let narrowest = *leaf_candidates(self.grid, self.max_error_m).last().expect("one candidate");
            let full = ChunkTree::plan(self.grid.width, self.grid.height, self.max_error_m, narrowest, 0);
            for l in (0..full.delta_m.len()).rev() {
                for (y, &zs) in full.zs[l].iter().enumerate() {
                    for (x, &xs) in full.xs[l].iter().enumerate() {
                        let kids = full.children(ChunkKey { level: l as u32, x: x as u32, y: y as u32 });
                        let e = match kids.is_empty() {
                            true => extent_in(self.grid, xs, zs),
                            false => kids.iter().map(|&c| self.extents[&full.footprint(c)]).fold(None, merge_extent),
                        };
                        self.extents.insert((xs, zs), e);
                    }
                }
            }
        }
        if let Some(&e) = self.extents.get(&fp) {
            return e;
        }
        let e = extent_in(self.grid, fp.0, fp.1);
        self.extents.insert(fp, e);
        e
    }

    /// [`valid_in`], counted once per footprint.
    fn valid_in_footprint(&mut self, xs: Span, zs: Span) -> usize {
        if let Some(&(_, n)) = self.valid_by_footprint.iter().find(|(f, _)| *f == (xs, zs)) {
            return n;
        }
        let n = valid_in(self.grid, xs, zs);
        self.valid_by_footprint.push(((xs, zs), n));
        n
    }

    /// The refine levels to try first for leaves of `leaf_cells`: the fewest
    /// under which no chunk of more samples than `max_chunk_vertices` is
    /// estimated at more than [`SURELY_TOO_DENSE`] times as many vertices. Such a chunk is
    /// sure enough to fail that building it to find out (2.3 s for each of
    /// California's two roots at 1 m) is skipped; a closer call is still
    /// built and decides (see `build_into`).
    pub fn refine_levels(&mut self, leaf_cells: u32) -> u32 {
        let grid = self.grid;
        for refine in 0..MAX_REFINE_LEVELS {
            let tree = ChunkTree::plan(grid.width, grid.height, self.max_error_m, leaf_cells, refine);
            let levels = tree.delta_m.len();
            let limit = SURELY_TOO_DENSE * self.max_vertices as f64;
            let mut too_dense = Vec::new();
            for l in 0..levels {
                let big = |s: &Span| (s.1 - s.0 + 1) as usize;
                if tree.xs[l].iter().map(big).max().unwrap_or(0) * tree.zs[l].iter().map(big).max().unwrap_or(0)
                    <= self.max_vertices
                {
                    continue;
                }
                let d = self.density(levels - 1 - l);
                let dense = tree.xs[l].iter().any(|&xs| {
                    tree.zs[l].iter().any(|&zs| {
                        let (samples, perimeter) =
                            ((big(&xs) * big(&zs)) as f64, 2.0 * f64::from(xs.1 - xs.0 + zs.1 - zs.0));
                        // Counting the valid samples (a pass over the
                        // footprint) only where a full footprint could pass.
                        d.vertices(samples, perimeter, 1.0) > limit && {
                            let valid = self.valid_in_footprint(xs, zs) as f64;
                            d.vertices(valid, perimeter, valid / samples) > limit
                        }
                    })
                });
                if dense {
                    too_dense.push(l);
                }
            }
            // The last level has the leaves' footprint and δ whatever the
            // refine levels: more cannot help it, the build says so.
            if too_dense.is_empty() || too_dense.contains(&(levels - 1)) {
                return refine;
            }
        }
        MAX_REFINE_LEVELS
    }
}

/// The leaf widths of every distinct tree over `grid` with leaves of at
/// least 32 cells, widest first: the widest chunk after each split.
fn leaf_candidates(grid: &Grid, max_error_m: f64) -> Vec<u32> {
    let full = ChunkTree::plan(grid.width, grid.height, max_error_m, 1, 0);
    let widths = (0..=full.depth()).map(|d| full.widest_cells(d).into_iter().max().unwrap_or(0));
    let candidates: Vec<u32> = widths.filter(|&c| c >= 32).collect();
    if candidates.is_empty() { vec![32] } else { candidates }
}

/// How far over `max_chunk_vertices` a chunk's estimate must be before it is
/// taken as failing without building it. The estimate has been 11 % over
/// the built count (Fuji's root at 20 and 40 m) and far under it (74 % under
/// at California's 256 m root: windows of 64 cells see little of a coarse
/// level's shape), so a fifth over is a safe "surely".
pub const SURELY_TOO_DENSE: f64 = 1.2;

/// How near [`CHUNK_VERTICES`] a tree's estimate must be to be measured
/// again on more windows.
const CLOSE_CALL: f64 = 0.15;

/// The lowest and highest valid height in a footprint (`None`: none valid).
fn extent_in(grid: &Grid, xs: Span, zs: Span) -> Option<(f32, f32)> {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for row in footprint_rows(grid, xs, zs) {
        for &h in row {
            // NaN (nodata) fails both.
            if h < lo {
                lo = h;
            }
            if h > hi {
                hi = h;
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Two extents as one.
fn merge_extent(a: Option<(f32, f32)>, b: Option<(f32, f32)>) -> Option<(f32, f32)> {
    match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, b) => a.or(b),
    }
}

/// Valid samples in a footprint.
fn valid_in(grid: &Grid, xs: Span, zs: Span) -> usize {
    footprint_rows(grid, xs, zs).map(|row| row.iter().filter(|h| !h.is_nan()).count()).sum()
}

/// The heights of a footprint, row by row.
fn footprint_rows<'a>(grid: &'a Grid, xs: Span, zs: Span) -> impl Iterator<Item = &'a [f32]> {
    (zs.0 as usize..=zs.1 as usize).map(move |i| {
        let row = i * grid.width;
        &grid.heights[row + xs.0 as usize..=row + xs.1 as usize]
    })
}

/// What [`Estimate`] measures on its windows at one δ.
#[derive(Clone, Copy, Default)]
struct Density {
    /// Vertices off the window's border per valid sample.
    interior: f64,
    /// Vertices on the window's border per cell of border.
    border: f64,
    /// The densest window's vertices per valid sample.
    densest: f64,
}

impl Density {
    /// Vertices of an area with `valid` valid samples and `perimeter` cells
    /// of border (each chunk's four, a shared one counted by both chunks),
    /// `share` of whose samples are valid.
    fn vertices(&self, valid: f64, perimeter: f64, share: f64) -> f64 {
        self.interior * valid + self.border * perimeter * share
    }
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
        timers: Timers {
            mesh: AtomicU64::new(0),
            skirt_morph: AtomicU64::new(0),
            check: AtomicU64::new(0),
            texture: AtomicU64::new(0),
            write: AtomicU64::new(0),
        },
        bytes: AtomicU64::new(0),
        failed: std::sync::atomic::AtomicBool::new(false),
        bar: progress_bar(opts.progress, planned as u64),
    };
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
            let mesh = build_chunk(grid, &spec)?;
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

fn progress_bar(enabled: bool, len: u64) -> indicatif::ProgressBar {
    if !enabled {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template("[{bar:40}] {pos}/{len} chunks at most {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
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
