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
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let window = Window::new(grid, spec.footprint);
    let grid = &window;
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
    Ok(finish(grid, spec, &tin, &lines, &scans, (relief, magnitude)))
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

/// The error a sample may keep, by what can move the surface over it once
/// the chunk is written.
///
/// - Where every corner is a DEM sample (`exact`): nothing. Each sample
///   corner is written exactly — its f32 height in f32, relative to a
///   translation chosen so that the difference is exact
///   ([`crate::output::gltf::chunk_origin`]), or on the quantize grid less
///   what its height rounds by ([`Targets::rounding`]: nothing for a DEM of
///   whole metres at a step of 1/8 m) — and `verify` snaps a
///   position within f32 rounding of a sample index to that index. What is
///   left is the f64 arithmetic of the two error measurements, which
///   `verify` allows for.
/// - A triangle with a cut point for a corner (`cut`: where a dividing line
///   crosses a parent edge, off the sample grid): that corner's height
///   rounds (by at most 2⁻²⁴ of the relief in f32; 4ε·relief is eight times
///   that) and its position moves along the line (f32, or half a quantize
///   step), which on steep ground tilts the triangle: 2 % of δ
///   ([`CUT_SHARE`]) covers that in f32. Half a quantize step can move it
///   further (on Provence's Verdon gorge at 1 m, to 8.058 m in a chunk of
///   δ 8 m), so a quantized chunk is measured again as it will be written
///   and meshed with a smaller share where it misses (`ChunkSpec::cut_share`).
///
/// The margin is not applied everywhere: on integer heights many samples
/// lie within 2 % of δ, and meshing to 0.98·δ would cost some 10 % more
/// triangles than a TIN to δ.
#[derive(Clone, Copy, Debug)]
pub struct Targets {
    /// Where every corner is written exactly.
    pub exact: f64,
    /// Next to a cut point the file rounds.
    pub cut: f64,
    /// Steps per cell of the grid the file holds exactly: 1 (the samples)
    /// for f32 output, 2^k for quantized output, whose cut points are
    /// placed on that grid ([`ChunkSpec::cut_lattice`]) and so count as
    /// exact corners.
    pub lattice: f64,
    /// The height step quantized output rounds every height to (0: f32
    /// output, whose sample heights are written exactly).
    pub step_y: f64,
}

impl Targets {
    /// The targets for δ over ground of this relief.
    pub fn new(delta_m: f64, relief_m: f64) -> Self {
        Self::with_cut_share(delta_m, relief_m, CUT_SHARE)
    }

    /// The same with `share` of δ next to cut points.
    pub fn with_cut_share(delta_m: f64, relief_m: f64, share: f64) -> Self {
        let rounding = relief_m * 4.0 * f64::from(f32::EPSILON);
        Targets { exact: delta_m, cut: (delta_m * share - rounding).max(0.0), lattice: 1.0, step_y: 0.0 }
    }

    /// The same for a file that holds positions on `lattice` steps per cell
    /// and, if quantized, heights on multiples of `step_y`.
    pub fn on_lattice(self, lattice: f64, step_y: Option<f64>) -> Self {
        Targets { lattice, step_y: step_y.unwrap_or(0.0), ..self }
    }

    /// The target over a triangle, or a line interval, with these corners:
    /// the exact or the cut-point share of δ, less the most any corner's
    /// height moves when the file rounds it ([`Targets::rounding`]).
    fn over(&self, corners: &[V]) -> f64 {
        let share = if self.rounds(corners) { self.cut } else { self.exact };
        // A triangle with a cut point for a corner keeps half a step
        // whatever its corners round by: crowded crossings make steep
        // slivers there, whose planes f64 evaluates only to some 10⁻⁹ m, and
        // a sample exactly δ off (common on whole metres) would read over δ.
        let rounding = if self.step_y > 0.0 && is_cut(corners) { self.step_y / 2.0 } else { self.rounding(corners) };
        share - rounding
    }

    /// How far rounding to the height step moves the surface anywhere over
    /// these corners: the most any one of them moves, as the surface at a
    /// point is a weighted mean of its corners. On a DEM of whole metres
    /// with a step of 1/8 m, every sample corner stays where it is, so a
    /// triangle of samples keeps all of δ (one δ − step/2 for every
    /// triangle cost California at 1 m 4.8 % more vertices); a cut point's
    /// height (a line's profile between two samples) moves up to half a step.
    /// Exact: the step is a power of two, so h / step, its rounding and the
    /// product are exact in f64.
    pub fn rounding(&self, corners: &[V]) -> f64 {
        corners.iter().map(|v| rounds_by(v.h, self.step_y)).fold(0.0, f64::max)
    }
    /// Whether a grid coordinate is off the grid the file holds exactly.
    #[inline]
    fn off(&self, c: f64) -> bool {
        off_lattice(c, self.lattice)
    }

    /// Whether any of these corners is (a cut point the file rounds).
    fn rounds(&self, corners: &[V]) -> bool {
        corners.iter().any(|v| self.off(v.x) || self.off(v.z))
    }
}

/// How far a height moves when the file rounds it to a multiple of `step`
/// (0: f32 output, which writes sample heights exactly).
fn rounds_by(h: f64, step: f64) -> f64 {
    if step == 0.0 { 0.0 } else { (h - (h / step).round() * step).abs() }
}

/// Whether `c` (any finite coordinate) is a whole number.
fn whole_f(c: f64) -> bool {
    c == c.round()
}

/// Whether grid coordinate `c` is off the grid of `lattice` steps per cell.
#[inline]
fn off_lattice(c: f64, lattice: f64) -> bool {
    if lattice == 1.0 {
        return !whole(c);
    }
    let y = c * lattice;
    (y as i64) as f64 != y
}

/// Whether a corner is off the sample grid (a cut point).
fn is_cut(corners: &[V]) -> bool {
    corners.iter().any(|v| !whole(v.x) || !whole(v.z))
}

/// Whether a grid coordinate (≥ 0, far below 2³²) is a whole sample index;
/// `fract` is a libm call on x86-64 without SSE4.1, and this runs per scan.
#[inline]
fn whole(c: f64) -> bool {
    f64::from(c as u32) == c
}

/// Largest minus smallest valid height in a footprint (0 if none), and the
/// largest |height|.
fn footprint_relief(grid: &Window, footprint: (Span, Span)) -> (f64, f64) {
    let ((x0, x1), (z0, z1)) = footprint;
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for i in z0..=z1 {
        for j in x0..=x1 {
            let h = grid.sample(i as usize, j as usize);
            if !h.is_nan() {
                lo = lo.min(f64::from(h));
                hi = hi.max(f64::from(h));
            }
        }
    }
    if hi >= lo { (hi - lo, lo.abs().max(hi.abs())) } else { (0.0, 0.0) }
}

/// What f64 arithmetic may add to an error measured over heights of this
/// relief and magnitude: a few units in the last place of the heights
/// involved, for which 256 of them is ample (4·10⁻¹⁰ m at 3 km). A sample
/// exactly δ off — common on integer heights — reads as δ give or take
/// that, from one triangle or its neighbour.
pub fn f64_slack(relief_m: f64, magnitude_m: f64) -> f64 {
    256.0 * f64::EPSILON * (relief_m + magnitude_m)
}

/// Counter-clockwise triangles over a vertex list, with a fixed flag per edge.
struct Soup {
    pts: Vec<V>,
    tris: Vec<[u32; 3]>,
    fixed: Vec<[bool; 3]>,
    /// The parent triangle each one is, unchanged (`u32::MAX`: a piece of a
    /// cut one, or the top level's).
    origin: Vec<u32>,
}

/// The starting triangulation: the parent's triangles inside the footprint
/// with every parent edge fixed (the top level: its four corners), cut along
/// the dividing lines, whose pieces are fixed too.
fn initial_tin(
    grid: &Window,
    spec: &ChunkSpec,
    mx: Option<u32>,
    mz: Option<u32>,
    nested: Targeting,
) -> (Tin, Vec<u32>) {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let mut soup = match spec.parent {
        Some(p) => {
            let inside = |v: &MeshVertex| {
                v.x >= f64::from(x0) && v.x <= f64::from(x1) && v.z >= f64::from(z0) && v.z <= f64::from(z1)
            };
            let mut remap = vec![u32::MAX; p.vertices.len()];
            let mut pts = Vec::new();
            for (k, v) in p.vertices.iter().enumerate() {
                if inside(v) {
                    remap[k] = pts.len() as u32;
                    pts.push(V { x: v.x, z: v.z, h: v.h, ph: v.h });
                }
            }
            // Stored clockwise in grid space (see `finish`): turn them back.
            let (tris, origin): (Vec<[u32; 3]>, Vec<u32>) = p
                .triangles
                .iter()
                .enumerate()
                .map(|(k, t)| ([remap[t[0] as usize], remap[t[2] as usize], remap[t[1] as usize]], k as u32))
                .filter(|(t, _)| !t.contains(&u32::MAX))
                .unzip();
            let fixed = vec![[spec.keep_parent_edges; 3]; tris.len()];
            Soup { pts, tris, fixed, origin }
        }
        None => {
            // The corners, and with lines for parts the samples where they
            // meet the borders and each other: a rectangle between each
            // pair, halved on the diagonal the four corners' pair takes.
            let (mut xs, mut zs) = (vec![x0], vec![z0]);
            if spec.dividing_lines == DividingLines::Parts {
                xs.extend(mx);
                zs.extend(mz);
            }
            xs.push(x1);
            zs.push(z1);
            let mut pts = Vec::with_capacity(xs.len() * zs.len());
            for &i in &zs {
                for &j in &xs {
                    let h = grid.vertex_height(i as usize, j as usize);
                    pts.push(V { x: f64::from(j), z: f64::from(i), h, ph: h });
                }
            }
            let n = xs.len() as u32;
            let mut tris = Vec::new();
            for r in 0..zs.len() as u32 - 1 {
                for c in 0..n - 1 {
                    let k = r * n + c;
                    tris.extend([[k, k + 1, k + n + 1], [k, k + n + 1, k + n]]);
                }
            }
            let count = tris.len();
            Soup { pts, tris, fixed: vec![[false; 3]; count], origin: vec![u32::MAX; count] }
        }
    };
    let inherited = soup.pts.len();
    for (vertical, line) in [(true, mx), (false, mz)] {
        if let Some(coord) = line {
            cut_along_line(&mut soup, grid, Line { vertical, coord }, (nested, inherited), spec.lattice());
        }
    }
    (Tin::from_soup(soup.pts, &soup.tris, &soup.fixed), soup.origin)
}

/// A dividing line: `x = coord` (`vertical`) or `z = coord`.
#[derive(Clone, Copy)]
struct Line {
    vertical: bool,
    coord: u32,
}

/// Cuts every triangle `line` crosses, at points on the crossed edges, so
/// that the line becomes a chain of fixed edges. A cut point's morph target
/// is the parent surface's height there; its own height is the line's
/// profile (the sample's, where a crossing falls on a sample). A crossing
/// shared by two triangles is computed once.
///
/// With `lattice` > 1 (quantized output) each crossing then moves along the
/// line to the nearest of `lattice` steps per cell, where the file holds it
/// exactly, so the mesher measures the surface the file will draw. Rounding
/// it only at write time moved it by up to half a step after the mesher had
/// judged the triangles around it: on steep ground, next to a sliver of the
/// parent, that tilted them far past δ (California at 1 m: 151 chunks over
/// δ as written, up to 10 m at δ 1 m). The morph target of a crossing of a
/// parent edge stays the parent's height at the exact crossing, so the
/// pieces' morph planes are the parent triangle's to within the slope times
/// half a step, as `verify` allows; a crossing of a piece edge (the second
/// line's, across the first's pieces) and every vertex placed later take
/// the parent's height where they are ([`Targeting`]).
/// Crossings closer together than a step (a fan of parent edges from a
/// vertex just off the line) land on one point as separate vertices with
/// flat pieces between them, as the file would draw them anyway; a crossing
/// whose move would turn a piece over tries the other neighbouring step,
/// then stays where it is and keeps the mesher's margin.
fn cut_along_line(soup: &mut Soup, grid: &Window, line: Line, nested: (Targeting, usize), lattice: f64) {
    let base = soup.pts.len();
    // Per crossing (edge key), how many of its lattice points folded a piece:
    // the nearest first, then the other neighbour, then none (it stays).
    let mut tried: HashMap<(u32, u32), u8> = HashMap::new();
    loop {
        soup.pts.truncate(base);
        let (tris, fixed, origin, moved) = cut_pieces(soup, grid, line, nested, lattice, &tried);
        // Crossings closer together than a step land on one point: the
        // pieces between them are flat, which the file cannot avoid and the
        // mesh carries (each crossing keeps its own morph target, so no
        // piece's morph is wrong; the TIN looks past flat triangles). A
        // piece turned over, or flattened onto a line, sends one of its
        // crossings on, the one tried least.
        // Flat is allowed only where two corners are one point; three
        // distinct corners in a line make a wall with no area under it, the
        // surface two-valued along it (California at 1 m: a child's morph
        // targets read three heights there, one 2.4 m off every parent plane).
        let mut folded: Vec<(u32, u32)> = tris
            .iter()
            .filter(|t| t.iter().any(|v| moved.contains_key(v)))
            .filter(|t| turned(&soup.pts, t))
            .filter_map(|t| {
                t.iter().filter_map(|v| moved.get(v)).copied().min_by_key(|k| (tried.get(k).copied().unwrap_or(0), *k))
            })
            .collect();
        if folded.is_empty() {
            soup.tris = tris;
            soup.fixed = fixed;
            soup.origin = origin;
            return;
        }
        folded.sort_unstable();
        folded.dedup();
        for k in folded {
            *tried.entry(k).or_insert(0) += 1;
        }
    }
}

/// Whether piece `t` is turned over, or flattened onto a line through
/// three distinct points (flat is allowed only where two corners are one
/// point).
fn turned(pts: &[V], t: &[u32; 3]) -> bool {
    let pos = |v: u32| {
        let v = &pts[v as usize];
        Coord { x: v.x, y: v.z }
    };
    let o = robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2]));
    let same = |a: u32, b: u32| pos(a).x == pos(b).x && pos(a).y == pos(b).y;
    o < 0.0 || (o == 0.0 && !same(t[0], t[1]) && !same(t[1], t[2]) && !same(t[2], t[0]))
}

/// The pieces of [`cut_along_line`], each crossing (edge key) on the
/// nearest lattice point, or the other neighbour after `tried` 1 fold, or
/// left exact after 2; and the crossings moved onto the lattice (vertex →
/// edge key).
#[allow(clippy::type_complexity)]
fn cut_pieces(
    soup: &mut Soup,
    grid: &Window,
    Line { vertical, coord }: Line,
    (nested, inherited): (Targeting, usize),
    lattice: f64,
    tried: &HashMap<(u32, u32), u8>,
) -> (Vec<[u32; 3]>, Vec<[bool; 3]>, Vec<u32>, HashMap<u32, (u32, u32)>) {
    let c = f64::from(coord);
    let across = |v: &V| if vertical { v.x } else { v.z };
    let along = |v: &V| if vertical { v.z } else { v.x };
    let side = |v: &V| across(v).total_cmp(&c) as i8;
    let mut cuts: HashMap<(u32, u32), u32> = HashMap::new();
    let mut moved: HashMap<u32, (u32, u32)> = HashMap::new();
    let mut cut = |pts: &mut Vec<V>, a: u32, b: u32| -> u32 {
        let key = (a.min(b), a.max(b));
        *cuts.entry(key).or_insert_with(|| {
            let (p, q) = (pts[key.0 as usize], pts[key.1 as usize]);
            let s = (c - across(&p)) / (across(&q) - across(&p));
            let mut t = along(&p) + s * (along(&q) - along(&p));
            let ph = p.ph + s * (q.ph - p.ph);
            let at = |t: f64| {
                let (j, i) = if vertical { (coord, t as u32) } else { (t as u32, coord) };
                grid.vertex_height(i as usize, j as usize)
            };
            let mut on_lattice = false;
            let attempt = tried.get(&key).copied().unwrap_or(0);
            if (t - t.round()).abs() >= 1e-6 && lattice > 1.0 {
                // The nearest grid point, then the other neighbour; never a
                // sample's (a vertex may be there already: the border's
                // midpoint, forced where the line meets it).
                let (nearest, y) = ((t * lattice).round(), t * lattice);
                let other = if y > nearest { nearest + 1.0 } else { nearest - 1.0 };
                let mut candidates = [nearest, other].into_iter().map(|n| n / lattice).filter(|t| !whole_f(*t));
                if let Some(r) = candidates.nth(usize::from(attempt)) {
                    t = r;
                    on_lattice = true;
                }
            }
            // A crossing that falls on a sample takes the sample itself (its
            // fill over nodata), so a border crossing (always on a sample) is
            // the same vertex the neighbour across that border makes. Between
            // samples it takes the line's own profile, not the parent's
            // height there: that can be δ away, and where the line's
            // refinement puts a sample a hair from the crossing, the two
            // would make a near-vertical wall that the next level's cuts
            // shred into slivers no f32 file can place. Only the
            // morph target must lie on the parent surface.
            let h = if (t - t.round()).abs() < 1e-6 {
                t = t.round();
                at(t)
            } else {
                let (lo, hi) = (t.floor(), t.ceil());
                at(lo) + (t - lo) * (at(hi) - at(lo))
            };
            let (x, z) = if vertical { (c, t) } else { (t, c) };
            // A crossing of an edge an earlier line's cut made (a piece
            // edge, inside one parent triangle, from a crossing the grid
            // may have moved off the parent's planes) takes the parent's
            // height where it lands ([`Targeting`]); a crossing of a parent
            // edge keeps the height at the exact crossing, right for the
            // parent triangles on both sides of that edge.
            let ph = match nested.parent {
                _ if !nested.nested => h,
                Some(parent) if key.1 as usize >= inherited => parent.locate(x, z, 1e-6).map_or(ph, |(_, ph)| ph),
                _ => ph,
            };
            pts.push(V { x, z, h, ph });
            let v = (pts.len() - 1) as u32;
            if on_lattice {
                moved.insert(v, key);
            }
            v
        })
    };
    let mut tris = Vec::with_capacity(soup.tris.len() + soup.tris.len() / 8);
    let mut fixed = Vec::with_capacity(tris.capacity());
    let mut origin = Vec::with_capacity(tris.capacity());
    for ((&t, &f), &o) in soup.tris.iter().zip(&soup.fixed).zip(&soup.origin) {
        let s = t.map(|v| side(&soup.pts[v as usize]));
        let crosses = |k: usize| s[k] * s[(k + 1) % 3] < 0;
        if let Some(k) = (0..3).find(|&k| crosses(k) && crosses((k + 2) % 3)) {
            // Corner k alone on its side: cut edges k and k + 2.
            let (a, b, cc) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (fab, fbc, fca) = (f[k], f[(k + 1) % 3], f[(k + 2) % 3]);
            let p = cut(&mut soup.pts, a, b);
            let q = cut(&mut soup.pts, cc, a);
            tris.push([a, p, q]);
            fixed.push([fab, true, fca]);
            origin.extend([u32::MAX; 3]);
            // The quadrilateral p, b, c, q: the Delaunay diagonal.
            let pos = |v: u32| {
                let v = &soup.pts[v as usize];
                Coord { x: v.x, y: v.z }
            };
            if robust::incircle(pos(p), pos(b), pos(cc), pos(q)) > 0.0 {
                tris.extend([[p, b, q], [b, cc, q]]);
                fixed.extend([[fab, false, true], [fbc, fca, false]]);
            } else {
                tris.extend([[p, b, cc], [p, cc, q]]);
                fixed.extend([[fab, fbc, false], [false, fca, true]]);
            }
        } else if let Some(k) = (0..3).find(|&k| s[k] == 0 && crosses((k + 1) % 3)) {
            // Through corner k and across the opposite edge.
            let (a, b, cc) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (fab, fbc, fca) = (f[k], f[(k + 1) % 3], f[(k + 2) % 3]);
            let p = cut(&mut soup.pts, b, cc);
            tris.extend([[a, b, p], [a, p, cc]]);
            fixed.extend([[fab, fbc, true], [true, fbc, fca]]);
            origin.extend([u32::MAX; 2]);
        } else {
            // Not crossed; an edge lying on the line becomes fixed.
            let on = |k: usize| s[k] == 0 && s[(k + 1) % 3] == 0;
            tris.push(t);
            fixed.push([f[0] || on(0), f[1] || on(1), f[2] || on(2)]);
            origin.push(o);
        }
    }
    (tris, fixed, origin, moved)
}

/// Inserts interior sample (i, j), queued from triangle `t`. A sample within
/// `within` cells of a fixed edge splits that edge instead of leaving a sliver
/// beside it: within rounding (10⁻⁷), a zero-width sliver would make the
/// surface two-valued along the edge; with quantized output, within one
/// step of the lattice, the sliver's far corners are cut points the file
/// may move by a step, and a later level's crossing of the edge, placed on
/// the lattice, turned it over (Sierra 3 × 3 at 5 m, 32-cell leaves: 34
/// triangles, samples 10⁻⁴ cells from a parent edge).
fn insert_interior(tin: &mut Tin, grid: &Window, t: u32, (j, i): (u32, u32), nested: Targeting, within: f64) {
    let p = Coord { x: f64::from(j), y: f64::from(i) };
    let h = grid.vertex_height(i as usize, j as usize);
    match tin.locate_from(t, p) {
        Position::Face(f) => {
            let near = (0..3).map(|k| 3 * f + k).find(|&e| {
                if !tin.is_fixed(e) {
                    return false;
                }
                let (a, b) = tin.ends(e);
                beside(&tin.pts[a as usize], &tin.pts[b as usize], p, within)
                    && tin.splits_cleanly(e, p)
                    && data_across(tin, grid, e)
            });
            match near {
                Some(e) => {
                    let ph = nested.on_edge(tin, e, p, h);
                    let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
                    tin.split_edge(e, v);
                }
                None => {
                    let ph = nested.in_triangle(tin, f, p, h);
                    let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
                    tin.split_triangle(f, v);
                }
            }
        }
        Position::Edge(e) => {
            let ph = nested.on_edge(tin, e, p, h);
            let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
            tin.split_edge(e, v);
        }
        Position::Vertex(_) | Position::Outside => {}
    }
}

/// Whether `p` lies within `within` cells of the segment a–b, its foot
/// strictly between the ends.
fn beside(a: &V, b: &V, p: Coord<f64>, within: f64) -> bool {
    let (dx, dz) = (b.x - a.x, b.z - a.z);
    let len2 = dx * dx + dz * dz;
    let cross = dx * (p.y - a.z) - dz * (p.x - a.x);
    let along = (dx * (p.x - a.x) + dz * (p.y - a.z)) / len2;
    cross.abs() <= within * len2.sqrt() && along > 0.0 && along < 1.0
}

/// Whether the triangle across half-edge `e` covers a valid sample (or no
/// triangle is across, or the DEM has no voids). A sample split onto `e`
/// becomes a corner of the triangles across, and a corner with data keeps
/// a triangle written ([`finish`]); across a parent edge over a void, the
/// parent's triangle is not written and the child's would stand outside
/// the parent's surface (Seamount `quantize` at 5 m, 16-cell leaves).
fn data_across(tin: &Tin, grid: &Window, e: u32) -> bool {
    if grid.grid.filled.is_none() {
        return true;
    }
    let Some(tri) = tin.across(e) else { return true };
    let (x1, z1) = grid.last();
    let clip = ((grid.x0 as u32, x1 as u32), (grid.z0 as u32, z1 as u32));
    let mut any = false;
    scan_triangle(grid, clip, &tri, |_, _, _| {
        any = true;
        f64::INFINITY
    });
    any
}

/// Where a new vertex's morph target, the parent surface's height at it,
/// comes from: interpolated over the triangle or edge of this TIN it falls
/// in (with f32 output every triangle refines one parent triangle, linear
/// there), or, with quantized output, read from the parent itself.
///
/// A quantized file moves each crossing along its line onto its grid. The
/// crossing keeps the parent's height at the exact crossing, which the
/// planes of the parent triangles beside it miss at the moved point by
/// their slope times the move, and the pieces' edges move with it, so a
/// sample may fall on the wrong side of a parent edge by that much: on a
/// parent sliver either is metres for a thousandth of a cell. Interpolated,
/// that went on into every vertex placed against the crossing, and from
/// them into the next, inside ordinary parent triangles whose gentle slope
/// allows no such miss (Provence at 5 m, 16-cell leaves: a sample 0.75 m
/// off its parent; Sierra 3 × 3 at 5 m, 16-cell leaves: 7.3 m, two
/// samples from the crossing). Reading the parent costs quantized builds'
/// mesher about 45 % more time (Sierra 3 × 3 at 5 m: 8.5 → 12.6
/// thread-seconds, the whole build 9.0 → 11.1 s).
#[derive(Clone, Copy)]
struct Targeting<'a> {
    /// The chunk has a parent (at the top level a target is the height).
    nested: bool,
    /// The parent's surface, given for quantized output.
    parent: Option<&'a SurfaceLocator<'a>>,
}

impl Targeting<'_> {
    /// The target at `p`, of height `h`, whose parent height interpolates
    /// as `interpolated`.
    fn target(&self, p: Coord<f64>, h: f64, interpolated: impl FnOnce() -> f64) -> f64 {
        match self.parent {
            _ if !self.nested => h,
            Some(parent) => parent.locate(p.x, p.y, 1e-6).map_or_else(interpolated, |(_, ph)| ph),
            None => interpolated(),
        }
    }

    /// The target at `p` of height `h` in triangle `t`.
    fn in_triangle(&self, tin: &Tin, t: u32, p: Coord<f64>, h: f64) -> f64 {
        let [a, b, c] = tin.corners(t);
        self.target(p, h, || match plane_weights(&a, &b, &c, p.x, p.y) {
            Some([_, l1, l2]) => (1.0 - l1 - l2) * a.ph + l1 * b.ph + l2 * c.ph,
            None => a.ph,
        })
    }

    /// The target at `p` of height `h` on (or next to) half-edge `e`.
    fn on_edge(&self, tin: &Tin, e: u32, p: Coord<f64>, h: f64) -> f64 {
        let (a, b) = tin.ends(e);
        let (a, b) = (tin.pts[a as usize], tin.pts[b as usize]);
        self.target(p, h, || {
            let (dx, dz) = (b.x - a.x, b.z - a.z);
            let s = (((p.x - a.x) * dx + (p.y - a.z) * dz) / (dx * dx + dz * dz)).clamp(0.0, 1.0);
            a.ph + s * (b.ph - a.ph)
        })
    }
}

/// 1-D greedy refinement of the line `x = coord` (`vertical`) or `z = coord`
/// over `span`, a chain of edges: split every interval at its worst valid
/// sample until all are within `target`.
fn refine_line(
    tin: &mut Tin,
    grid: &Window,
    vertical: bool,
    coord: u32,
    span: Span,
    target: Targets,
    nested: Targeting,
) {
    let c = f64::from(coord);
    let (lo, hi) = (f64::from(span.0), f64::from(span.1));
    let mut pts: Vec<(f64, u32)> = tin
        .pts
        .iter()
        .enumerate()
        .filter_map(|(k, v)| {
            let (along, across) = if vertical { (v.z, v.x) } else { (v.x, v.z) };
            (across == c && along >= lo && along <= hi).then_some((along, k as u32))
        })
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    chain_ties(&mut pts, |a, b| tin.find_edge(a, b).is_some());
    let sample = |t: u32| if vertical { (coord, t) } else { (t, coord) };
    let mut stack: Vec<((f64, u32), (f64, u32))> = pts.windows(2).map(|w| (w[0], w[1])).collect();
    while let Some((a, b)) = stack.pop() {
        let (ha, hb) = (tin.pts[a.1 as usize].h, tin.pts[b.1 as usize].h);
        let target = target.over(&[tin.pts[a.1 as usize], tin.pts[b.1 as usize]]);
        let first = (a.0 + 1e-9).ceil() as i64;
        let last = (b.0 - 1e-9).floor() as i64;
        let mut worst: Option<(f64, u32, f64)> = None;
        for t in first..=last {
            let (j, i) = sample(t as u32);
            let h = grid.sample(i as usize, j as usize);
            if h.is_nan() {
                continue;
            }
            let h = f64::from(h);
            let s = (t as f64 - a.0) / (b.0 - a.0);
            let err = (h - (ha + s * (hb - ha))).abs();
            if err > target && worst.is_none_or(|w| err > w.0) {
                worst = Some((err, t as u32, h));
            }
        }
        let Some((_, t, h)) = worst else { continue };
        let Some(e) = tin.find_edge(a.1, b.1) else {
            unreachable!("a line is a chain of edges");
        };
        let s = (f64::from(t) - a.0) / (b.0 - a.0);
        let (j, i) = sample(t);
        let (pa, pb) = (tin.pts[a.1 as usize], tin.pts[b.1 as usize]);
        let ph = nested.target(Coord { x: f64::from(j), y: f64::from(i) }, h, || pa.ph + s * (pb.ph - pa.ph));
        let v = tin.add_vertex(V { x: f64::from(j), z: f64::from(i), h, ph });
        tin.split_edge(e, v);
        let m = (f64::from(t), v);
        stack.push((a, m));
        stack.push((m, b));
    }
}

/// The samples step 4 leaves alone: those on borders and dividing lines
/// (decided in 1-D), and those that are already vertices. The latter matters
/// where a vertex sits (within rounding) on an edge split at a non-sample
/// point: the zero-width sliver there makes the neighbouring triangle's plane
/// look wrong at the vertex, which is exact.
struct Lines {
    xs: [Option<u32>; 3],
    zs: [Option<u32>; 3],
    origin: (u32, u32),
    width: usize,
    vertex: Vec<bool>,
}

impl Lines {
    fn new(tin: &Tin, footprint: (Span, Span), xs: [Option<u32>; 3], zs: [Option<u32>; 3]) -> Self {
        let ((x0, x1), (z0, z1)) = footprint;
        let width = (x1 - x0 + 1) as usize;
        let mut l = Lines { xs, zs, origin: (x0, z0), width, vertex: vec![false; width * (z1 - z0 + 1) as usize] };
        for p in &tin.pts {
            if whole(p.x) && whole(p.z) {
                l.mark_vertex(p.z as u32, p.x as u32);
            }
        }
        l
    }
    #[inline]
    fn mark_vertex(&mut self, i: u32, j: u32) {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize] = true;
    }
    #[inline]
    fn unmark_vertex(&mut self, i: u32, j: u32) {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize] = false;
    }
    #[inline]
    fn is_vertex(&self, i: u32, j: u32) -> bool {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize]
    }
    #[inline]
    fn row_is_line(&self, i: u32) -> bool {
        self.zs.contains(&Some(i))
    }
    #[inline]
    fn col_is_line(&self, j: u32) -> bool {
        self.xs.contains(&Some(j))
    }
}

#[derive(Clone, Copy)]
struct Candidate {
    err: f64,
    t: u32,
    i: u32,
    j: u32,
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    fn cmp(&self, o: &Self) -> Ordering {
        // Largest error first; ties broken by position so the order is total.
        self.err.total_cmp(&o.err).then((o.i, o.j).cmp(&(self.i, self.j)))
    }
}

/// What the last scan of a triangle found.
#[derive(Clone, Copy)]
struct Scan {
    /// The triangle's version when scanned.
    version: u32,
    /// What it found.
    found: TriangleScan,
}

/// What scanning one triangle found, kept with a finished mesh
/// ([`ChunkMesh::scans`]) so that a child starting from that triangle need
/// not scan it again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleScan {
    /// Largest error over its valid samples that are not vertices.
    max_err: f64,
    /// What it covers (None: zero area).
    coverage: Option<Coverage>,
    /// Its worst sample step 4 may insert, whatever the target: (error, row,
    /// column).
    worst: Option<(f64, u32, u32)>,
}

/// Step 4's queue: each triangle's worst sample beyond the target.
struct Queue<'g> {
    grid: &'g Window<'g>,
    clip: (Span, Span),
    target: Targets,
    heap: TriHeap,
    scans: Vec<Scan>,
}

/// A max-heap of candidates holding at most one per triangle, which a rescan
/// replaces in place: no stale entries to pop, and a heap only as large as
/// the number of triangles still beyond the target.
#[derive(Default)]
struct TriHeap {
    heap: Vec<Candidate>,
    /// Per triangle: its entry's index in `heap`, or `u32::MAX`.
    pos: Vec<u32>,
}

impl TriHeap {
    /// Makes `c` triangle `t`'s entry (`None`: no entry).
    fn set(&mut self, t: u32, c: Option<Candidate>) {
        if self.pos.len() <= t as usize {
            self.pos.resize(t as usize + 1, u32::MAX);
        }
        match (self.pos[t as usize], c) {
            (u32::MAX, None) => {}
            (u32::MAX, Some(c)) => {
                self.heap.push(c);
                self.pos[t as usize] = (self.heap.len() - 1) as u32;
                self.up(self.heap.len() - 1);
            }
            (k, Some(c)) => {
                self.heap[k as usize] = c;
                let k = self.up(k as usize);
                self.down(k);
            }
            (k, None) => self.remove(k as usize),
        }
    }

    /// Takes the largest candidate.
    fn pop(&mut self) -> Option<Candidate> {
        let top = *self.heap.first()?;
        self.remove(0);
        Some(top)
    }

    fn remove(&mut self, k: usize) {
        let t = self.heap[k].t;
        let last = self.heap.pop().expect("entry exists");
        self.pos[t as usize] = u32::MAX;
        if k < self.heap.len() {
            self.heap[k] = last;
            self.pos[last.t as usize] = k as u32;
            let k = self.up(k);
            self.down(k);
        }
    }

    // Both sifts move a hole rather than swapping: each entry passed over
    // is written once, and the moving one only where it comes to rest (the
    // same arrangement as swapping, with half the writes).
    fn up(&mut self, mut k: usize) -> usize {
        let c = self.heap[k];
        while k > 0 {
            let p = (k - 1) / 2;
            if c <= self.heap[p] {
                break;
            }
            self.place(k, self.heap[p]);
            k = p;
        }
        self.place(k, c);
        k
    }

    fn down(&mut self, mut k: usize) {
        let c = self.heap[k];
        let n = self.heap.len();
        loop {
            let (l, r) = (2 * k + 1, 2 * k + 2);
            if l >= n {
                break;
            }
            let m = if r < n && self.heap[r] > self.heap[l] { r } else { l };
            if self.heap[m] <= c {
                break;
            }
            self.place(k, self.heap[m]);
            k = m;
        }
        self.place(k, c);
    }

    #[inline]
    fn place(&mut self, k: usize, c: Candidate) {
        self.pos[c.t as usize] = k as u32;
        self.heap[k] = c;
    }
}

impl Queue<'_> {
    /// Scans triangle `t`, records what it found, and queues its worst
    /// sample that step 4 may insert, if that is beyond the target.
    fn push(&mut self, tin: &Tin, lines: &Lines, t: u32) {
        let tri = tin.corners(t);
        let found = scan_for_queue(self.grid, self.clip, lines, &tri);
        let target = self.target.over(&tri);
        self.record(t, tin.version(t), found, target);
    }

    /// Records what triangle `t` (as it is now) holds, and queues its worst
    /// sample if that is beyond the target.
    fn record(&mut self, t: u32, version: u32, found: TriangleScan, target: f64) {
        if self.scans.len() <= t as usize {
            let none = TriangleScan { max_err: 0.0, coverage: None, worst: None };
            self.scans.resize(t as usize + 1, Scan { version: u32::MAX, found: none });
        }
        self.scans[t as usize] = Scan { version, found };
        let c = found.worst.filter(|w| w.0 > target).map(|(err, i, j)| Candidate { err, t, i, j });
        self.heap.set(t, c);
    }
}

/// Scans triangle `tri` for step 4's queue: its largest error over samples
/// that are not vertices, and its worst sample step 4 may insert.
fn scan_for_queue(grid: &Window, clip: (Span, Span), lines: &Lines, tri: &[V; 3]) -> TriangleScan {
    scan_within(grid, clip, lines, tri, f64::INFINITY).expect("nothing is beyond an infinite limit")
}

/// [`scan_for_queue`], or `None` as soon as a sample that is not a vertex
/// lies more than `limit` off. Every such sample is visited: while the
/// worst is within `limit`, the floor (the worst's error) is too.
fn scan_within(grid: &Window, clip: (Span, Span), lines: &Lines, tri: &[V; 3], limit: f64) -> Option<TriangleScan> {
    let mut worst: Option<(f64, u32, u32)> = None;
    let mut max_err = 0.0;
    let mut beyond = false;
    let coverage = scan_triangle(grid, clip, tri, |i, j, err| {
        if err > max_err && !lines.is_vertex(i, j) {
            if err > limit {
                beyond = true;
                return f64::INFINITY;
            }
            max_err = err;
        }
        if worst.is_none_or(|w| err > w.0) && !lines.row_is_line(i) && !lines.col_is_line(j) && !lines.is_vertex(i, j) {
            worst = Some((err, i, j));
        }
        // A sample no further off than the worst so far (and so than
        // `max_err`, never below it) changes neither.
        worst.map_or(f64::NEG_INFINITY, |w| w.0)
    });
    (!beyond).then_some(TriangleScan { max_err, coverage, worst })
}

/// Calls `visit(i, j, |h − plane|)` for every valid sample in the closed
/// triangle `tri` (clipped to `clip`) that can matter; returns whether any
/// valid sample was what it covers, or `None` for a zero-area triangle
/// (which is not scanned).
///
/// `visit` returns a floor: a sample no further off than it cannot change
/// what `visit` finds, and is not visited (`NEG_INFINITY`: every valid
/// sample counts; `INFINITY`: stop, the answer is known). Once the worst is
/// known, most samples cost one comparison, and a nodata sample (NaN) fails
/// it too.
fn scan_triangle(
    grid: &Window,
    clip: (Span, Span),
    tri: &[V; 3],
    mut visit: impl FnMut(u32, u32, f64) -> f64,
) -> Option<Coverage> {
    let [a, b, c] = tri.map(|v| (v.x, v.z, v.h));
    let det = (b.0 - a.0) * (c.1 - a.1) - (c.0 - a.0) * (b.1 - a.1);
    if det.abs() < 1e-12 {
        return None;
    }
    // h(x, z) = a.h + gx·(x − a.x) + gz·(z − a.z)
    let gx = ((b.2 - a.2) * (c.1 - a.1) - (c.2 - a.2) * (b.1 - a.1)) / det;
    let gz = ((b.0 - a.0) * (c.2 - a.2) - (c.0 - a.0) * (b.2 - a.2)) / det;
    const EPS: f64 = 1e-7;
    let zmin = a.1.min(b.1).min(c.1).max(f64::from(clip.1.0));
    let zmax = a.1.max(b.1).max(c.1).min(f64::from(clip.1.1));
    let first = ceil(zmin - EPS);
    let last = floor_i64(zmax + EPS);
    let mut any = false;
    let mut seen = false;
    let mut floor = f64::NEG_INFINITY;
    // Corners by row: p on top, r at the bottom; the long edge p–r spans
    // every row, the short edges p–q and q–r one part each.
    let mut v = [a, b, c];
    v.sort_unstable_by(|u, w| u.1.total_cmp(&w.1));
    let [p, q, r] = v;
    let long = (r.0 - p.0) / (r.1 - p.1);
    let upper = if q.1 > p.1 { (q.0 - p.0) / (q.1 - p.1) } else { 0.0 };
    let lower = if r.1 > q.1 { (r.0 - q.0) / (r.1 - q.1) } else { 0.0 };
    for i in first..=last {
        let z = i as f64;
        let zc = z.max(p.1).min(r.1);
        let x_long = p.0 + (zc - p.1) * long;
        let x_short = if zc < q.1 { p.0 + (zc - p.1) * upper } else { q.0 + (zc - q.1) * lower };
        let (xl, xr) = if x_long <= x_short { (x_long, x_short) } else { (x_short, x_long) };
        let j0 = ceil(xl - EPS).max(i64::from(clip.0.0));
        let j1 = floor_i64(xr + EPS).min(i64::from(clip.0.1));
        let row = grid.row(i as usize);
        // Relative to corner a: far from the grid's origin on steep ground,
        // gx·j and gx·a.x would each be large and their difference rounded.
        let base = a.2 + gz * (z - a.1);
        if j0 > j1 {
            continue;
        }
        seen = true;
        let samples = &row[j0 as usize - grid.x0..=j1 as usize - grid.x0];
        let mut k = 0;
        // A valid sample is visited at least until the floor is finite, so
        // `any` is set by then.
        while let Some((d, err)) = first_over(&samples[k..], (j0 + k as i64) as f64, a.0, base, gx, floor) {
            k += d;
            any = true;
            floor = visit(i as u32, (j0 + k as i64) as u32, err);
            if floor == f64::INFINITY {
                return Some(Coverage::Valid);
            }
            k += 1;
        }
    }
    Some(match (seen, any) {
        (_, true) => Coverage::Valid,
        (true, false) => Coverage::NodataOnly,
        (false, _) => Coverage::NoSample,
    })
}

/// The first of a row's `samples` more than `floor` off the plane
/// `base + gx·(x − ax)`, the first at column `x`, and its error: the scan's
/// inner loop, kept apart from what `visit` keeps so that its few values
/// stay in registers. The column counts up by one as an f64, exactly (a
/// whole number far below 2⁵³): each error is the one `j as f64` gives.
#[inline]
fn first_over(samples: &[f32], x: f64, ax: f64, base: f64, gx: f64, floor: f64) -> Option<(usize, f64)> {
    let mut x = x;
    for (k, &h) in samples.iter().enumerate() {
        let err = (f64::from(h) - (base + gx * (x - ax))).abs();
        if err > floor {
            return Some((k, err));
        }
        x += 1.0;
    }
    None
}

/// `x.ceil() as i64` without the libm call (x86-64 before SSE4.1 has no
/// rounding instruction); grid coordinates are far inside i64.
#[inline]
fn ceil(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t + 1 } else { t }
}

/// `x.floor() as i64`, as [`ceil`].
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

/// What samples a triangle covers.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Coverage {
    /// At least one valid sample.
    Valid,
    /// Samples, all nodata.
    NodataOnly,
    /// No sample at all (a small triangle between samples).
    NoSample,
}

/// Whether any corner of the grid cell under the triangle's centroid holds data.
fn cell_has_data(grid: &Window, tri: &[V; 3]) -> bool {
    let cx = (tri[0].x + tri[1].x + tri[2].x) / 3.0;
    let cz = (tri[0].z + tri[1].z + tri[2].z) / 3.0;
    let (x1, z1) = grid.last();
    let j = (cx.floor().max(grid.x0 as f64) as usize).min(x1 - 1);
    let i = (cz.floor().max(grid.z0 as f64) as usize).min(z1 - 1);
    [(i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)].iter().any(|&(i, j)| !grid.sample(i, j).is_nan())
}

fn finish(
    grid: &Window,
    spec: &ChunkSpec,
    tin: &Tin,
    lines: &Lines,
    scans: &[Scan],
    (relief_m, magnitude_m): (f64, f64),
) -> ChunkMesh {
    // Vertices step 5 collapsed away are left out, the rest keep their order.
    let mut id = Vec::with_capacity(tin.pts.len());
    let mut vertices = Vec::with_capacity(tin.pts.len());
    for (k, v) in tin.pts.iter().enumerate() {
        id.push(vertices.len() as u32);
        if tin.is_live(k as u32) {
            vertices.push(MeshVertex { x: v.x, z: v.z, h: v.h, ph: v.ph });
        }
    }
    let n = tin.num_triangles();
    let mut triangles = Vec::with_capacity(n);
    let mut kept = Vec::with_capacity(n);
    let mut max_err: f64 = 0.0;
    let mut max_err_cut: f64 = 0.0;
    let mut parent_locator = None;
    let lattice = spec.lattice();
    let mut seeds = Vec::with_capacity(n);
    for t in (0..n as u32).filter(|&t| !tin.is_dead(t)) {
        let tri = tin.corners(t);
        // A triangle's last scan still holds unless a corner is a cut point:
        // then a sample within rounding outside it may since have become a
        // vertex (of the neighbour), which is exact and must not count. Only
        // a scan that holds is handed to the children.
        let cut = is_cut(&tri);
        let rounds = tri.iter().any(|v| off_lattice(v.x, lattice) || off_lattice(v.z, lattice));
        // Where a corner's height rounds, a sample's error as written is
        // bounded by its own share of the corners' rounding (the barycentric
        // mean: a sample on a line weighs only that line's ends, which its
        // 1-D target left room for), so such a triangle is scanned again.
        // Errors as the file will draw them, within which every target left
        // room: the corners as they move, interpolated like heights.
        let r = tri.map(|v| rounds_by(v.h, spec.height_step.unwrap_or(0.0)));
        let rounded = r.iter().any(|&r| r > 0.0);
        let [ra, rb, rc] = [0, 1, 2].map(|k| MeshVertex { x: tri[k].x, z: tri[k].z, h: r[k], ph: 0.0 });
        let moved = |i: u32, j: u32| {
            barycentric(&ra, &rb, &rc, f64::from(j), f64::from(i)).1.clamp(0.0, r[0].max(r[1]).max(r[2]))
        };
        let valid = scans.get(t as usize).filter(|s| s.version == tin.version(t) && !cut);
        seeds.push(valid.map(|s| s.found));
        let any = match valid {
            Some(s) if !rounded => {
                max_err = max_err.max(s.found.max_err);
                s.found.coverage
            }
            _ => {
                // A sample on a border or dividing line was decided in 1-D
                // against its interval's own target: δ where both ends are
                // samples, so it may be exactly δ off even in a triangle
                // with a cut corner (it lies on the exact edge, where that
                // corner weighs nothing). It counts in the lattice class,
                // whose δ reading is snapped. Where an end of its interval
                // is a cut point the file rounds, it counts with the cut
                // points: France–Italy at 0.5 m, 16-cell leaves, f32: a
                // chunk at δ 1 m ended the tree with a line sample 0.5 m off
                // beside a cut point, 0.5000005 m as written.
                let (row, col) = (|i: u32, v: &V| v.z == f64::from(i), |j: u32, v: &V| v.x == f64::from(j));
                let rounds_at = |v: &V| off_lattice(v.x, lattice) || off_lattice(v.z, lattice);
                scan_triangle(grid, spec.footprint, &tri, |i, j, e| {
                    if !lines.is_vertex(i, j) {
                        let (on_row, on_col) = (lines.row_is_line(i), lines.col_is_line(j));
                        let cut_end = tri.iter().any(|v| rounds_at(v) && (on_row && row(i, v) || on_col && col(j, v)));
                        let near_cut = rounds && (!(on_row || on_col) || cut_end);
                        let class = if near_cut { &mut max_err_cut } else { &mut max_err };
                        *class = class.max(if rounded { e + moved(i, j) } else { e });
                    }
                    f64::NEG_INFINITY // every sample counts
                })
            }
        };
        // Counter-clockwise with z taken as up is clockwise in x-east,
        // z-south grid space: store them reversed.
        let [a, b, c] = tin.triangle(t).map(|v| id[v as usize]);
        triangles.push([a, c, b]);
        // A zero-area sliver, or a small triangle with no sample inside,
        // covers nothing by itself: keep it unless its cell is all nodata.
        kept.push(match any {
            Some(Coverage::Valid) => true,
            Some(Coverage::NodataOnly) => false,
            // Over voids, a child must not draw where its parent does not
            // (it would pop in and out with the level): such a triangle lies
            // inside one parent triangle, and is written if that one is.
            _ => match (spec.parent, grid.grid.filled.is_some()) {
                (Some(p), true) => {
                    let loc = parent_locator.get_or_insert_with(|| p.locator());
                    let (cx, cz) = ((tri[0].x + tri[1].x + tri[2].x) / 3.0, (tri[0].z + tri[1].z + tri[2].z) / 3.0);
                    loc.locate(cx, cz, 1e-6).is_some_and(|(pt, _)| p.kept[pt as usize])
                }
                _ => cell_has_data(grid, &tri),
            },
        });
    }
    ChunkMesh {
        key: spec.key,
        footprint: spec.footprint,
        delta_m: spec.delta_m,
        vertices,
        triangles,
        kept,
        // A sample exactly δ off may read a hair over δ from the triangle on
        // the other side of its edge: it is δ.
        max_error_m: if max_err > spec.delta_m && max_err <= spec.delta_m + f64_slack(relief_m, magnitude_m) {
            spec.delta_m
        } else {
            max_err
        }
        .max(max_err_cut),
        max_error_near_cuts_m: max_err_cut,
        relief_m,
        scans: seeds,
        locator_index: Default::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rough ground: two ridges and a hashed roughness of a few metres.
    fn rough(w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|k| {
                let (x, z) = ((k % w) as f64, (k / w) as f64);
                let hash = ((k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as f64 / f64::from(1u32 << 24);
                (40.0 * (x / 9.0).sin() * (z / 13.0).cos() + 0.3 * x + 3.0 * hash) as f32
            })
            .collect()
    }

    /// Each triangle as its corners' coordinates, sorted: a mesh's
    /// triangles whatever their numbering.
    fn triangle_set(m: &ChunkMesh) -> Vec<[[u64; 3]; 3]> {
        let mut set: Vec<[[u64; 3]; 3]> = m
            .triangles
            .iter()
            .map(|t| {
                let mut c = t.map(|v| {
                    let p = m.vertices[v as usize];
                    [p.x.to_bits(), p.z.to_bits(), p.h.to_bits()]
                });
                c.sort_unstable();
                c
            })
            .collect();
        set.sort_unstable();
        set
    }

    #[test]
    fn parts_filled_in_parallel_make_the_same_mesh_as_one_tin() {
        let (w, h) = (129, 97);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let spec = |key, footprint, delta_m, parent, split| ChunkSpec {
            key,
            footprint,
            delta_m,
            parent,
            keep_parent_edges: true,
            max_vertices: crate::config::MAX_CHUNK_VERTICES as usize,
            dividing_lines: DividingLines::Children,
            split_insertion: split,
            cancel: None,
            cut_share: CUT_SHARE,
            cut_lattice: None,
            height_step: None,
            thin: false,
        };
        let root = ChunkKey { level: 0, x: 0, y: 0 };
        let whole = ((0, 128), (0, 96));
        let [one, parts] = [false, true].map(|split| build_chunk(&grid, &spec(root, whole, 2.0, None, split)).unwrap());
        assert!(one.triangles.len() > 1000, "{} triangles", one.triangles.len());
        assert_eq!(triangle_set(&one), triangle_set(&parts));
        assert_eq!(one.vertices.len(), parts.vertices.len());
        assert_eq!(one.max_error_m, parts.max_error_m);
        // The scans each hands down stand for the same triangles: a child of
        // either is the same mesh, and so is a child filled in parts.
        let child = ChunkKey { level: 1, x: 1, y: 0 };
        let quarter = ((64, 128), (0, 48));
        let a = build_chunk(&grid, &spec(child, quarter, 1.0, Some(&one), false)).unwrap();
        let b = build_chunk(&grid, &spec(child, quarter, 1.0, Some(&parts), false)).unwrap();
        let c = build_chunk(&grid, &spec(child, quarter, 1.0, Some(&parts), true)).unwrap();
        assert_eq!(triangle_set(&a), triangle_set(&b));
        assert_eq!(triangle_set(&a), triangle_set(&c));
        let held = |m: &ChunkMesh| m.scans.iter().filter(|s| s.is_some()).count();
        assert_eq!(held(&one), held(&parts));
        // The vertex limit counts the parts together.
        let limit = one.vertices.len() - 1;
        for split in [false, true] {
            let tight = ChunkSpec { max_vertices: limit, ..spec(root, whole, 2.0, None, split) };
            assert!(matches!(build_chunk(&grid, &tight), Err(MeshError::TooDense { .. })), "split {split}");
            let exact = ChunkSpec { max_vertices: limit + 1, ..spec(root, whole, 2.0, None, split) };
            assert!(build_chunk(&grid, &exact).is_ok(), "split {split}");
        }
    }

    /// A chunk with dividing lines, nested in `parent` if given, thinned or not.
    fn lined<'p>(
        key: ChunkKey,
        footprint: (Span, Span),
        delta_m: f64,
        parent: Option<&'p ChunkMesh>,
        thin: bool,
    ) -> ChunkSpec<'p> {
        ChunkSpec {
            key,
            parent,
            dividing_lines: DividingLines::Children,
            thin,
            ..ChunkSpec::unconstrained(footprint, delta_m)
        }
    }

    /// A chunk filled by parts and thinned (`--thin all`'s root) is thinned
    /// part by part, on the threads: it must make the collapses that
    /// thinning the joined TIN on one thread made, so the files stay the same.
    #[test]
    fn parts_thinned_in_parallel_make_the_collapses_of_the_joined_tin() {
        // Rough ground with a void, so that thinning also skips stars that
        // touch nodata; the root filled by parts and thinned, as `--thin
        // all` builds it, then a child of it filled and thinned by parts.
        let (w, h) = (129, 97);
        let mut heights = rough(w, h);
        for i in 60..75 {
            for j in 20..41 {
                heights[i * w + j] = f32::NAN;
            }
        }
        let hf = crate::heightfield::Heightfield::ungeoreferenced(w, h, heights.clone(), "rough".into());
        let filled = crate::heightfield::void_fill(&hf).expect("a void");
        let grid = Grid::new(w, h, &heights, Some(&filled));
        let spec = |key, footprint, delta_m, parent, thin| ChunkSpec {
            split_insertion: true,
            ..lined(key, footprint, delta_m, parent, thin)
        };
        let root = ChunkKey { level: 0, x: 0, y: 0 };
        let whole = ((0, 128), (0, 96));
        let plain = build_chunk(&grid, &spec(root, whole, 2.0, None, false)).unwrap();
        let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
            .map(|how| build_chunk_thinning(&grid, &spec(root, whole, 2.0, None, true), how).unwrap());
        let (n0, n1) = (plain.vertices.len(), by_parts.vertices.len());
        assert!(n1 * 100 < n0 * 97, "{n1} vertices thinned against {n0}");
        same_mesh(&joined, &by_parts);
        let child = ChunkKey { level: 1, x: 0, y: 1 };
        let quarter = ((0, 64), (48, 96));
        let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
            .map(|how| build_chunk_thinning(&grid, &spec(child, quarter, 1.0, Some(&by_parts), true), how).unwrap());
        same_mesh(&joined, &by_parts);
        assert!(by_parts.kept.iter().any(|&k| !k), "the child covers part of the void");
    }

    /// The same mesh, vertex for vertex and triangle for triangle, so the
    /// same bytes: `a` thinned joined, `b` by parts.
    fn same_mesh(a: &ChunkMesh, b: &ChunkMesh) {
        let (na, nb) = ((a.vertices.len(), a.triangles.len()), (b.vertices.len(), b.triangles.len()));
        assert!(a.vertices == b.vertices, "vertices differ: joined {na:?}, by parts {nb:?} (vertices, triangles)");
        assert!(a.triangles == b.triangles, "triangles differ: joined {na:?}, by parts {nb:?}");
        assert!(a.kept == b.kept && a.scans == b.scans, "what is written or handed down differs");
        assert_eq!(a.max_error_m.to_bits(), b.max_error_m.to_bits());
    }

    /// A lone leaf cut into parts only to fill them in parallel
    /// ([`DividingLines::Parts`]) starts from the samples where its lines
    /// meet the borders and each other: unlike the children's lines, which
    /// cut the corners' diagonal at a point off the sample grid where a
    /// span is odd, it holds no vertex but samples. Filled and thinned by
    /// parts it is the mesh of filling and thinning it whole, within δ, and
    /// its lines cost the free leaf few triangles.
    #[test]
    fn a_lone_leaf_cut_into_parts_holds_only_samples_and_meets_delta() {
        // 127 cells across: the vertical line at 63 meets the diagonal off the grid.
        let (w, h) = (128, 97);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let whole = ((0, 127), (0, 96));
        let spec = |lines, split| ChunkSpec {
            dividing_lines: lines,
            split_insertion: split,
            thin: true,
            ..ChunkSpec::unconstrained(whole, 2.0)
        };
        let on_samples = |m: &ChunkMesh| m.vertices.iter().all(|v| v.x.fract() == 0.0 && v.z.fract() == 0.0);
        let children = build_chunk(&grid, &spec(DividingLines::Children, false)).unwrap();
        assert!(!on_samples(&children), "the children's lines make a cut point here");
        let free = build_chunk(&grid, &spec(DividingLines::None, false)).unwrap();
        let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
            .map(|how| build_chunk_thinning(&grid, &spec(DividingLines::Parts, true), how).unwrap());
        same_mesh(&joined, &by_parts);
        assert!(on_samples(&by_parts), "a vertex off the sample grid");
        assert!(by_parts.max_error_m <= 2.0, "{} m", by_parts.max_error_m);
        for (x, z) in [(63.0, 48.0), (0.0, 48.0), (127.0, 48.0), (63.0, 0.0), (63.0, 96.0)] {
            assert!(by_parts.vertices.iter().any(|v| (v.x, v.z) == (x, z)), "({x}, {z}) is where lines meet");
        }
        let count = |m: &ChunkMesh| m.kept.iter().filter(|&&k| k).count();
        let (n, n0) = (count(&by_parts), count(&free));
        assert!(n0 > 2000 && n * 100 <= n0 * 105, "{n} triangles by parts against {n0} free");
    }

    /// Step 5 takes out vertices step 4 no longer needs, and only those: the
    /// thinned TIN keeps every sample within δ (measured afresh over its
    /// triangles, not from the mesher's scans), keeps every border and
    /// dividing-line vertex, holds no vertex without a triangle, and a child
    /// meshed from a thinned parent still refines it (each child triangle
    /// inside one parent triangle, each morph target on the parent surface).
    #[test]
    fn thinning_takes_out_vertices_and_keeps_every_sample_within_delta() {
        let (w, h) = (129, 97);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let root = ChunkKey { level: 0, x: 0, y: 0 };
        let whole = ((0, 128), (0, 96));
        let spec = lined;
        let [plain, thinned] =
            [false, true].map(|thin| build_chunk(&grid, &spec(root, whole, 2.0, None, thin)).unwrap());
        let (n0, n1) = (plain.vertices.len(), thinned.vertices.len());
        assert!(n1 * 100 < n0 * 97, "{n1} vertices thinned against {n0}");
        assert!(thinned.max_error_m <= 2.0, "{}", thinned.max_error_m);
        let within = |m: &ChunkMesh, delta: f64| {
            let loc = m.locator();
            for i in 0..h {
                for j in 0..w {
                    let (_, s) = loc.locate(j as f64, i as f64, 1e-9).expect("every sample covered");
                    let e = (s - f64::from(heights[i * w + j])).abs();
                    assert!(e <= delta + 1e-9, "sample ({i}, {j}) {e} m off, δ {delta}");
                }
            }
        };
        within(&thinned, 2.0);
        let mut used = vec![false; n1];
        thinned.triangles.iter().flatten().for_each(|&v| used[v as usize] = true);
        assert!(used.iter().all(|&u| u), "a vertex without a triangle");
        let lines = |m: &ChunkMesh| {
            let on = |v: &MeshVertex| [0.0, 64.0, 128.0].contains(&v.x) || [0.0, 48.0, 96.0].contains(&v.z);
            let mut p: Vec<(u64, u64)> =
                m.vertices.iter().filter(|v| on(v)).map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
            p.sort_unstable();
            p
        };
        assert_eq!(lines(&plain), lines(&thinned));

        // The scans a thinned mesh keeps, from which its max error is read
        // and its children start, are what scanning its triangles finds:
        // thinning records the scans it made while trying each collapse
        // instead of scanning the new triangles again.
        let corner: std::collections::HashSet<(u64, u64)> =
            thinned.vertices.iter().map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
        let mut kept_scans = 0;
        for (t, scan) in thinned.triangles.iter().zip(&thinned.scans) {
            let Some(scan) = scan else { continue };
            let [p, q, r] = t.map(|k| thinned.vertices[k as usize]);
            let mut worst: f64 = 0.0;
            for i in p.z.min(q.z).min(r.z) as usize..=p.z.max(q.z).max(r.z) as usize {
                for j in p.x.min(q.x).min(r.x) as usize..=p.x.max(q.x).max(r.x) as usize {
                    let (x, z) = (j as f64, i as f64);
                    let (outside, plane) = barycentric(&p, &q, &r, x, z);
                    if outside <= 1e-9 && !corner.contains(&(x.to_bits(), z.to_bits())) {
                        worst = worst.max((f64::from(heights[i * w + j]) - plane).abs());
                    }
                }
            }
            assert!((worst - scan.max_err).abs() < 1e-9, "kept scan {} against {worst} by brute force", scan.max_err);
            kept_scans += 1;
        }
        assert!(kept_scans * 10 > thinned.triangles.len() * 9, "{kept_scans} of {}", thinned.triangles.len());

        let child = ChunkKey { level: 1, x: 1, y: 0 };
        let quarter = ((64, 128), (0, 48));
        let c = build_chunk(
            &grid,
            &ChunkSpec { dividing_lines: DividingLines::None, ..spec(child, quarter, 1.0, Some(&thinned), true) },
        )
        .unwrap();
        assert!(c.max_error_m <= 1.0, "{}", c.max_error_m);
        let parent = thinned.locator();
        for v in &c.vertices {
            let (_, ph) = parent.locate(v.x, v.z, 1e-9).unwrap();
            assert!((ph - v.ph).abs() < 1e-9, "morph target {} against the parent's {ph}", v.ph);
        }
        for t in &c.triangles {
            let [a, b, d] = t.map(|k| c.vertices[k as usize]);
            let (cx, cz) = ((a.x + b.x + d.x) / 3.0, (a.z + b.z + d.z) / 3.0);
            let (pt, _) = parent.locate(cx, cz, 1e-9).unwrap();
            let [p, q, r] = thinned.triangles[pt as usize].map(|k| thinned.vertices[k as usize]);
            for v in [a, b, d] {
                let (outside, _) = barycentric(&p, &q, &r, v.x, v.z);
                assert!(outside < 1e-9, "a child triangle crosses a parent edge");
            }
        }
    }

    /// The leaf-width estimate measures each δ by continuing its windows'
    /// TINs from twice that δ (`quadtree::estimate::Estimate`). A continued TIN is the
    /// free TIN at its δ but for the order its points went in: within δ,
    /// every point it started from kept, its borders exactly a fresh TIN's
    /// (each interval split at its worst sample whatever the δ), and about
    /// as many vertices. It fails if the start's edges stay fixed (0.73 to
    /// 1.45 times the vertices here).
    #[test]
    fn a_continued_tin_is_within_delta_with_a_fresh_tins_borders() {
        let (w, h) = (129, 97);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let whole = ((0, 128), (0, 96));
        let on_border = |v: &MeshVertex| v.x == 0.0 || v.x == 128.0 || v.z == 0.0 || v.z == 96.0;
        let points = |m: &ChunkMesh, border: bool| {
            let mut p: Vec<(u64, u64)> =
                m.vertices.iter().filter(|v| !border || on_border(v)).map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
            p.sort_unstable();
            p
        };
        let mut chain = build_chunk(&grid, &ChunkSpec::unconstrained(whole, 8.0)).unwrap();
        for delta in [4.0, 2.0, 1.0, 0.5] {
            let next = build_chunk(&grid, &ChunkSpec::continued(whole, delta, &chain)).unwrap();
            let fresh = build_chunk(&grid, &ChunkSpec::unconstrained(whole, delta)).unwrap();
            assert!(next.max_error_m <= delta, "{} over δ {delta}", next.max_error_m);
            let kept = points(&next, false);
            assert!(points(&chain, false).iter().all(|p| kept.binary_search(p).is_ok()), "δ {delta}");
            assert_eq!(points(&next, true), points(&fresh, true), "δ {delta}");
            let ratio = next.vertices.len() as f64 / fresh.vertices.len() as f64;
            // The order moves the count by up to 5 % here (kept edges: 0.73–1.45×).
            assert!(
                (0.95..=1.06).contains(&ratio),
                "δ {delta}: {} against {}",
                next.vertices.len(),
                fresh.vertices.len()
            );
            chain = next;
        }
        assert!(chain.vertices.len() > 2000, "{} vertices", chain.vertices.len());
    }

    /// A mesh's locator (the children's void checks use their parent's) is
    /// indexed once and then lent: the same grid on every call, and the
    /// same answers as a locator indexed afresh.
    #[test]
    fn a_meshs_locator_is_indexed_once_and_answers_as_a_fresh_one() {
        let (w, h) = (65, 49);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let mesh = build_chunk(&grid, &ChunkSpec::unconstrained(((0, 64), (0, 48)), 2.0)).unwrap();
        assert!(mesh.locator_index.get().is_none(), "indexed before it was asked for");
        let (first, second) = (mesh.locator(), mesh.locator());
        assert!(mesh.locator_index.get().is_some(), "not indexed when first asked for");
        let fresh = crate::mesh::locate::SurfaceLocator::from_parts(&mesh.vertices, &mesh.triangles);
        let mut found = 0;
        for k in 0..2000 {
            let (x, z) = (f64::from(k % 97) * 0.661, f64::from(k / 97) * 2.31 + 0.1);
            let want = fresh.locate(x, z, 1e-6);
            assert_eq!(first.locate(x, z, 1e-6), want, "({x}, {z})");
            assert_eq!(second.locate(x, z, 1e-6), want, "({x}, {z})");
            found += usize::from(want.is_some());
        }
        assert!(found > 1900, "{found} points located");
    }

    /// A fan of parent edges around a vertex a thousandth of a cell from the
    /// dividing line crosses it at points closer together than the quantize
    /// grid, which the file cannot hold apart. Each crossing moves onto the
    /// grid, those on one point stay separate vertices (each its own morph
    /// target) with flat pieces between them, and no piece turns over.
    #[test]
    fn crowded_crossings_move_onto_the_lattice_without_folding_a_piece() {
        let (w, h) = (21, 11);
        let heights: Vec<f32> = (0..w * h).map(|k| ((k % w) * 7 + (k / w) * 3) as f32).collect();
        let grid = Grid::new(w, h, &heights, None);
        let window = Window::new(&grid, ((0, 20), (0, 10)));
        let centre = V { x: 10.001, z: 5.0, h: 50.0, ph: 50.0 };
        let mut pts = vec![centre];
        let n = 16;
        for k in 0..n {
            let a = std::f64::consts::TAU * f64::from(k) / f64::from(n) + 0.1;
            pts.push(V { x: 10.001 + 4.0 * a.cos(), z: 5.0 + 4.0 * a.sin(), h: 40.0, ph: 40.0 });
        }
        let tris: Vec<[u32; 3]> = (0..n).map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
        let mut soup = Soup { fixed: vec![[true; 3]; tris.len()], origin: vec![u32::MAX; tris.len()], pts, tris };
        let lattice = 256.0;
        let before = soup.pts.len();
        let nested = (Targeting { nested: true, parent: None }, soup.pts.len());
        cut_along_line(&mut soup, &window, Line { vertical: true, coord: 10 }, nested, lattice);
        let pos = |v: u32| Coord { x: soup.pts[v as usize].x, y: soup.pts[v as usize].z };
        let area = |t: &[u32; 3]| robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2])) / 2.0;
        for t in &soup.tris {
            assert!(area(t) >= 0.0, "piece {t:?} turned over");
        }
        // All counter-clockwise and the fan's area (less what the two rim
        // crossings' moves take, under 1e-3 here): the pieces tile it
        // without overlap.
        let rim: f64 = (0..n).map(|k| area(&[0, 1 + k, 1 + (k + 1) % n])).sum();
        let total: f64 = soup.tris.iter().map(area).sum();
        assert!((total - rim).abs() < 1e-3 * rim, "pieces cover {total}, the fan {rim}");
        let crossings = &soup.pts[before..];
        // Eight spokes reach across the line, seven of them within two grid
        // steps, and two rim edges cross it far away.
        assert_eq!(crossings.len(), 10);
        assert!(crossings.iter().all(|v| v.x == 10.0 && !off_lattice(v.z, lattice)), "on the line and the grid");
        let mut at: Vec<f64> = crossings.iter().map(|v| v.z).collect();
        at.sort_by(f64::total_cmp);
        at.dedup();
        assert!(at.len() <= 6, "seven crowded crossings share three grid points: {at:?}");
        let flat = soup.tris.iter().filter(|t| area(t) == 0.0).count();
        assert!(flat > 0, "the crossings on one point leave flat pieces between them");
    }

    /// Provence at 5 m with 16-cell leaves, `quantize`, failed `verify`: a
    /// sample was placed on an edge from a crossing that the file's grid had
    /// moved a thousandth of a cell off a steep parent sliver, and its morph
    /// target, interpolated from that crossing's, missed the parent by 1.9 m
    /// (and the next sample, inside an ordinary parent triangle, by 0.75 m).
    /// In a quantized build every sample's target is now the parent
    /// surface's height at it, to f64 rounding, however the crossings moved.
    #[test]
    fn samples_placed_against_moved_crossings_target_the_parent_surface() {
        let (w, h) = (129, 97);
        let heights = rough(w, h);
        let grid = Grid::new(w, h, &heights, None);
        let root = ChunkKey { level: 0, x: 0, y: 0 };
        fn on_grid(spec: ChunkSpec<'_>, k: u32) -> ChunkSpec<'_> {
            ChunkSpec { cut_lattice: Some(k), ..spec }
        }
        let parent = build_chunk(&grid, &on_grid(lined(root, ((0, 128), (0, 96)), 4.0, None, false), 2)).unwrap();
        let surface = parent.locator();
        let (mut samples, mut crossings) = (0, 0);
        for (x, y, footprint) in
            [(0, 0, ((0, 64), (0, 48))), (1, 0, ((64, 128), (0, 48))), (1, 1, ((64, 128), (48, 96)))]
        {
            let key = ChunkKey { level: 1, x, y };
            let child = build_chunk(&grid, &on_grid(lined(key, footprint, 2.0, Some(&parent), false), 3)).unwrap();
            for v in &child.vertices {
                if whole(v.x) && whole(v.z) {
                    let (_, ph) = surface.locate(v.x, v.z, 1e-9).expect("on the parent");
                    assert!((ph - v.ph).abs() < 1e-9, "sample ({}, {}): target {} against {ph}", v.x, v.z, v.ph);
                    samples += 1;
                } else {
                    crossings += usize::from(!off_lattice(v.x, 8.0) && !off_lattice(v.z, 8.0));
                }
            }
        }
        assert!(samples > 300 && crossings > 20, "{samples} samples, {crossings} cut points on the grid");
    }

    /// California at 1 m panicked ("a line is a chain of edges"): crossings
    /// within half a step of the point where the dividing line meets the
    /// border rounded onto that sample, where the border's vertex already
    /// was, and the border line went through seven vertices at one point.
    /// A crossing never lands on a sample's point.
    #[test]
    fn a_crossing_next_to_a_sample_does_not_land_on_it() {
        let heights = vec![0.0f32; 21 * 11];
        let grid = Grid::new(21, 11, &heights, None);
        let window = Window::new(&grid, ((0, 20), (0, 10)));
        let v = |x: f64, z: f64| V { x, z, h: 0.0, ph: 0.0 };
        // The line x = 10 passes through corner P and crosses A–B at z = 4.999,
        // whose nearest point on a 1/256 grid is the sample (10, 5) = P.
        let pts = vec![v(9.0, 4.998), v(11.0, 5.0), v(10.0, 5.0)];
        let mut soup = Soup { pts, tris: vec![[0, 1, 2]], fixed: vec![[true; 3]], origin: vec![0] };
        let nested = (Targeting { nested: true, parent: None }, soup.pts.len());
        cut_along_line(&mut soup, &window, Line { vertical: true, coord: 10 }, nested, 256.0);
        let x = soup.pts[3];
        assert_eq!((x.x, x.z * 256.0), (10.0, 1279.0), "the other neighbour, off the sample");
        let pos = |v: u32| Coord { x: soup.pts[v as usize].x, y: soup.pts[v as usize].z };
        assert!(soup.tris.iter().all(|t| robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2])) > 0.0));
    }

    /// A vertex 7·10⁻⁵ cells from a free edge of its triangle (quantized
    /// output, one lattice step 1/256) takes the edge's place only where
    /// the flipped triangles stay within target.
    #[test]
    fn a_vertex_a_hair_from_a_free_edge_takes_its_place_where_the_surface_allows() {
        // 9 × 9 samples at 100 m. The free edge a–b along z = x + 0.5 has
        // c 7·10⁻⁵ cells off it on one side (a sliver) and d across.
        let (w, h) = (9, 9);
        let heights = vec![100.0f32; w * h];
        let grid = Grid::new(w, h, &heights, None);
        let window = Window::new(&grid, ((0, 8), (0, 8)));
        let lattice = 256.0;
        let target = Targets::new(1.0, 0.0).on_lattice(lattice, None);
        let run = |c_height: f64| {
            let v = |x: f64, z: f64, h: f64| V { x, z, h, ph: h };
            let (a, b, c, d) = (0, 1, 2, 3);
            let pts = vec![v(0.0, 0.5, 100.0), v(8.0, 8.5, 100.0), v(4.0, 4.5001, c_height), v(6.0, 2.0, 100.0)];
            let mut tin = Tin::from_soup(pts, &[[a, b, c], [b, a, d]], &[[false; 3], [false; 3]]);
            let lines = Lines::new(&tin, ((0, 8), (0, 8)), [Some(0), None, Some(8)], [Some(0), None, Some(8)]);
            unsliver(&mut tin, &window, ((0, 8), (0, 8)), &lines, target, 1.0 / lattice);
            let turned = (0..2).filter(|&t| !counter_clockwise(&tin.corners(t))).count();
            (tin.find_edge(a, b).is_some(), tin.find_edge(c, d).is_some(), turned)
        };
        // On the surface the edge carries: the edge gives way to c–d.
        assert_eq!(run(100.0), (false, true, 0));
        // A vertex 50 m off that surface would tilt the new triangles past
        // δ over the samples beside it: the edge stays.
        assert_eq!(run(150.0), (true, false, 0));
    }

    /// A sample beside a fixed edge is split onto it only where the
    /// triangle across covers data: over a void, that triangle's parent is
    /// not written, and the sample at its corner would keep the child's.
    #[test]
    fn a_sample_is_split_onto_an_edge_only_where_data_lies_across() {
        // 9 × 9 samples; the columns x < 4 are nodata.
        let (w, h) = (9, 9);
        let heights: Vec<f32> = (0..w * h).map(|k| if k % w < 4 { f32::NAN } else { 100.0 }).collect();
        let filled: Vec<f32> = vec![100.0; w * h];
        let v = |x: f64, z: f64| V { x, z, h: 100.0, ph: 100.0 };
        // The fixed edge A–B along x = 3.5: data east of it, a void west.
        let (a, b, east, west) = (0, 1, 2, 3);
        let pts = vec![v(3.5, 0.0), v(3.5, 8.0), v(8.0, 4.0), v(0.5, 4.0)];
        let tin = Tin::from_soup(pts, &[[b, a, east], [a, b, west]], &[[true, false, false], [true, false, false]]);
        assert_eq!((tin.ends(0), tin.ends(3)), ((b, a), (a, b)));
        let grid = Grid::new(w, h, &heights, Some(&filled));
        let window = Window::new(&grid, ((0, 8), (0, 8)));
        assert!(!data_across(&tin, &window, 0), "from the east, the void across");
        assert!(data_across(&tin, &window, 3), "from the west, the data across");
        // Without voids every edge has data across.
        let whole = Grid::new(w, h, &filled, None);
        assert!(data_across(&tin, &Window::new(&whole, ((0, 8), (0, 8))), 0));
    }
}
