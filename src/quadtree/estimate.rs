//! The plan's choices: how wide the leaves are and how many refine levels
//! the tree starts with, from greedy TINs on sample windows, before any
//! chunk is built (`plan_tree`, [`Estimate`]).
//!
//! A level of δ holds about (valid samples × vertices per sample at δ)
//! vertices whatever its chunking, so the density measured at each δ on a
//! few windows of the grid says how many vertices each candidate tree's
//! chunks would hold ([`Estimate::vertices_per_chunk`]). The leaf width is
//! the shallowest tree's whose chunks hold at most [`CHUNK_VERTICES`] on
//! average; a refine level is added where a coarse chunk would pass
//! `max_chunk_vertices` ([`Estimate::refine_levels`]). The tree itself, its
//! levels, footprints and δ, is [`super::ChunkTree::plan`]'s.

use rayon::prelude::*;

use super::{ChunkKey, ChunkTree, MAX_REFINE_LEVELS, Span};
use crate::config::{Config, dense_leaf_cells};
use crate::heightfield::Heightfield;
use crate::mesh::decimate::{ChunkSpec, build_chunk};
use crate::mesh::grid::Grid;
use crate::mesh::{ChunkMesh, MeshVertex};

/// One estimate window's chain: (vertices on its border, all its
/// vertices) at each δ, `None` where its TIN failed, and its last TIN.
type WindowChain = (Vec<Option<(usize, usize)>>, Option<ChunkMesh>);

/// What [`plan_tree`] chose: the leaf width and the refine levels to try
/// first, and the estimate that measured them (asked again if the build
/// needs narrower leaves).
pub(crate) struct Planned<'g> {
    pub(crate) estimate: Estimate<'g>,
    pub(crate) leaf_cells: u32,
    pub(crate) refine: u32,
}

/// Chooses the leaf width (unless set) and the refine levels. `to_px`: the
/// colour source's DEM-to-pixel scale, if textured.
///
/// A wide leaf's texture may hit `max_texture_px` only where its texels
/// still keep the bound T_g ≤ δ/τ_max, or where the source's own texels
/// are reached first: wider leaves must not blur what narrower ones showed.
pub(crate) fn plan_tree<'g>(
    hf: &Heightfield,
    grid: &'g Grid<'g>,
    cfg: &Config,
    to_px: Option<[(f64, f64); 2]>,
) -> Planned<'g> {
    let widest_leaf = to_px.map_or(u32::MAX, |to_px| {
        let texels = f64::from(cfg.max_texture_px.saturating_sub(1));
        let by_source = texels / to_px[0].1.abs().max(to_px[1].1.abs()).max(1e-9);
        let by_bound = texels * cfg.max_error_m / cfg.tau_max_px / hf.spacing_m[0].max(hf.spacing_m[1]);
        by_source.max(by_bound).floor().min(f64::from(u32::MAX)) as u32
    });
    let mut estimate = Estimate::new(grid, cfg.max_error_m, cfg.max_chunk_vertices as usize, cfg.root_cells);
    let (leaf_cells, refine) = match cfg.leaf_cells {
        Some(c) => (c, estimate.refine_levels(c)),
        None => estimate.leaf_cells(widest_leaf),
    };
    Planned { estimate, leaf_cells, refine }
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
    /// `root_cells`: every tree considered has top-level chunks at most
    /// this wide.
    root_cells: Option<u32>,
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
    /// The tree over the grid with `leaf_cells` leaves and `refine` refine
    /// levels, under the estimate's `root_cells`.
    pub fn tree(&self, leaf_cells: u32, refine: u32) -> ChunkTree {
        ChunkTree::plan_rooted(self.grid.width, self.grid.height, self.max_error_m, self.root_cells, leaf_cells, refine)
    }

    /// Chooses the windows; measures nothing yet.
    pub fn new(grid: &'g Grid<'g>, max_error_m: f64, max_vertices: usize, root_cells: Option<u32>) -> Self {
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
        let narrowest = *leaf_candidates(grid, max_error_m, root_cells).last().expect("one candidate");
        let top =
            ChunkTree::plan_rooted(grid.width, grid.height, max_error_m, root_cells, narrowest, 0).depth() as usize;
        Estimate {
            grid,
            max_error_m,
            max_vertices,
            root_cells,
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
        let candidates = leaf_candidates(grid, self.max_error_m, self.root_cells);
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
            let tree = self.tree(c, refine);
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
            let narrowest =
                *leaf_candidates(self.grid, self.max_error_m, self.root_cells).last().expect("one candidate");
            let full = self.tree(narrowest, 0);
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
        for refine in 0..MAX_REFINE_LEVELS {
            let tree = self.tree(leaf_cells, refine);
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

/// The leaf widths of every distinct tree over `grid` (with top-level
/// chunks at most `root_cells` wide) with leaves of at least 32 cells,
/// widest first: the widest chunk after each split.
fn leaf_candidates(grid: &Grid, max_error_m: f64, root_cells: Option<u32>) -> Vec<u32> {
    let full = ChunkTree::plan_rooted(grid.width, grid.height, max_error_m, root_cells, 1, 0);
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
