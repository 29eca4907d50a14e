//! The orchestrator: load → plan → mesh → skirt → morph → texture → write,
//! one call each, with plain data between them (DESIGN.md, "The pipeline").
//!
//! [`build`] lists the stages; [`schedule`] runs the per-chunk path
//! ([`chunk`]) over the tree, top-down and in parallel (a chunk needs its
//! parent's mesh, siblings are independent), with the retries that restart
//! a chunk or the whole tree; [`out_dir`] claims the output folder and puts
//! the finished tileset in place; [`report`] is what a build tells its user.
//! Chunks are collected in key order, so output does not depend on the
//! thread count.

mod chunk;
pub mod out_dir;
mod part;
mod report;
mod schedule;

pub(crate) use schedule::chunk_tree;

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::{Compress, Config, ConfigError, FLAT_FRAME_SHARE, Frame, Mesher};
use crate::dem::{self, DemError, LoadOptions};
use crate::geodesy::{FrameKind, Globe, Placement};
use crate::heightfield::{Crs, Heightfield, void_fill_in};
use crate::mesh::MeshError;
use crate::mesh::grid::Grid;
use crate::output::compress::QuantizeError;
use crate::output::tileset::{GridSize, MorphConvention, SourceFile, TilesetExtras, tileset_json, write_index};
use crate::quadtree::ChunkTree;
use crate::quadtree::estimate::{Planned, plan_tree};
use crate::store::Memory;
use crate::texture::source::{generate_in, generated_to_px, load_image};
use crate::texture::{TextureError, TextureSource};

pub use chunk::assemble;
pub use out_dir::{OutDir, OutDirError};
pub use part::{FixedPlan, PartBuilt, TreePart};
pub use report::{ChunkStageTimes, LevelReport, LevelTexture, OverDelta, Report, StageTimes, Summary, peak_rss};

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
    /// A geoid model whose undulation makes the DEM's heights ellipsoidal
    /// (`crate::geoid`); absent: heights as given.
    pub geoid: Option<PathBuf>,
}

/// How [`dem::load`] reads the inputs of `opts`, grids past `memory`'s
/// share into scratch files.
fn load_options(opts: &BuildOptions, memory: Option<&Memory>) -> LoadOptions {
    let cfg = &opts.config;
    LoadOptions {
        vertical_scale: Some(cfg.vertical_scale),
        spacing_m: cfg.spacing_m,
        geoid: opts.geoid.clone(),
        memory: memory.cloned(),
    }
}

/// The build's memory limit, with scratch files in `dir` (the temporary
/// folder beside OUT, or a job's own).
fn memory(cfg: &Config, dir: &Path) -> Option<Memory> {
    cfg.memory_limit_bytes().ok().flatten().map(|limit| Memory::new(limit, dir))
}

/// The folder that holds `path` (its parent, `.` for a bare name): where
/// a job's or a plan's scratch files go.
fn beside(path: &Path) -> &Path {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// Where a build's scratch files failed (the message names the file).
pub(super) fn scratch_error(dir: &Path, source: std::io::Error) -> BuildError {
    BuildError::Io { path: dir.to_path_buf(), source }
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
    #[error("{0}: already exists (use --force to replace a tileset terrachunk wrote)")]
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
    /// The output folder cannot be used as asked (see [`out_dir`]).
    #[error(transparent)]
    Output(OutDirError),
    /// The worker threads could not be started.
    #[error("cannot start {threads} worker threads: {why}; use fewer (--threads)")]
    ThreadPool {
        /// How many were asked for.
        threads: usize,
        /// What the system said.
        why: String,
    },
    /// The grid spans more than [`MAX_EXTENT_M`] on an axis.
    #[error(
        "{files}: the grid spans {} × {} m at a spacing of {} × {} m, more than the Earth's \
         circumference ({MAX_EXTENT_M} m): check the spacing (--spacing, or the file's georeference)",
        extent_m[0], extent_m[1], spacing_m[0], spacing_m[1]
    )]
    Extent {
        /// The input file(s).
        files: String,
        /// West-east and north-south extent, metres.
        extent_m: [f64; 2],
        /// The spacing in use, metres.
        spacing_m: [f64; 2],
    },
    /// `frame = "curved"` for a grid that cannot be placed on the Earth.
    #[error("frame = \"curved\": {0}")]
    Frame(String),
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
            BuildError::Output(e) => e.exit_code(),
            BuildError::ThreadPool { .. } | BuildError::Extent { .. } | BuildError::Frame(_) => 2,
            BuildError::LeafTooWide { .. } => 2,
            BuildError::Texture(TextureError::Encode { .. }) => 1,
            BuildError::Texture(_) => 2,
            BuildError::Quantize(QuantizeError::Range { .. }) => 1,
            BuildError::Quantize(_) => 2,
            BuildError::Mesh(_) | BuildError::MissedDelta { .. } | BuildError::Io { .. } => 1,
        }
    }
}

impl From<OutDirError> for BuildError {
    fn from(e: OutDirError) -> Self {
        match e {
            OutDirError::Exists(path) => BuildError::OutputExists(path),
            e => BuildError::Output(e),
        }
    }
}

/// Runs the whole pipeline: claim the output folder, load, plan and build
/// every chunk into a temporary folder beside it, write the index, and put
/// the folder in place ([`out_dir`]). On error nothing is left at
/// `opts.out` and nothing else is changed.
pub fn build(opts: &BuildOptions) -> Result<Report, BuildError> {
    let t0 = Instant::now();
    let cfg = &opts.config;
    cfg.validate()?;
    let mut reads: Vec<&Path> = opts.inputs.iter().map(PathBuf::as_path).collect();
    if let TextureSource::Image(image) = &opts.texture {
        reads.push(image);
    }
    let out = OutDir::claim(&opts.out, &reads, opts.force)?;
    let memory = memory(cfg, out.tmp());
    let hf = dem::load(&opts.inputs, &load_options(opts, memory.as_ref()))?;
    check_extent(&hf, opts)?;
    let t_load = t0.elapsed();
    let threads = if cfg.threads == 0 { rayon::current_num_threads() } else { cfg.threads };
    let pool = thread_pool(threads)?;

    let built = pool.install(|| schedule::build_into(&hf, opts, out.tmp(), memory.as_ref()))?;
    let (mut report, tree, records, texture, [t_plan, t_source, t_chunks]) = built;
    let t_idx = Instant::now();
    let mut extras = tileset_extras(&hf, opts, &tree);
    extras.source = SourceFile::of_inputs(&opts.inputs).map_err(|(path, source)| BuildError::Io { path, source })?;
    extras.geoid = geoid_file(opts)?;
    extras.texture = texture;
    report.not_placed = not_placed(&hf);
    report.flat_frame_error = extras.placement.as_ref().and_then(|p| p.flat_frame_error.clone());
    report.frame = extras.placement.as_ref().map_or(FrameKind::Flat, |p| p.frame);
    let doc = tileset_json(&tree, &records, &extras, cfg.index_tiles);
    let index = write_index(out.tmp(), &doc).map_err(|(path, source)| BuildError::Io { path, source })?;
    report.index_files = index.files;
    out.commit()?;
    report.bytes += index.bytes;
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
    report.record_memory(memory.as_ref());
    Ok(report)
}

/// The widest a grid may span on either axis, metres: a little over the
/// Earth's equatorial circumference (40 075 017 m), which a whole-globe
/// grid of degrees spans from −180° to 180°. A wider grid is no terrain
/// (its spacing is wrong), and its positions would lose metres in f32 and
/// its geometric errors overflow.
pub const MAX_EXTENT_M: f64 = 4.01e7;

/// The geoid model's name, length and hash for the extras.
fn geoid_file(opts: &BuildOptions) -> Result<Option<SourceFile>, BuildError> {
    opts.geoid
        .as_ref()
        .map(|p| SourceFile::of(p).map_err(|source| BuildError::Io { path: p.clone(), source }))
        .transpose()
}

/// Refuses a grid whose extent, from its sample count and spacing (the
/// file's own or `spacing_m`), is beyond [`MAX_EXTENT_M`].
fn check_extent(hf: &Heightfield, opts: &BuildOptions) -> Result<(), BuildError> {
    let extent =
        [(hf.width, hf.spacing_m[0]), (hf.height, hf.spacing_m[1])].map(|(n, s)| n.saturating_sub(1) as f64 * s);
    if extent.iter().all(|e| e.is_finite() && *e <= MAX_EXTENT_M) {
        return Ok(());
    }
    let files: Vec<String> = opts.inputs.iter().map(|p| p.display().to_string()).collect();
    Err(BuildError::Extent { files: files.join(", "), extent_m: extent, spacing_m: hf.spacing_m })
}

/// Why a georeferenced grid gets no root transform; `None` when it gets
/// one or when the file places it nowhere at all (nothing to warn about).
fn not_placed(hf: &Heightfield) -> Option<String> {
    if hf.georef.crs == Crs::Unknown {
        return None;
    }
    Placement::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m).err().map(|why| why.to_string())
}

pub(super) fn tileset_extras(hf: &Heightfield, opts: &BuildOptions, tree: &ChunkTree) -> TilesetExtras {
    let curved = curved(hf, &opts.config);
    TilesetExtras {
        generator: format!("terrachunk {}", env!("CARGO_PKG_VERSION")),
        grid: GridSize { width: hf.width as u32, height: hf.height as u32 },
        spacing_m: hf.spacing_m,
        vertical_scale: opts.config.vertical_scale,
        max_error_m: opts.config.max_error_m,
        tau_max_px: opts.config.tau_max_px,
        levels: tree.depth() + 1,
        delta_m: tree.delta_m.clone(),
        source: Vec::new(),
        geoid: None,
        georef: hf.georef.clone(),
        placement: Placement::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m).ok().map(|p| {
            let p = if curved { p.curved() } else { p };
            match &opts.geoid {
                Some(model) => p.with_geoid(&dem::file_name(model)),
                None => p,
            }
        }),
        morph: MorphConvention {
            target: "parent".into(),
            delta: if curved {
                "POSITION offset (x, y, z): base + delta lies on the parent chunk's surface as written, at the \
                 point of the parent triangle with the vertex's grid barycentric coordinates; skirt bottom \
                 vertices have delta 0"
                    .into()
            } else {
                "POSITION y offset: base + delta lies on the parent chunk's surface; x and z offsets 0; \
                 skirt bottom vertices have delta 0"
                    .into()
            },
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

/// Whether the chunks of `hf` are written in the curved frame
/// (`config::Frame`; a `curved` setting the grid cannot take is refused by
/// [`globe`] first).
pub(crate) fn curved(hf: &Heightfield, cfg: &Config) -> bool {
    cfg.frame == Frame::Curved || matches!(globe(hf, cfg), Ok(Some(_)))
}

/// The curved frame's map of `hf`, where its chunks are written in it.
pub(crate) fn globe(hf: &Heightfield, cfg: &Config) -> Result<Option<Globe>, BuildError> {
    let map = || Globe::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m);
    match cfg.frame {
        Frame::Flat => Ok(None),
        Frame::Curved => map()
            .map(Some)
            .map_err(|why| BuildError::Frame(format!("{}: the grid cannot be placed on the Earth: {why}", hf.source))),
        Frame::Auto => {
            let far = cfg.mesher == Mesher::Rtin
                && cfg.compress == Compress::None
                && Placement::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m)
                    .ok()
                    .and_then(|p| p.flat_frame_error)
                    .is_some_and(|e| e.worst_m() > FLAT_FRAME_SHARE * cfg.max_error_m);
            Ok(far.then(|| map().ok()).flatten())
        }
    }
}

/// Each worker's stack as std gives it (2 MiB) and the signal stack std
/// adds (at most 64 KiB with its guard page).
const WORKER_STACK_BYTES: u64 = (2 << 20) + (64 << 10);

/// The build's worker threads. Where the process's address space is
/// limited (`ulimit -v`) and their stacks would take more than half of it,
/// the pool is refused before any thread starts: a thread that starts but
/// cannot map its signal stack ends in a panic inside std, not an error.
fn thread_pool(threads: usize) -> Result<rayon::ThreadPool, BuildError> {
    let limit = rustix::process::getrlimit(rustix::process::Resource::As).current;
    if let Some(limit) = limit {
        let need = threads as u64 * WORKER_STACK_BYTES;
        if need > limit / 2 {
            let why = format!(
                "their stacks need {} MB of the {} MB of address space this process may use (ulimit -v)",
                need >> 20,
                limit >> 20
            );
            return Err(BuildError::ThreadPool { threads, why });
        }
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| BuildError::ThreadPool { threads, why: e.to_string() })
}

/// The tree [`build`] would plan for `opts`, fixed so that the jobs of a
/// sharded build ([`crate::shard`]) all build the same one: the grid's size,
/// the leaf width and refine levels the estimate chooses, and whether lone
/// chunks fill by parts. `build` adds a refine level when a chunk turns out
/// too dense; a job cannot, and fails instead ([`crate::shard`] says so).
pub fn plan_fixed(opts: &BuildOptions) -> Result<FixedPlan, BuildError> {
    opts.config.validate()?;
    let cfg = &opts.config;
    // Scratch files beside OUT (they are unlinked at once).
    let scratch = beside(&opts.out);
    let memory = memory(cfg, scratch);
    let memory = memory.as_ref();
    let hf = dem::load(&opts.inputs, &load_options(opts, memory))?;
    check_extent(&hf, opts)?;
    let filled = void_fill_in(&hf, memory).map_err(|e| scratch_error(scratch, e))?;
    let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref()).governed(memory);
    let to_px = match &opts.texture {
        TextureSource::None => None,
        TextureSource::Image(path) => Some(load_image(path, &hf)?.to_px),
        TextureSource::Generated => Some(generated_to_px(&hf, cfg)),
    };
    let Planned { mut estimate, leaf_cells, mut refine } = plan_tree(&hf, &grid, cfg, to_px);
    if cfg.mesher == crate::config::Mesher::Rtin {
        refine = schedule::counted_refine(&hf, &grid, cfg, leaf_cells, 0, &mut None, memory)
            .map_err(|e| scratch_error(scratch, e))?;
    }
    let tree = chunk_tree(cfg, [hf.width, hf.height], leaf_cells, refine);
    let lone_parts = schedule::lone_parts(&tree, &mut estimate);
    Ok(FixedPlan { grid: [hf.width, hf.height], leaf_cells, refine_levels: refine, lone_parts })
}

/// Builds one job's part of the fixed tree `plan` into `dir` (which must
/// not exist yet): its chunks' files, and what the index needs from them.
/// The chunks are byte for byte those [`build`] writes for the same
/// options and tree, whatever the part and the thread count.
pub fn build_part(opts: &BuildOptions, plan: &FixedPlan, part: &TreePart, dir: &Path) -> Result<PartBuilt, BuildError> {
    opts.config.validate()?;
    let cfg = &opts.config;
    // Scratch files beside the job's folder (they are unlinked at once).
    let scratch = beside(dir);
    let memory = memory(cfg, scratch);
    let memory = memory.as_ref();
    let hf = dem::load(&opts.inputs, &load_options(opts, memory))?;
    check_extent(&hf, opts)?;
    let threads = if cfg.threads == 0 { rayon::current_num_threads() } else { cfg.threads };
    let pool = thread_pool(threads)?;
    pool.install(|| {
        let filled = void_fill_in(&hf, memory).map_err(|e| scratch_error(scratch, e))?;
        let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref()).governed(memory);
        let colour = match &opts.texture {
            TextureSource::None => None,
            TextureSource::Image(path) => Some(load_image(path, &hf)?),
            TextureSource::Generated => Some(generate_in(&hf, filled.as_deref(), cfg, memory)?),
        };
        let tree = plan.tree(cfg);
        std::fs::create_dir_all(dir).map_err(|source| BuildError::Io { path: dir.into(), source })?;
        let target = schedule::Target { dir, part: Some(part) };
        let meshing = schedule::Meshing { lone_parts: plan.lone_parts, field: None, memory };
        let (mut report, records, texture) =
            schedule::build_levels(&hf, &grid, &tree, colour.as_ref(), opts, target, meshing)?;
        report.threads = threads;
        report.record_memory(memory);
        let mut extras = tileset_extras(&hf, opts, &tree);
        extras.source =
            SourceFile::of_inputs(&opts.inputs).map_err(|(path, source)| BuildError::Io { path, source })?;
        extras.geoid = geoid_file(opts)?;
        extras.texture = texture;
        Ok(PartBuilt { report, records, extras })
    })
}
