//! When each chunk is built: the tree top-down, siblings in parallel
//! (rayon), each chunk through the per-chunk path ([`super::chunk`]), and
//! the two retries around it: a quantized chunk shaped again at a wider
//! margin next to cut points ([`CUT_SHARES`]), and the whole tree planned
//! again with one more refine level where a chunk cannot meet its δ within
//! `max_chunk_vertices` ([`build_into`]).

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

use super::part::TreePart;
use super::report::{ChunkStageTimes, LevelReport, LevelTexture, OverDelta, Report};
use super::{BuildError, BuildOptions};
use crate::chunk::Chunk;
use crate::config::{Config, Mesher, dense_leaf_cells};
use crate::heightfield::{Heightfield, void_fill_in};
use crate::mesh::decimate::{CUT_SHARE, U16_INDEXED};
use crate::mesh::grid::Grid;
use crate::mesh::rtin::{self, Rtin};
use crate::mesh::{ChunkMesh, MeshError};
use crate::output::compress::Quantization;
use crate::output::gltf::GlbContext;
use crate::output::tileset::TileRecord;
use crate::progress;
use crate::quadtree::estimate::{Estimate, Planned, plan_tree};
use crate::quadtree::{ChunkKey, ChunkTree, MAX_REFINE_LEVELS};
use crate::store::Memory;
use crate::texture::source::{generate_in, generated_to_px, load_image};
use crate::texture::{ColourSource, Limit, NormalSource, TextureExtras, TextureSource, Texturer};

/// What [`build_into`] hands back: the report so far, the tree, the index
/// records, the texture extras, and the plan, texture source and chunk times.
pub(super) type Built = (Report, ChunkTree, Vec<TileRecord>, Option<TextureExtras>, [Duration; 3]);

/// Plans the tree and builds every chunk into `tmp`, planning again with
/// narrower leaves or one more refine level where a chunk is too dense.
pub(super) fn build_into(
    hf: &Heightfield,
    opts: &BuildOptions,
    tmp: &Path,
    memory: Option<&Memory>,
) -> Result<Built, BuildError> {
    let t = Instant::now();
    let scratch = |source| super::scratch_error(tmp, source);
    let filled = void_fill_in(hf, memory).map_err(scratch)?;
    let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref()).governed(memory);
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
                || timed(|| generate_in(hf, filled.as_deref(), &opts.config, memory)),
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
    if opts.config.mesher == Mesher::Rtin {
        // Counted exactly below, from the bintree's own errors.
        refine = 0;
    }
    let mut estimated = refine;
    let dense = dense_leaf_cells(opts.config.max_chunk_vertices);
    let t = Instant::now();
    let attempts = Instant::now();
    let mut field: Option<Rtin> = None;
    loop {
        if opts.config.mesher == Mesher::Rtin {
            refine =
                counted_refine(hf, &grid, &opts.config, leaf_cells, refine, &mut field, memory).map_err(scratch)?;
            estimated = estimated.max(refine);
        }
        let tree = chunk_tree(&opts.config, [hf.width, hf.height], leaf_cells, refine);
        // An attempt that stopped leaves tiles of a tree planned otherwise.
        let tiles = tmp.join("tiles");
        if tiles.exists() {
            std::fs::remove_dir_all(&tiles).map_err(|source| BuildError::Io { path: tiles, source })?;
        }
        let discarded = attempts.elapsed();
        let lone_parts = lone_parts(&tree, &mut estimate);
        let target = Target { dir: tmp, part: None };
        let meshing = Meshing { lone_parts, field: field.as_ref(), memory };
        match build_levels(hf, &grid, &tree, colour.as_ref(), opts, target, meshing) {
            Ok((mut report, records, texture)) => {
                report.refine_levels = refine;
                report.refine_estimated = estimated;
                report.discarded_s = discarded.as_secs_f64();
                report.leaf_cells = leaf_cells;
                report.leaf_width_cells = tree.widest_cells(tree.depth()).into_iter().max().unwrap_or(0);
                report.roots = (tree.roots().len(), tree.widest_cells(0).into_iter().max().unwrap_or(0));
                report.roots_narrowed = opts.config.mesher == Mesher::Rtin
                    && rtin::fitting_root(
                        hf.width,
                        hf.height,
                        opts.config.root_cells,
                        opts.config.max_chunk_vertices as usize,
                    ) != opts.config.root_cells;
                return Ok((report, tree, records, texture, [t_plan, t_source, t.elapsed()]));
            }
            // Leaves wider than a dense leaf may be: refine levels keep their
            // footprint and cannot help, narrower leaves do.
            Err(BuildError::Mesh(_)) if opts.config.leaf_cells.is_none() && leaf_cells > dense => {
                (leaf_cells, refine) = estimate.leaf_cells(dense);
                estimated = refine;
            }
            // A chosen wide leaf that is too dense: a level with the leaves'
            // footprint keeps it and its δ under every refine level added
            // below it, so they cannot help.
            Err(BuildError::Mesh(source @ MeshError::TooDense { level, .. }))
                if leaf_cells > dense && tree.widest_cells(level) == tree.widest_cells(tree.depth()) =>
            {
                return Err(BuildError::LeafTooWide { leaf_cells, dense, source });
            }
            Err(BuildError::Mesh(_)) if refine < MAX_REFINE_LEVELS => refine += 1,
            Err(e) => return Err(e),
        }
    }
}

/// The refine levels (at least `refine`) that the bintree's chunks need over
/// leaves of `leaf_cells`, counted from its error field (made or remade in
/// `field` as the tree needs): a coarse chunk with more vertices than
/// `max_chunk_vertices` gets one more level at the bottom, which doubles
/// every δ above. A level with the leaves' footprint that does not fit
/// keeps its δ under any refine level, so it stops the count (the build
/// then says which setting to change).
pub(crate) fn counted_refine(
    hf: &Heightfield,
    grid: &Grid,
    cfg: &Config,
    leaf_cells: u32,
    mut refine: u32,
    field: &mut Option<Rtin>,
    memory: Option<&Memory>,
) -> std::io::Result<u32> {
    let sag = sag(hf, cfg);
    loop {
        let tree = chunk_tree(cfg, [hf.width, hf.height], leaf_cells, refine);
        let step = height_step(hf, &tree, cfg);
        if !field.as_ref().is_some_and(|f| f.serves(&tree, step, sag)) {
            // The old field goes first: two would hold twice the memory.
            *field = None;
            *field = Some(Rtin::new_in(grid, &tree, step, sag, memory)?);
        }
        let f = field.as_ref().expect("made above");
        match f.densest_over(&tree, cfg.max_chunk_vertices as usize) {
            Some(level)
                if refine < MAX_REFINE_LEVELS && tree.widest_cells(level) != tree.widest_cells(tree.depth()) =>
            {
                refine += 1
            }
            _ => return Ok(refine),
        }
    }
}

/// What the curved frame adds to the bintree's errors, where `hf`'s chunks
/// are written in it (a grid it refuses is refused by the build itself).
fn sag(hf: &Heightfield, cfg: &Config) -> Option<rtin::Sag> {
    super::globe(hf, cfg).ok().flatten().map(|g| rtin::Sag::of(&g, hf.spacing_m))
}

/// The height step quantized output rounds `tree`'s heights to, if any
/// (a plan that fails is reported by the build).
fn height_step(hf: &Heightfield, tree: &ChunkTree, cfg: &Config) -> Option<f64> {
    cfg.compress.quantizes().then(|| Quantization::plan(hf, tree, cfg.max_error_m).ok().map(|q| q.step_y_m)).flatten()
}

/// The chunk tree `cfg`'s mesher needs over a grid of `size` samples: the
/// quadtree's midpoint cuts for the TIN, squares of 2^k cells for the
/// bintree ([`rtin::plan`]).
pub(crate) fn chunk_tree(cfg: &Config, size: [usize; 2], leaf_cells: u32, refine: u32) -> ChunkTree {
    let [w, h] = size;
    match cfg.mesher {
        Mesher::Tin => ChunkTree::plan_rooted(w, h, cfg.max_error_m, cfg.root_cells, leaf_cells, refine),
        Mesher::Rtin => {
            let root_cells = rtin::fitting_root(w, h, cfg.root_cells, cfg.max_chunk_vertices as usize);
            rtin::plan(w, h, cfg.max_error_m, root_cells, leaf_cells, refine)
        }
    }
}

/// What `f` returns and how long it took.
fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let t = Instant::now();
    (f(), t.elapsed())
}

pub(super) struct Timers {
    pub(super) mesh: AtomicU64,
    pub(super) skirt_morph: AtomicU64,
    pub(super) check: AtomicU64,
    pub(super) texture: AtomicU64,
    pub(super) write: AtomicU64,
}

impl Timers {
    pub(super) fn add(a: &AtomicU64, since: Instant) {
        a.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}

/// Where a build writes its chunks, and which of them: the whole tree, or
/// one job's part of it.
pub(super) struct Target<'p> {
    pub(super) dir: &'p Path,
    pub(super) part: Option<&'p TreePart>,
}

/// What the plan decided for the mesher beyond the tree: whether lone
/// chunks fill by parts (the TIN), the bintree's error field where one
/// was made for the tree already, and the memory limit a new one keeps to.
pub(super) struct Meshing<'r> {
    pub(super) lone_parts: bool,
    pub(super) field: Option<&'r Rtin>,
    pub(super) memory: Option<&'r Memory>,
}

pub(super) fn build_levels(
    hf: &Heightfield,
    grid: &Grid,
    tree: &ChunkTree,
    colour: Option<&ColourSource>,
    opts: &BuildOptions,
    target: Target,
    meshing: Meshing,
) -> Result<(Report, Vec<TileRecord>, Option<TextureExtras>), BuildError> {
    let Target { dir: tmp, part } = target;
    let Meshing { lone_parts, field, memory } = meshing;
    let cfg = &opts.config;
    let generator = format!("terrachunk {}", env!("CARGO_PKG_VERSION"));
    let planned: usize = (0..tree.delta_m.len()).map(|l| tree.xs[l].len() * tree.zs[l].len()).sum();
    let normals = (cfg.normal_map && colour.is_some()).then(|| NormalSource::new(grid, hf.spacing_m));
    let texturer = colour.map(|c| Texturer::new(c, normals.as_ref(), tree, hf.spacing_m, cfg));
    let quantization = cfg.compress.quantizes().then(|| Quantization::plan(hf, tree, cfg.max_error_m)).transpose()?;
    let globe = super::globe(hf, cfg)?;
    let t = Instant::now();
    let step = quantization.as_ref().map(|q| q.step_y_m);
    let own;
    let sag = globe.as_ref().map(|g| rtin::Sag::of(g, hf.spacing_m));
    let rtin = match (cfg.mesher, field) {
        (Mesher::Rtin, Some(f)) if f.serves(tree, step, sag) => Some(f),
        (Mesher::Rtin, _) => {
            own = Rtin::new_in(grid, tree, step, sag, memory).map_err(|e| super::scratch_error(tmp, e))?;
            Some(&own)
        }
        (Mesher::Tin, _) => None,
    };
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
        rtin,
        globe: globe.as_ref(),
        part,
        memory_limit: memory.map(Memory::limit),
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

/// What a chunk held while its level waits costs per vertex at most: its
/// mesh (vertex, triangles, their scans) and its chunk (positions, normals,
/// morph deltas, skirts), about 200 bytes measured, with room to spare.
const BYTES_PER_HELD_VERTEX: u64 = 256;

/// What one chunk adds to the report and the index.
pub(super) struct BuiltChunk {
    pub(super) record: TileRecord,
    pub(super) figures: LevelFigures,
    pub(super) max_error_m: f64,
    /// Meshed again for its cut points (quantized output), and, where even
    /// that missed δ, its error as written.
    pub(super) remeshed: bool,
    pub(super) over_delta_m: Option<f64>,
    /// No children: already within max_error, or at the deepest level.
    pub(super) leaf: bool,
}

/// A chunk meshed and assembled, not yet written.
pub(super) struct Meshed {
    pub(super) chunk: Chunk,
    pub(super) remeshed: bool,
    pub(super) over_delta_m: Option<f64>,
    pub(super) max_error_m: f64,
    pub(super) leaf: bool,
}

/// The meshes of a subtree job's ancestors, each with whether it is a leaf.
type AncestorMeshes = std::collections::BTreeMap<ChunkKey, (ChunkMesh, bool)>;

/// One build's shared state.
pub(super) struct Run<'a> {
    pub(super) hf: &'a Heightfield,
    pub(super) grid: &'a Grid<'a>,
    pub(super) tree: &'a ChunkTree,
    pub(super) opts: &'a BuildOptions,
    pub(super) tmp: &'a Path,
    pub(super) ctx: GlbContext<'a>,
    pub(super) texturer: Option<&'a Texturer<'a>>,
    /// The lone chunks are filled by parts ([`lone_parts`]).
    pub(super) lone_parts: bool,
    /// The bintree's error field, where it meshes the chunks.
    pub(super) rtin: Option<&'a Rtin>,
    /// The curved frame's map, where the chunks are written in it.
    pub(super) globe: Option<&'a crate::geodesy::Globe>,
    /// One job's part of the tree (a sharded build), or the whole tree.
    pub(super) part: Option<&'a TreePart>,
    /// The build's memory limit, bytes, if any.
    pub(super) memory_limit: Option<u64>,
    pub(super) timers: Timers,
    pub(super) bytes: AtomicU64,
    /// Set on the first error, so the other subtrees stop early.
    pub(super) failed: std::sync::atomic::AtomicBool,
    pub(super) bar: indicatif::ProgressBar,
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
        if let Some(TreePart::Under(roots)) = self.part {
            return self.under(roots);
        }
        let tree = self.tree;
        // Under a memory limit, a level is held whole only while a quarter
        // of the limit takes its meshes and chunks at their largest.
        let most_chunks = self.memory_limit.map_or(LEVEL_FIRST_CHUNKS, |limit| {
            let per_chunk = self.opts.config.max_chunk_vertices as u64 * BYTES_PER_HELD_VERTEX;
            ((limit / 4) / per_chunk.max(1)).clamp(1, LEVEL_FIRST_CHUNKS as u64) as usize
        });
        let level_first = (0..=tree.depth())
            .take_while(|&l| {
                let [wx, wz] = tree.widest_cells(l).map(|c| c as usize + 1);
                let l = l as usize;
                wx * wz > U16_INDEXED && tree.xs[l].len() * tree.zs[l].len() <= most_chunks
            })
            .count();
        let mut done = Vec::new();
        // (parent mesh, its children to build)
        let roots = tree.roots().into_iter().filter(|&k| self.in_part(k) && self.worth_building(k)).collect();
        let mut frontier: Vec<(Option<ChunkMesh>, Vec<ChunkKey>)> = vec![(None, roots)];
        // A level's chunks are textured and written while the next level is
        // meshed: its meshes are all the next level needs (the root alone
        // would otherwise keep the other threads waiting while it writes).
        let mut unwritten: Vec<Meshed> = Vec::new();
        let write_all = |unwritten: Vec<Meshed>| -> Vec<Result<BuiltChunk, BuildError>> {
            unwritten.into_par_iter().map(|m| self.finish(m).inspect_err(|_| self.fail())).collect()
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
                    (self.for_children(mesh), kids)
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

    /// A chunk's mesh, where its children start from it: the greedy TIN's
    /// do; the bintree's are cut from the error field alone, so it is
    /// dropped at once (a level of them took 100 MB on California).
    fn for_children(&self, mesh: ChunkMesh) -> Option<ChunkMesh> {
        self.rtin.is_none().then_some(mesh)
    }

    /// Marks this build as failed: other chunks stop early.
    fn fail(&self) {
        self.failed.store(true, Ordering::Relaxed);
    }

    /// The children of a chunk that are worth building (and that this
    /// job's part of the tree holds).
    fn kids(&self, key: ChunkKey, leaf: bool) -> Vec<ChunkKey> {
        match leaf {
            true => Vec::new(),
            false => {
                self.tree.children(key).into_iter().filter(|&c| self.in_part(c) && self.worth_building(c)).collect()
            }
        }
    }

    /// Whether chunk `k` is this job's to write: below the shard level for
    /// the job above the shards; every chunk otherwise (a subtree job starts
    /// from its own roots, [`Run::under`]).
    fn in_part(&self, k: ChunkKey) -> bool {
        match self.part {
            Some(TreePart::Above(level)) => k.level < *level,
            _ => true,
        }
    }

    /// Whether chunk `k` is built, given the meshes of the level above
    /// (each with whether it is a leaf), and if so its parent's mesh.
    fn built_parent<'m>(&self, meshes: &'m AncestorMeshes, k: ChunkKey) -> Option<Option<&'m ChunkMesh>> {
        let parent = match self.tree.parent(k) {
            None => None,
            Some(p) => match meshes.get(&p) {
                Some((mesh, false)) => Some(mesh),
                _ => return None,
            },
        };
        self.worth_building(k).then_some(parent)
    }

    /// Builds the subtrees under `roots` (one level): their ancestors are
    /// meshed again from the top, exactly as the whole build meshes them,
    /// but not written, so each subtree starts from the parent mesh the
    /// whole build would hand it.
    fn under(&self, roots: &[ChunkKey]) -> Result<Vec<BuiltChunk>, BuildError> {
        let tree = self.tree;
        let Some(level) = roots.first().map(|k| k.level) else { return Ok(Vec::new()) };
        let ancestor = |mut k: ChunkKey, l: u32| {
            while k.level > l {
                k = tree.parent(k).expect("a chunk below the top has a parent");
            }
            k
        };
        // (mesh, whether the chunk is a leaf) of every ancestor that exists.
        let mut meshes = AncestorMeshes::new();
        for l in 0..level {
            let need: std::collections::BTreeSet<ChunkKey> = roots.iter().map(|&r| ancestor(r, l)).collect();
            let made: Vec<Result<Option<_>, BuildError>> = need
                .into_par_iter()
                .map(|k| match self.built_parent(&meshes, k) {
                    None => Ok(None),
                    Some(parent) => self.mesh_chunk(k, parent).map(|(mesh, m)| Some((k, mesh, m.leaf))),
                })
                .collect();
            for m in made {
                if let Some((k, mesh, leaf)) = m? {
                    meshes.insert(k, (mesh, leaf));
                }
            }
        }
        let below: Vec<Result<Vec<BuiltChunk>, BuildError>> = roots
            .par_iter()
            .map(|&r| match self.built_parent(&meshes, r) {
                None => Ok(Vec::new()),
                Some(parent) => self.subtree(r, parent),
            })
            .collect();
        let mut all = Vec::new();
        for b in below {
            all.extend(b?);
        }
        Ok(all)
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
        let mesh = self.for_children(mesh);
        let below: Vec<Result<Vec<BuiltChunk>, BuildError>> =
            kids.par_iter().map(|&k| self.subtree(k, mesh.as_ref())).collect();
        drop(mesh);
        for b in below {
            all.extend(b?);
        }
        Ok(all)
    }

    /// Builds one chunk: shaped, then textured, encoded and written.
    fn chunk(&self, key: ChunkKey, parent: Option<&ChunkMesh>) -> Result<(ChunkMesh, BuiltChunk), BuildError> {
        let (mesh, meshed) = self.mesh_chunk(key, parent)?;
        Ok((mesh, self.finish(meshed)?))
    }

    /// Shapes one chunk ([`Run::shape`]): what its children need (the
    /// mesh) and what is left to write. A quantized chunk is measured again
    /// as it will be written (cut points move sideways to the grid) and,
    /// where that misses δ, shaped again with a wider margin next to cut
    /// points ([`CUT_SHARES`]).
    fn mesh_chunk(&self, key: ChunkKey, parent: Option<&ChunkMesh>) -> Result<(ChunkMesh, Meshed), BuildError> {
        let delta = self.tree.delta_m[key.level as usize];
        // The attempt whose written error came closest, while none is within δ.
        let mut closest: Option<(f64, ChunkMesh, Chunk)> = None;
        let mut shares = CUT_SHARES.iter();
        let (mesh, chunk, remeshed, over_delta_m) = loop {
            let Some(&share) = shares.next() else {
                let (e, mesh, chunk) = closest.expect("one attempt at least");
                break (mesh, chunk, true, Some(e));
            };
            let (mesh, chunk) = self.shape(key, parent, share)?;
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
            let written = q.cut_error(&chunk, self.grid, delta + slack)?;
            Timers::add(&self.timers.check, t);
            if written <= delta + slack {
                break (mesh, chunk, share != CUT_SHARE, None);
            }
            if closest.as_ref().is_none_or(|c| written < c.0) {
                closest = Some((written, mesh, chunk));
            }
        };
        let stops = !self.opts.config.complete_tree && mesh.meets(self.opts.config.max_error_m);
        let leaf = stops || self.tree.children(key).is_empty();
        let max_error_m = mesh.max_error_m;
        Ok((mesh, Meshed { chunk, remeshed, over_delta_m, max_error_m, leaf }))
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
pub(super) fn few_chunks(tree: &ChunkTree, level: u32) -> bool {
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
pub(super) fn lone_parts(tree: &ChunkTree, estimate: &mut Estimate) -> bool {
    let lone = (0..=tree.depth()).any(|l| few_chunks(tree, l) && !tree.splits(l));
    lone && estimate.vertices_per_chunk(tree, 0) >= PARTS_VERTICES
}

/// The fewest vertices a lone chunk is estimated to hold to be filled by
/// parts ([`lone_parts`]).
const PARTS_VERTICES: f64 = 2000.0;

/// What a level's summary needs from one written chunk.
pub(super) struct LevelFigures {
    pub(super) triangles: usize,
    pub(super) skirt_triangles: usize,
    pub(super) vertices: usize,
    pub(super) bytes: u64,
    pub(super) texture: Option<TileFigures>,
}

/// What a level's summary needs from one chunk's texture.
pub(super) struct TileFigures {
    pub(super) texel_m: f64,
    pub(super) texels: [u32; 2],
    pub(super) limit: Limit,
    pub(super) bytes: u64,
}

fn has_valid(grid: &Grid, tree: &ChunkTree, k: ChunkKey) -> bool {
    let ((x0, x1), (z0, z1)) = tree.footprint(k);
    (z0..=z1).any(|i| {
        let row = &grid.heights[i as usize * grid.width..];
        (x0..=x1).any(|j| !row[j as usize].is_nan())
    })
}
