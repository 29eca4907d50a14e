//! Greedy insertion (Garland & Heckbert's "Greedy Insertion" TIN, as in
//! delatin), constrained and nested so that Chunked LOD can morph exactly.
//!
//! A chunk's TIN ([`super::tin`]) is built in five steps; the first four only
//! add points:
//!
//! 1. Start from the parent's triangles inside the footprint with *every*
//!    parent edge fixed (never flipped), so whatever is inserted later stays
//!    inside a parent triangle: the child refines the parent and its morph to
//!    the parent surface is exact everywhere (DESIGN.md, promise 3). The top
//!    level starts from its four corners (a lone leaf cut into parts, from
//!    the nine samples where its lines meet: [`DividingLines::Parts`]).
//! 2. Cut the triangles along the dividing lines (the children's borders),
//!    at points on the crossed edges that take the parent surface height;
//!    the pieces of the lines are fixed edges. Where a line crosses the
//!    border it forces the border's midpoint (the children's corner).
//! 3. Refine each border line, then each dividing line, in 1-D from that
//!    line's own samples: split the worst interval at its worst sample until
//!    every valid sample on the line is within δ. Neighbours see the same
//!    inherited vertices and the same samples, so they arrive at the same
//!    border without talking.
//! 4. Insert the interior sample with the largest error until every valid
//!    sample is within δ (samples on the lines of steps 2–3 never move).
//!    No insertion or flip crosses a dividing line, so the parts the lines
//!    make can be filled as TINs of their own and joined, with the same
//!    triangles: the root, and a large lone leaf, do so in parallel
//!    ([`ChunkSpec::split_insertion`]).
//! 5. Where [`ChunkSpec::thin`] says so, take out the free vertices step 4
//!    added that the finished TIN no longer needs (`thin`).
//!
//! Decisions are made in f64 grid coordinates; next to cut points the
//! target is shrunk by a margin that covers the rounding of the written
//! positions ([`Targets`]); elsewhere every corner is written exactly.

use std::cmp::Ordering;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering as AtomicOrdering};

use rayon::prelude::*;

use robust::Coord;

use super::grid::{Grid, Window};
use super::tin::{Position, Tin, V};
use super::{ChunkMesh, MeshError, MeshVertex, chain_ties};
use crate::mesh::locate::{SurfaceLocator, barycentric};
use crate::quadtree::{ChunkKey, Span, midpoint};

mod cuts;
mod scan;
mod targets;
#[cfg(test)]
mod tests;

use cuts::*;
pub use scan::TriangleScan;
use scan::*;
pub use targets::*;

/// Most vertices one u16-indexed vertex set may hold (index 65 535 is the
/// primitive restart value of some APIs, so it is never written): a chunk
/// with more is written with u32 indices.
pub const U16_INDEXED: usize = 65_535;

/// Everything `build_chunk` needs besides the heights.
pub struct ChunkSpec<'p> {
    /// Which chunk.
    pub key: ChunkKey,
    /// Footprint in samples.
    pub footprint: (Span, Span),
    /// δ(L) in metres.
    pub delta_m: f64,
    /// The parent's mesh (None at the top level).
    pub parent: Option<&'p ChunkMesh>,
    /// Fix every parent edge (step 1), as a chunk must for its morph to be
    /// exact. Off only where `parent` is a warm start, not a parent: the
    /// sample windows [`ChunkSpec::continued`] refines to a smaller δ.
    pub keep_parent_edges: bool,
    /// Most vertices allowed (`Config::max_chunk_vertices` in a build).
    pub max_vertices: usize,
    /// Which dividing lines the TIN keeps as fixed edges (step 2).
    pub dividing_lines: DividingLines,
    /// Fill the parts the dividing lines make in parallel, each a TIN of
    /// its own (the same triangles as one TIN, numbered part by part): for
    /// the chunks of a level too few to keep every thread busy.
    pub split_insertion: bool,
    /// Stop early with [`MeshError::Cancelled`] once this is set (another
    /// chunk failed, so this build's work is lost anyway).
    pub cancel: Option<&'p AtomicBool>,
    /// The share of δ a triangle or line interval with a cut-point corner is
    /// meshed to ([`Targets`]; [`CUT_SHARE`] unless the quantized output
    /// needs a wider margin there, see `Quantization::cut_error`).
    pub cut_share: f64,
    /// Quantized output: the level's horizontal grid is 2^-k cells, and a
    /// cut point this chunk makes is placed on it (along its dividing line),
    /// where the file holds it exactly, unless that would turn a piece over
    /// (`cut_along_line`). `None`: f32 output, cut points where the lines
    /// cross the parent's edges.
    pub cut_lattice: Option<u32>,
    /// Quantized output: the height step the file rounds every height to
    /// (`Quantization::step_y_m`), which each triangle's target leaves room
    /// for ([`Targets::rounding`]). `None`: f32 output.
    pub height_step: Option<f64>,
    /// Step 5: take out the vertices the finished mesh does not need
    /// (`thin`).
    pub thin: bool,
}

/// The lines through a chunk's middle, across and along, that its TIN
/// keeps as fixed edges, besides its borders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DividingLines {
    /// None: one TIN inside the borders (a leaf, the single-TIN baseline,
    /// the plan's sample windows).
    None,
    /// The children's borders, which every level below keeps.
    Children,
    /// The same lines in a chunk whose children (if any) keep its
    /// footprint: a lone leaf large enough to be worth filling by parts in
    /// parallel ([`ChunkSpec::split_insertion`]), where it would keep every
    /// other thread waiting. At the top level its TIN starts from the
    /// samples where the lines meet the borders and each other rather than
    /// from the four corners, so the lines make no cut points: no vertex
    /// off the sample grid that no level needs.
    Parts,
}

impl ChunkSpec<'_> {
    /// Steps per cell of the grid the file writes positions on exactly
    /// (1: only the samples, as f32 output is taken).
    fn lattice(&self) -> f64 {
        self.cut_lattice.map_or(1.0, |k| f64::from(1u32 << k.min(30)))
    }
}

/// The share of δ next to cut points by default ([`Targets`]).
pub const CUT_SHARE: f64 = 0.98;

impl<'p> ChunkSpec<'p> {
    /// One free greedy TIN over `footprint` at `delta_m`: no parent, no
    /// dividing lines, no vertex limit (the single-TIN baseline, and the
    /// sample windows the leaf width is estimated from).
    pub fn unconstrained(footprint: (Span, Span), delta_m: f64) -> Self {
        ChunkSpec {
            key: ChunkKey { level: 0, x: 0, y: 0 },
            footprint,
            delta_m,
            parent: None,
            keep_parent_edges: true,
            max_vertices: usize::MAX,
            dividing_lines: DividingLines::None,
            split_insertion: false,
            cancel: None,
            cut_share: CUT_SHARE,
            cut_lattice: None,
            height_step: None,
            thin: false,
        }
    }

    /// [`ChunkSpec::unconstrained`] at `delta_m`, continued from `from`, the
    /// same footprint's free TIN at a larger δ: its vertices and triangles
    /// are the start and every edge stays free to flip, so the result is the
    /// free TIN at `delta_m` but for the order the points went in. The
    /// borders are refined from `from`'s border points to exactly the points
    /// a fresh TIN's would take (each interval split at its worst sample, the
    /// same splits at any δ); the interior keeps `from`'s points and adds
    /// the worst sample until all are within `delta_m`, where a fresh TIN
    /// would have refined the borders first.
    pub fn continued(footprint: (Span, Span), delta_m: f64, from: &'p ChunkMesh) -> Self {
        ChunkSpec { parent: Some(from), keep_parent_edges: false, ..ChunkSpec::unconstrained(footprint, delta_m) }
    }
}

/// Builds one chunk's TIN (see the module comment for the five steps).
pub fn build_chunk(grid: &Grid, spec: &ChunkSpec) -> Result<ChunkMesh, MeshError> {
    build_chunk_thinning(grid, spec, Thinning::ByParts)
}

/// Where a chunk filled by parts ([`ChunkSpec::split_insertion`]) is thinned.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Thinning {
    /// Each part on its own, in parallel: what a build does.
    ByParts,
    /// The joined TIN, on one thread: what it did first, which the tests
    /// hold the other to, collapse for collapse.
    Joined,
}

fn build_chunk_thinning(grid: &Grid, spec: &ChunkSpec, thinning: Thinning) -> Result<ChunkMesh, MeshError> {
    // Debug builds, the tests' among them, hold every chunk's TIN to its
    // invariants: the walk is linear in the TIN, a small share of meshing it.
    build_checked(grid, spec, thinning, cfg!(debug_assertions))
}

/// [`build_chunk_thinning`], with the finished TIN held to [`assert_sound`]
/// before it becomes the chunk's mesh where `check` says so.
fn build_checked(grid: &Grid, spec: &ChunkSpec, thinning: Thinning, check: bool) -> Result<ChunkMesh, MeshError> {
    let window = Window::new(grid, spec.footprint);
    let meshed = mesh_tin(&window, spec, thinning)?;
    if check {
        assert_sound(&meshed.tin, spec.footprint);
    }
    Ok(finish(&window, spec, &meshed.tin, &meshed.lines, &meshed.scans, meshed.relief))
}

/// A chunk's TIN after the five steps, with what [`finish`] needs to make
/// its mesh: the lines' samples, the last scans and the footprint's relief
/// and magnitude.
struct Meshed {
    tin: Tin,
    lines: Lines,
    scans: Vec<Scan>,
    relief: (f64, f64),
}

/// Panics unless `tin` keeps every invariant of [`Tin::sanity_check`] and
/// its border lies on the footprint's rectangle, the region a chunk's TIN
/// covers (the check itself only knows the border is one convex loop).
fn assert_sound(tin: &Tin, ((x0, x1), (z0, z1)): (Span, Span)) {
    if let Err(broken) = tin.sanity_check() {
        panic!("the TIN over {:?} is broken: {broken}", ((x0, x1), (z0, z1)));
    }
    let along = |c: f64, d: f64, side: u32| c == f64::from(side) && d == f64::from(side);
    for e in (0..tin.num_triangles() as u32).filter(|&t| !tin.is_dead(t)).flat_map(|t| 3 * t..3 * t + 3) {
        if tin.twin_of(e).is_none() {
            let (a, b) = tin.ends(e);
            let (p, q) = (tin.pts[a as usize], tin.pts[b as usize]);
            let on = along(p.x, q.x, x0) || along(p.x, q.x, x1) || along(p.z, q.z, z0) || along(p.z, q.z, z1);
            assert!(on, "border edge {a}–{b} of the TIN over {:?} is not on its rectangle", ((x0, x1), (z0, z1)));
        }
    }
}

/// Steps 1 to 5 over `grid`, a chunk's window.
fn mesh_tin(grid: &Window, spec: &ChunkSpec, thinning: Thinning) -> Result<Meshed, MeshError> {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let (relief, magnitude) = footprint_relief(grid, spec.footprint);
    let target =
        Targets::with_cut_share(spec.delta_m, relief, spec.cut_share).on_lattice(spec.lattice(), spec.height_step);
    let parent_locator = spec.parent.filter(|_| spec.lattice() > 1.0).map(|p| p.locator());
    let nested = Targeting { nested: spec.parent.is_some(), parent: parent_locator.as_ref() };
    let (mx, mz) = match spec.dividing_lines {
        DividingLines::Children | DividingLines::Parts => (midpoint((x0, x1)), midpoint((z0, z1))),
        DividingLines::None => (None, None),
    };

    // Steps 1 and 3a: the parent's triangles, cut along the dividing lines.
    let (mut tin, origin) = initial_tin(grid, spec, mx, mz, nested);

    // Steps 2 and 3b: borders, then dividing lines, refined in 1-D. Their
    // target takes its f32 margin from the whole grid's relief, not the
    // chunk's: the chunks on either side of a line must decide it alike.
    // The borders keep the default share next to cut points (a neighbour
    // meshed at another share must draw them alike); the dividing lines,
    // inside the chunk, take this chunk's.
    let line_relief = grid.grid.relief_m.max(relief);
    let border_target = Targets::new(spec.delta_m, line_relief).on_lattice(spec.lattice(), spec.height_step);
    for (vertical, coord, span) in
        [(false, z0, (x0, x1)), (false, z1, (x0, x1)), (true, x0, (z0, z1)), (true, x1, (z0, z1))]
    {
        refine_line(&mut tin, grid, vertical, coord, span, border_target, nested);
    }
    let line_target =
        Targets::with_cut_share(spec.delta_m, line_relief, spec.cut_share).on_lattice(spec.lattice(), spec.height_step);
    if let Some(mx) = mx {
        refine_line(&mut tin, grid, true, mx, (z0, z1), line_target, nested);
    }
    if let Some(mz) = mz {
        refine_line(&mut tin, grid, false, mz, (x0, x1), line_target, nested);
    }
    tin.take_dirty(&mut Vec::new());

    // Step 4: greedy insertion of interior samples.
    let (xs, zs) = ([Some(x0), mx, Some(x1)], [Some(z0), mz, Some(z1)]);
    let lines = Lines::new(&tin, spec.footprint, xs, zs);
    // A parent triangle the cuts and lines left alone holds the same samples
    // against the same plane: its last scan in the parent stands, unless its
    // worst sample now lies on a dividing line (decided in 1-D instead).
    let seeds = spec.parent.map(|p| &p.scans[..]).unwrap_or(&[]);
    let start: Vec<Option<TriangleScan>> = (0..tin.num_triangles() as u32)
        .map(|t| {
            let seed = origin.get(t as usize).and_then(|&o| seeds.get(o as usize)).copied().flatten();
            seed.filter(|s| {
                tin.version(t) == 0 && s.worst.is_none_or(|(_, i, j)| !lines.row_is_line(i) && !lines.col_is_line(j))
            })
        })
        .collect();
    // Step 5 comes with step 4: a chunk filled by parts thins each part.
    let (mut tin, lines, scans) = match spec.split_insertion && (mx.is_some() || mz.is_some()) {
        true if thinning == Thinning::Joined && spec.thin => {
            let (mut tin, mut lines, scans) =
                insert_by_parts(grid, spec, (target, nested), &tin, lines, &start, false)?;
            let mut queue = Queue { grid, clip: spec.footprint, target, heap: TriHeap::default(), scans };
            thin(&mut tin, &mut lines, &mut queue);
            (tin, lines, queue.scans)
        }
        true => insert_by_parts(grid, spec, (target, nested), &tin, lines, &start, spec.thin)?,
        false => {
            let (mut tin, mut lines) = (tin, lines);
            let mut queue = Queue { grid, clip: spec.footprint, target, heap: TriHeap::default(), scans: Vec::new() };
            insert_samples(&mut tin, spec, &mut lines, &mut queue, &start, nested, None)?;
            if spec.thin {
                thin(&mut tin, &mut lines, &mut queue);
            }
            (tin, lines, queue.scans)
        }
    };
    // Before the scans are checked: a flipped triangle's version moves on,
    // and `finish` scans it again.
    if spec.lattice() > 1.0 {
        unsliver(&mut tin, grid, spec.footprint, &lines, target, 1.0 / spec.lattice());
    }
    Ok(Meshed { tin, lines, scans, relief: (relief, magnitude) })
}

/// With quantized output, after step 5: a vertex within `within` (one
/// lattice step) of a free edge of its triangle, its foot on the edge,
/// takes that edge's place: the edge is flipped onto the vertex, if both
/// new triangles are counter-clockwise and within target (else it is
/// flipped back). A child keeps every edge of its parent fixed and cuts it
/// where a dividing line crosses; the crossing moves along the line onto
/// the lattice, by up to a step, and could pass the vertex, turning the
/// child's piece between them over. Beside a fan of nearly parallel parent
/// edges no step along the line took every crossing (Sierra 3 × 3
/// `quantize` at 5 m, 16-cell leaves: a sample 2.7·10⁻⁵ cells from such an
/// edge, one turned triangle in chunk 6/52/44). Both triangles of a free
/// edge lie in one parent triangle, so the flip keeps promise 3.
fn unsliver(tin: &mut Tin, grid: &Window, clip: (Span, Span), lines: &Lines, target: Targets, within: f64) {
    let pos = |v: &V| Coord { x: v.x, y: v.z };
    for t in 0..tin.num_triangles() as u32 {
        for k in 0..3 {
            if tin.is_dead(t) {
                break;
            }
            let e = 3 * t + k;
            if tin.is_fixed(e) {
                continue;
            }
            let Some(f) = tin.twin_of(e) else { continue };
            let (a, b) = tin.ends(e);
            let (pa, pb, pc, pd) = (
                tin.pts[a as usize],
                tin.pts[b as usize],
                tin.pts[tin.apex(e) as usize],
                tin.pts[tin.apex(f) as usize],
            );
            if !beside(&pa, &pb, pos(&pc), within) {
                continue;
            }
            if robust::orient2d(pos(&pc), pos(&pa), pos(&pd)) <= 0.0
                || robust::orient2d(pos(&pd), pos(&pb), pos(&pc)) <= 0.0
            {
                continue;
            }
            let (t1, u1) = tin.flip(e);
            let ok = [t1, u1].iter().all(|&s| {
                let tri = tin.corners(s);
                scan_within(grid, clip, lines, &tri, target.over(&tri)).is_some()
            });
            if !ok {
                tin.flip(3 * t1 + 2);
            }
        }
    }
}

/// Step 4 on one TIN: queues each triangle (from its `start` scan where one
/// stands, else by scanning it), then inserts the worst sample of the worst
/// triangle until every triangle is within its target. `shared`: the vertex
/// count is that of a whole chunk whose parts run at once (the vertices they
/// started from, and a counter of those all parts added).
fn insert_samples(
    tin: &mut Tin,
    spec: &ChunkSpec,
    lines: &mut Lines,
    queue: &mut Queue,
    start: &[Option<TriangleScan>],
    nested: Targeting,
    shared: Option<(usize, &AtomicUsize)>,
) -> Result<(), MeshError> {
    let grid = queue.grid;
    let within = if spec.lattice() > 1.0 { 1.0 / spec.lattice() } else { 1e-7 };
    for t in 0..tin.num_triangles() as u32 {
        match start[t as usize] {
            Some(s) => queue.record(t, 0, s, queue.target.over(&tin.corners(t))),
            None => queue.push(tin, lines, t),
        }
    }
    let mut dirty = Vec::new();
    while let Some(c) = queue.heap.pop() {
        if lines.is_vertex(c.i, c.j) {
            // The sample became a vertex of the next triangle over (it sat on
            // this triangle's edge within rounding): rescan without it.
            queue.push(tin, lines, c.t);
            continue;
        }
        insert_interior(tin, grid, c.t, (c.j, c.i), nested, within);
        lines.mark_vertex(c.i, c.j);
        let vertices = match shared {
            None => tin.pts.len(),
            Some((base, added)) => base + added.fetch_add(1, AtomicOrdering::Relaxed) + 1,
        };
        if vertices > spec.max_vertices {
            let k = spec.key;
            return Err(MeshError::TooDense {
                level: k.level,
                x: k.x,
                y: k.y,
                delta_m: spec.delta_m,
                limit: spec.max_vertices,
            });
        }
        if let Some(cancel) = spec.cancel
            && tin.pts.len().is_multiple_of(1024)
            && cancel.load(AtomicOrdering::Relaxed)
        {
            return Err(MeshError::Cancelled);
        }
        tin.take_dirty(&mut dirty);
        if dirty.binary_search(&c.t).is_err() {
            // Rounding put the sample just across this triangle's edge, into
            // the neighbour: this one is unchanged, so scan it again.
            queue.push(tin, lines, c.t);
        }
        for &t in &dirty {
            queue.push(tin, lines, t);
        }
    }
    Ok(())
}

/// Step 5: takes out the free vertices (inserted in step 4, every edge
/// free) that the mesh no longer needs. Greedy insertion places its early
/// points against large triangles; once the later ones are in, some can
/// go. Each free vertex v is tried, in vertex order, as a collapse onto
/// each neighbour u, cheapest first by v's own sample against the new
/// triangle it falls in; the first whose new triangles all stay
/// counter-clockwise and keep every sample within target is taken. The
/// triangles around a free vertex lie inside one parent triangle (no fixed
/// edge runs between them), so the mesh still refines its parent's. Up to
/// four passes; each after the first visits only the neighbours of the
/// vertices the last one took out (elsewhere nothing changed).
fn thin(tin: &mut Tin, lines: &mut Lines, queue: &mut Queue) {
    let voids = queue.grid.grid.filled.is_some();
    let (mut star, mut changed, mut options, mut probes) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut found = Vec::new();
    let mut visit = vec![true; tin.pts.len()];
    let mut next = vec![false; tin.pts.len()];
    for _ in 0..4 {
        let mut removed = 0;
        for v in 0..tin.pts.len() as u32 {
            let p = tin.pts[v as usize];
            if !visit[v as usize] || !whole(p.x) || !whole(p.z) || !tin.free_star(v, &mut star) {
                continue;
            }
            let scan = |t: u32| queue.scans.get(t as usize).filter(|s| s.version == tin.version(t)).map(|s| s.found);
            // Over a DEM with voids, only where every triangle around v
            // covers data: the holes keep their shape.
            if voids && star.iter().any(|&g| scan(g / 3).is_none_or(|s| s.coverage != Some(Coverage::Valid))) {
                continue;
            }
            // The samples that decide first: v's own (it went in for being
            // far off, and mostly still is) and each old triangle's worst
            // (within the target, mostly close to it).
            probes.clear();
            probes.push((p.x, p.z, p.h));
            probes.extend(
                star.iter().filter_map(|&g| scan(g / 3)?.worst).map(|(_, i, j)| {
                    (f64::from(j), f64::from(i), f64::from(queue.grid.sample(i as usize, j as usize)))
                }),
            );
            // The neighbours v may go onto, by v's own error in its new
            // triangle; the other probes are tested as each is tried below
            // (only up to the one taken).
            options.clear();
            for (k, &e) in star.iter().enumerate() {
                let u = tin.ends(e).1;
                if !fan(tin, &star, u).all(|t| counter_clockwise(&t)) {
                    continue;
                }
                let own = probe_off(fan(tin, &star, u), probes[0], &queue.target);
                if own <= 1.0 {
                    options.push((own, k));
                }
            }
            options.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let (i, j) = (p.z as u32, p.x as u32);
            lines.unmark_vertex(i, j);
            // Each new triangle is scanned as the queue would scan it once
            // the collapse is made (same corners in the same order, same
            // lines), so an accepted collapse records those scans rather
            // than scanning its triangles again.
            let chosen = options.iter().map(|&(_, k)| star[k]).find(|&e| {
                let u = tin.ends(e).1;
                if !probes[1..].iter().all(|&q| probe_off(fan(tin, &star, u), q, &queue.target) <= 1.0) {
                    return false;
                }
                found.clear();
                kept_fan(tin, &star, u).all(|(t, tri)| {
                    fits(queue.grid, queue.clip, lines, &queue.target, &tri, voids)
                        .map(|s| found.push((t, s)))
                        .is_some()
                })
            });
            match chosen {
                Some(e) => {
                    for &g in &star {
                        next[tin.ends(g).1 as usize] = true;
                    }
                    tin.collapse(e, &mut changed);
                    for &t in &changed {
                        match found.iter().find(|f| f.0 == t) {
                            Some(&(_, s)) => {
                                debug_assert_eq!(s, scan_for_queue(queue.grid, queue.clip, lines, &tin.corners(t)));
                                queue.record(t, tin.version(t), s, queue.target.over(&tin.corners(t)));
                            }
                            None => queue.push(tin, lines, t),
                        }
                    }
                    removed += 1;
                }
                None => lines.mark_vertex(i, j),
            }
        }
        if removed == 0 {
            break;
        }
        std::mem::swap(&mut visit, &mut next);
        next.fill(false);
    }
}

/// The triangles a collapse of v onto its neighbour u leaves: each of v's
/// triangles (`star`, its half-edges out) that does not hold u, with u for v.
fn fan<'a>(tin: &'a Tin, star: &'a [u32], u: u32) -> impl Iterator<Item = [V; 3]> + 'a {
    fan_corners(tin, star, u).map(move |(_, corners)| corners.map(|k| tin.pts[k as usize]))
}

/// [`fan`] as the TIN will hold it after the collapse: each triangle's id,
/// and its corners in the TIN's order (u where v was).
fn kept_fan<'a>(tin: &'a Tin, star: &'a [u32], u: u32) -> impl Iterator<Item = (u32, [V; 3])> + 'a {
    fan_corners(tin, star, u).map(move |(g, mut corners)| {
        // Half-edge g leaves corner g % 3 of its triangle.
        corners.rotate_right((g % 3) as usize);
        (g / 3, corners.map(|k| tin.pts[k as usize]))
    })
}

/// Each half-edge g out of v whose triangle does not hold u, and that
/// triangle's corners after the collapse, from u: `[u, w, x]` for g from v
/// to w and its apex x.
fn fan_corners<'a>(tin: &'a Tin, star: &'a [u32], u: u32) -> impl Iterator<Item = (u32, [u32; 3])> + 'a {
    star.iter().map(move |&g| (g, [u, tin.ends(g).1, tin.apex(g)])).filter(move |&(_, [_, w, x])| w != u && x != u)
}

/// Counter-clockwise by more than rounding.
fn counter_clockwise([a, b, c]: &[V; 3]) -> bool {
    robust::orient2d(Coord { x: a.x, y: a.z }, Coord { x: b.x, y: b.z }, Coord { x: c.x, y: c.z }) > 1e-6
}

/// A sample's error against the fan triangle it falls in, as a share of
/// that triangle's target (0 if none holds it).
fn probe_off(fan: impl Iterator<Item = [V; 3]>, (x, z, h): (f64, f64, f64), target: &Targets) -> f64 {
    for tri in fan {
        let [a, b, c] = &tri;
        let Some([_, l1, l2]) = plane_weights(a, b, c, x, z) else { continue };
        if l1 >= -1e-9 && l2 >= -1e-9 && l1 + l2 <= 1.0 + 1e-9 {
            let plane = (1.0 - l1 - l2) * a.h + l1 * b.h + l2 * c.h;
            return (h - plane).abs() / target.over(&tri).max(1e-300);
        }
    }
    0.0
}

/// The queue's scan of `tri` ([`scan_for_queue`]) if every sample in it
/// that is not a vertex lies within its target and the triangle covers
/// data (or, on a DEM without voids, lies between samples); `None` if not.
/// The scan stops at the first sample beyond.
fn fits(
    grid: &Window,
    clip: (Span, Span),
    lines: &Lines,
    target: &Targets,
    tri: &[V; 3],
    voids: bool,
) -> Option<TriangleScan> {
    let found = scan_within(grid, clip, lines, tri, target.over(tri))?;
    let covers = match found.coverage {
        Some(Coverage::Valid) => true,
        Some(Coverage::NoSample) => !voids,
        _ => false,
    };
    covers.then_some(found)
}

/// Barycentric weights of (x, z) in triangle (a, b, c); `None` if it has
/// no area.
fn plane_weights(a: &V, b: &V, c: &V, x: f64, z: f64) -> Option<[f64; 3]> {
    let det = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
    if det.abs() < 1e-300 {
        return None;
    }
    let l1 = ((x - a.x) * (c.z - a.z) - (c.x - a.x) * (z - a.z)) / det;
    let l2 = ((b.x - a.x) * (z - a.z) - (x - a.x) * (b.z - a.z)) / det;
    Some([1.0 - l1 - l2, l1, l2])
}

/// One part of a chunk filled on its own ([`insert_by_parts`]).
struct PartTin {
    /// Its triangles, over the vertices they use (in the chunk's order).
    tin: Tin,
    /// Those vertices' indices in the chunk.
    whole: Vec<u32>,
    /// Per triangle, the parent's scan that stands for it.
    starts: Vec<Option<TriangleScan>>,
    /// Its footprint: the chunk's, cut at the dividing lines.
    footprint: (Span, Span),
    /// What the last scan of each triangle found, once filled.
    scans: Vec<Scan>,
}

/// Step 4 with the chunk cut along its dividing lines into the parts its
/// children will cover, each a TIN of its own, filled in parallel, then
/// joined. The lines are fixed edges and no sample on them is inserted
/// here, so no insertion or flip in one part touches another: each part
/// ends as it would in one TIN of the whole chunk. Its candidates come in
/// the same order (largest error first, ties by sample, not by triangle),
/// so the joined mesh holds the same triangles, numbered part by part.
/// The vertex limit counts the parts' vertices together: whether it is
/// passed is decided by their sum, whatever the threads' pace.
///
/// Step 5 too, where the chunk is thinned: a free vertex's triangles lie in
/// one part (the lines are fixed edges), so each part is thinned on its own
/// with the same collapses, in the same order, as the joined TIN would be
/// (its stars start at the same half-edges, [`Tin::reset_out`]). Thinned
/// whole, a level of fewer than four chunks (`--thin all`) kept every other
/// thread waiting while it thinned.
fn insert_by_parts(
    grid: &Window,
    spec: &ChunkSpec,
    (target, nested): (Targets, Targeting),
    tin: &Tin,
    mut lines: Lines,
    start: &[Option<TriangleScan>],
    thin_parts: bool,
) -> Result<(Tin, Lines, Vec<Scan>), MeshError> {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let (mx, mz) = (midpoint((x0, x1)), midpoint((z0, z1)));
    let n0 = tin.pts.len();
    let beyond = |line: Option<u32>, c: f64| line.is_some_and(|m| c > f64::from(m));
    let mut by_part: [Vec<u32>; 4] = Default::default();
    for t in 0..tin.num_triangles() as u32 {
        let c = tin.corners(t);
        let (cx, cz) = ((c[0].x + c[1].x + c[2].x) / 3.0, (c[0].z + c[1].z + c[2].z) / 3.0);
        by_part[usize::from(beyond(mx, cx)) + 2 * usize::from(beyond(mz, cz))].push(t);
    }
    let parts: Vec<PartTin> = by_part
        .iter()
        .enumerate()
        .filter(|(_, ts)| !ts.is_empty())
        .map(|(k, ts)| {
            let mut used = vec![false; n0];
            for &t in ts {
                for v in tin.triangle(t) {
                    used[v as usize] = true;
                }
            }
            let whole: Vec<u32> = (0..n0 as u32).filter(|&v| used[v as usize]).collect();
            let mut local = vec![u32::MAX; n0];
            for (l, &v) in whole.iter().enumerate() {
                local[v as usize] = l as u32;
            }
            let pts = whole.iter().map(|&v| tin.pts[v as usize]).collect();
            let tris: Vec<[u32; 3]> = ts.iter().map(|&t| tin.triangle(t).map(|v| local[v as usize])).collect();
            let fixed: Vec<[bool; 3]> = ts.iter().map(|&t| [0, 1, 2].map(|e| tin.is_fixed(3 * t + e))).collect();
            let starts = ts.iter().map(|&t| start[t as usize]).collect();
            let span = |lo: u32, mid: Option<u32>, hi: u32, far: bool| match (mid, far) {
                (Some(m), false) => (lo, m),
                (Some(m), true) => (m, hi),
                (None, _) => (lo, hi),
            };
            let footprint = (span(x0, mx, x1, k % 2 == 1), span(z0, mz, z1, k >= 2));
            PartTin { tin: Tin::from_soup(pts, &tris, &fixed), whole, starts, footprint, scans: Vec::new() }
        })
        .collect();
    let added = AtomicUsize::new(0);
    let (xs, zs) = ([Some(x0), mx, Some(x1)], [Some(z0), mz, Some(z1)]);
    let filled: Vec<Result<PartTin, MeshError>> = parts
        .into_par_iter()
        .map(|mut part| {
            let mut lines = Lines::new(&part.tin, part.footprint, xs, zs);
            let mut queue = Queue { grid, clip: spec.footprint, target, heap: TriHeap::default(), scans: Vec::new() };
            insert_samples(&mut part.tin, spec, &mut lines, &mut queue, &part.starts, nested, Some((n0, &added)))?;
            if thin_parts {
                // Each star starts where the joined TIN's would.
                part.tin.reset_out();
                thin(&mut part.tin, &mut lines, &mut queue);
            }
            part.scans = queue.scans;
            Ok(part)
        })
        .collect();
    // Join: the chunk's vertices so far, then each part's new ones in turn.
    let mut pts = tin.pts.clone();
    let mut scans = Vec::new();
    let mut joined = Vec::new();
    for part in filled {
        let PartTin { tin: sub, scans: sub_scans, whole, .. } = part?;
        let (shared, first_new) = (whole.len(), pts.len());
        pts.extend_from_slice(&sub.pts[shared..]);
        // The samples the part inserted and kept are vertices of the whole
        // now (thinning leaves the ones it took out unconnected).
        for (v, p) in sub.pts.iter().enumerate().skip(shared) {
            if sub.is_live(v as u32) {
                lines.mark_vertex(p.z as u32, p.x as u32);
            }
        }
        let id: Vec<u32> =
            whole.iter().copied().chain((first_new..first_new + sub.pts.len() - shared).map(|v| v as u32)).collect();
        for t in 0..sub.num_triangles() as u32 {
            // A scan of the triangle as it ended stands (the joined TIN
            // starts every triangle at version 0).
            let stands = sub_scans.get(t as usize).filter(|s| s.version == sub.version(t));
            scans.push(match stands {
                Some(s) => Scan { version: 0, found: s.found },
                None => Scan { version: u32::MAX, found: TriangleScan { max_err: 0.0, coverage: None, worst: None } },
            });
        }
        joined.push((sub, id));
    }
    let parts: Vec<(&Tin, &[u32])> = joined.iter().map(|(sub, id)| (sub, &id[..])).collect();
    Ok((Tin::from_parts(pts, &parts), lines, scans))
}
