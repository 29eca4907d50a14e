//! Greedy insertion (Garland & Heckbert's "Greedy Insertion" TIN, as in
//! delatin), constrained and nested so that Chunked LOD can morph exactly.
//!
//! A chunk's TIN is built in four steps, each of which only inserts points:
//!
//! 1. Start from the parent's triangles inside the footprint with *every*
//!    parent edge a constraint (spade's CDT), so whatever is inserted later
//!    stays inside a parent triangle: the child refines the parent and its
//!    morph to the parent surface is exact everywhere (DESIGN.md, promise 3).
//!    The top level starts from its four corners.
//! 2. Refine each border line in 1-D from that line's own samples: split the
//!    worst interval at its worst sample until every valid sample on the line
//!    is within δ, after forcing the line's midpoint (the corner of the
//!    children). Neighbours see the same inherited vertices and the same
//!    samples, so they arrive at the same border without talking.
//! 3. Add the dividing lines (the children's borders) as constraints,
//!    splitting the parent edges they cross at points that take the parent
//!    surface height, and refine them in 1-D like the borders.
//! 4. Insert the interior sample with the largest error until every valid
//!    sample is within δ (samples on the lines of steps 2–3 never move).
//!
//! Decisions are made in f64 grid coordinates; the target is shrunk by a
//! margin that covers the f32 rounding of the written chunk-local positions.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use spade::handles::FixedFaceHandle;
use spade::{ConstrainedDelaunayTriangulation, HasPosition, Point2, Triangulation};

use super::{ChunkMesh, MeshError, MeshVertex};
use crate::quadtree::{ChunkKey, Span, midpoint};

/// The heights the mesher reads: the DEM (NaN = nodata) and, when the DEM has
/// voids, a smooth fill used only for vertices forced onto nodata samples.
#[derive(Clone, Copy)]
pub struct Grid<'a> {
    /// Samples per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major heights, NaN = nodata.
    pub heights: &'a [f32],
    /// Same layout with voids filled, if the DEM has any.
    pub filled: Option<&'a [f32]>,
}

impl Grid<'_> {
    #[inline]
    fn sample(&self, i: usize, j: usize) -> f32 {
        self.heights[i * self.width + j]
    }

    /// Height a vertex at sample (i, j) takes: the sample, or the fill.
    #[inline]
    fn vertex_height(&self, i: usize, j: usize) -> f64 {
        let h = self.sample(i, j);
        if h.is_nan() { self.filled.map_or(0.0, |f| f64::from(f[i * self.width + j])) } else { f64::from(h) }
    }
}

#[derive(Clone, Copy, Debug)]
struct V {
    p: Point2<f64>,
    h: f64,
    /// Height of the parent's surface here (= `h` at the top level): the
    /// parent surface is linear inside every face (faces refine parent
    /// triangles), so a new vertex takes it by interpolating its face's.
    ph: f64,
}

impl HasPosition for V {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.p
    }
}

type Cdt = ConstrainedDelaunayTriangulation<V>;

/// Most vertices one u16-indexed primitive may hold (65 535 is primitive restart).
pub const MAX_VERTICES: usize = 65_535;

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
    /// Most vertices allowed ([`MAX_VERTICES`] for u16 output).
    pub max_vertices: usize,
    /// Add the dividing lines (the children's borders). Off only for the
    /// unconstrained single-TIN baseline the benchmarks compare against.
    pub dividing_lines: bool,
}

/// Builds one chunk's TIN (see the module comment for the four steps).
pub fn build_chunk(grid: &Grid, spec: &ChunkSpec) -> Result<ChunkMesh, MeshError> {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let relief = footprint_relief(grid, spec.footprint);
    let target = build_target(spec.delta_m, relief);
    let mut cdt = initial_cdt(grid, spec);
    let nested = spec.parent.is_some();
    let profile_src: Vec<[V; 3]> = cdt.inner_faces().map(|f| f.vertices().map(|v| *v.data())).collect();

    // Step 2: borders, with their midpoints forced.
    let (mx, mz) = match spec.dividing_lines {
        true => (midpoint((x0, x1)), midpoint((z0, z1))),
        false => (None, None),
    };
    for (axis_x, coord, span, forced) in
        [(false, z0, (x0, x1), mx), (false, z1, (x0, x1), mx), (true, x0, (z0, z1), mz), (true, x1, (z0, z1), mz)]
    {
        refine_line(&mut cdt, grid, axis_x, coord, span, forced, target, nested);
    }

    // Step 3: the dividing lines.
    let handle_at =
        |cdt: &Cdt, x: u32, z: u32| cdt.locate_vertex(Point2::new(f64::from(x), f64::from(z))).map(|v| v.fix());
    if let (Some(mx), Some(mz)) = (mx, mz) {
        insert_sample(&mut cdt, grid, mx, mz, nested);
    }
    if let Some(mx) = mx {
        let ends = [Some(z0), mz, Some(z1)];
        add_dividing_line(&mut cdt, grid, &profile_src, true, mx, &ends, handle_at);
    }
    if let Some(mz) = mz {
        let ends = [Some(x0), mx, Some(x1)];
        add_dividing_line(&mut cdt, grid, &profile_src, false, mz, &ends, handle_at);
    }
    if let Some(mx) = mx {
        refine_line(&mut cdt, grid, true, mx, (z0, z1), mz, target, nested);
    }
    if let Some(mz) = mz {
        refine_line(&mut cdt, grid, false, mz, (x0, x1), mx, target, nested);
    }

    // Step 4: greedy insertion of interior samples.
    let mut lines = Lines::new(&cdt, spec.footprint, [Some(x0), mx, Some(x1)], [Some(z0), mz, Some(z1)]);
    let clip = spec.footprint;
    let mut heap = BinaryHeap::new();
    let faces: Vec<_> = cdt.inner_faces().map(|f| f.fix()).collect();
    for f in faces {
        push_face(&mut heap, grid, &lines, clip, &cdt, f, target);
    }
    while let Some(c) = heap.pop() {
        // A face is its vertex set: spade may move a triangle to another
        // face slot, so look it up by its vertices rather than its index.
        let Some(face) = find_face(&cdt, c.verts) else {
            continue; // stale: the triangle no longer exists
        };
        if lines.is_vertex(c.i, c.j) {
            // The sample became a vertex of the next triangle over (it sat on
            // this face's edge within rounding): rescan this face without it.
            push_face(&mut heap, grid, &lines, clip, &cdt, face, target);
            continue;
        }
        let hint = spade::handles::FixedVertexHandle::from_index(c.verts[0] as usize);
        let touched = insert_interior(&mut cdt, grid, c.j, c.i, hint, nested);
        lines.mark_vertex(c.i, c.j);
        if let Some(same) = find_face(&cdt, c.verts) {
            // Rounding put the sample just across this face's edge, into the
            // neighbour: this face is unchanged, so scan it again.
            push_face(&mut heap, grid, &lines, clip, &cdt, same, target);
        }
        if cdt.num_vertices() > spec.max_vertices {
            let k = spec.key;
            return Err(MeshError::TooDense {
                level: k.level,
                x: k.x,
                y: k.y,
                delta_m: spec.delta_m,
                limit: spec.max_vertices,
            });
        }
        let mut faces: Vec<FixedFaceHandle<_>> = touched
            .iter()
            .flat_map(|&v| cdt.vertex(v).out_edges().filter_map(|e| e.face().as_inner().map(|f| f.fix())))
            .collect();
        faces.sort_unstable();
        faces.dedup();
        for f in faces {
            push_face(&mut heap, grid, &lines, clip, &cdt, f, target);
        }
    }
    Ok(finish(grid, spec, &cdt, &lines, relief))
}

/// δ minus what f32 chunk-local output can add: a relative part for the
/// horizontal rounding on steep ground and an absolute part for heights.
pub fn build_target(delta_m: f64, relief_m: f64) -> f64 {
    delta_m * 0.98 - relief_m * 4.0 * f64::from(f32::EPSILON)
}

/// Largest minus smallest valid height in a footprint (0 if none).
fn footprint_relief(grid: &Grid, footprint: (Span, Span)) -> f64 {
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
    if hi >= lo { hi - lo } else { 0.0 }
}

fn initial_cdt(grid: &Grid, spec: &ChunkSpec) -> Cdt {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let inside =
        |v: &MeshVertex| v.x >= f64::from(x0) && v.x <= f64::from(x1) && v.z >= f64::from(z0) && v.z <= f64::from(z1);
    let (verts, edges) = match spec.parent {
        Some(p) => {
            let mut remap = vec![u32::MAX; p.vertices.len()];
            let mut verts = Vec::new();
            for (k, v) in p.vertices.iter().enumerate() {
                if inside(v) {
                    remap[k] = verts.len() as u32;
                    verts.push(V { p: Point2::new(v.x, v.z), h: v.h, ph: v.h });
                }
            }
            let mut edges = Vec::new();
            for t in &p.triangles {
                let r = t.map(|k| remap[k as usize]);
                if r.contains(&u32::MAX) {
                    continue;
                }
                for e in 0..3 {
                    let (a, b) = (r[e], r[(e + 1) % 3]);
                    edges.push([a.min(b) as usize, a.max(b) as usize]);
                }
            }
            edges.sort_unstable();
            edges.dedup();
            (verts, edges)
        }
        None => {
            let c = |j: u32, i: u32| {
                let h = grid.vertex_height(i as usize, j as usize);
                V { p: Point2::new(f64::from(j), f64::from(i)), h, ph: h }
            };
            (vec![c(x0, z0), c(x1, z0), c(x1, z1), c(x0, z1)], vec![[0, 1], [1, 2], [2, 3], [0, 3]])
        }
    };
    Cdt::bulk_load_cdt(verts, edges).expect("footprint vertices are finite")
}

fn insert_sample(cdt: &mut Cdt, grid: &Grid, j: u32, i: u32, nested: bool) -> spade::handles::FixedVertexHandle {
    let p = Point2::new(f64::from(j), f64::from(i));
    let h = grid.vertex_height(i as usize, j as usize);
    let ph = match cdt.locate(p) {
        spade::PositionInTriangulation::OnVertex(v) => return v,
        pos if nested => parent_height_at(cdt, pos, p),
        _ => h,
    };
    cdt.insert(V { p, h, ph }).expect("sample positions are finite")
}

/// The parent surface's height at `p`, interpolated in the face (or along
/// the edge) that `pos` says holds it.
fn parent_height_at(cdt: &Cdt, pos: spade::PositionInTriangulation, p: Point2<f64>) -> f64 {
    let lerp_edge = |a: &V, b: &V| {
        let (dx, dz) = (b.p.x - a.p.x, b.p.y - a.p.y);
        let t = (((p.x - a.p.x) * dx + (p.y - a.p.y) * dz) / (dx * dx + dz * dz)).clamp(0.0, 1.0);
        a.ph + t * (b.ph - a.ph)
    };
    match pos {
        spade::PositionInTriangulation::OnVertex(v) => cdt.vertex(v).data().ph,
        spade::PositionInTriangulation::OnEdge(e) => {
            let e = cdt.directed_edge(e);
            lerp_edge(e.from().data(), e.to().data())
        }
        spade::PositionInTriangulation::OnFace(f) => {
            let [a, b, c] = cdt.face(f).vertices().map(|v| *v.data());
            let det = (b.p.x - a.p.x) * (c.p.y - a.p.y) - (c.p.x - a.p.x) * (b.p.y - a.p.y);
            if det.abs() < 1e-300 {
                return a.ph;
            }
            let l1 = ((p.x - a.p.x) * (c.p.y - a.p.y) - (c.p.x - a.p.x) * (p.y - a.p.y)) / det;
            let l2 = ((b.p.x - a.p.x) * (p.y - a.p.y) - (p.x - a.p.x) * (b.p.y - a.p.y)) / det;
            (1.0 - l1 - l2) * a.ph + l1 * b.ph + l2 * c.ph
        }
        _ => f64::NAN,
    }
}

/// Inserts an interior sample. A sample can lie exactly on a constraint edge
/// whose end is a split point (not exactly representable): spade then sees it
/// a hair off the edge and would leave a zero-width sliver, making the surface
/// two-valued along that edge. Such an edge is split at the sample instead.
///
/// Returns the vertices whose surrounding faces may have changed (the new
/// one first).
fn insert_interior(
    cdt: &mut Cdt,
    grid: &Grid,
    j: u32,
    i: u32,
    hint: spade::handles::FixedVertexHandle,
    nested: bool,
) -> Vec<spade::handles::FixedVertexHandle> {
    let p = Point2::new(f64::from(j), f64::from(i));
    let h = grid.vertex_height(i as usize, j as usize);
    let pos = cdt.locate_with_hint(p, hint);
    let ph = if nested { parent_height_at(cdt, pos, p) } else { h };
    if let spade::PositionInTriangulation::OnFace(f) = pos {
        let mut on_edge = None;
        for e in cdt.face(f).adjacent_edges() {
            if !e.is_constraint_edge() {
                continue;
            }
            let [a, b] = e.vertices().map(|v| v.position());
            let (dx, dz) = (b.x - a.x, b.y - a.y);
            let len2 = dx * dx + dz * dz;
            let cross = dx * (p.y - a.y) - dz * (p.x - a.x);
            let along = (dx * (p.x - a.x) + dz * (p.y - a.y)) / len2;
            if cross.abs() <= 1e-7 * len2.sqrt() && along > 0.0 && along < 1.0 {
                on_edge = Some((e.as_undirected().fix(), e.from().fix(), e.to().fix()));
            }
        }
        if let Some((edge, a, b)) = on_edge {
            cdt.remove_constraint_edge(edge);
            let v = cdt.insert_with_hint(V { p, h, ph }, a).expect("sample positions are finite");
            cdt.add_constraint(a, v);
            cdt.add_constraint(v, b);
            return vec![v, a, b];
        }
    }
    vec![cdt.insert_with_hint(V { p, h, ph }, hint).expect("sample positions are finite")]
}

/// Adds one dividing line (vertical when `vertical`, at `coord`) through the
/// given stops, splitting crossed constraint edges at the parent surface.
fn add_dividing_line(
    cdt: &mut Cdt,
    grid: &Grid,
    parent_tris: &[[V; 3]],
    vertical: bool,
    coord: u32,
    stops: &[Option<u32>; 3],
    handle_at: impl Fn(&Cdt, u32, u32) -> Option<spade::handles::FixedVertexHandle>,
) {
    let c = f64::from(coord);
    let stops: Vec<u32> = stops.iter().flatten().copied().collect();
    let at = |t: u32| if vertical { (coord, t) } else { (t, coord) };
    for w in stops.windows(2) {
        let (a, b) = (at(w[0]), at(w[1]));
        let (Some(ha), Some(hb)) = (handle_at(cdt, a.0, a.1), handle_at(cdt, b.0, b.1)) else {
            continue;
        };
        cdt.add_constraint_and_split(ha, hb, |p| {
            let mut t = if vertical { p.y } else { p.x };
            let ph = surface_on_line(parent_tris, vertical, c, t);
            let mut h = ph;
            // A crossing that falls on a sample takes the sample itself, so
            // the line's own samples decide the line wherever they can.
            if (t - t.round()).abs() < 1e-6 {
                t = t.round();
                let (j, i) = if vertical { (coord, t as u32) } else { (t as u32, coord) };
                let s = grid.sample(i as usize, j as usize);
                if !s.is_nan() {
                    h = f64::from(s);
                }
            }
            let p = if vertical { Point2::new(c, t) } else { Point2::new(t, c) };
            V { p, h, ph }
        });
    }
}

/// Height of the triangulated surface `tris` at the point of the line
/// (`x = c` when `vertical`, else `z = c`) with coordinate `t` along it.
fn surface_on_line(tris: &[[V; 3]], vertical: bool, c: f64, t: f64) -> f64 {
    let (u, w) = if vertical { (c, t) } else { (t, c) };
    let mut best = (f64::INFINITY, 0.0);
    for tri in tris {
        let [a, b, d] = tri.map(|v| (v.p.x, v.p.y, v.h));
        let det = (b.0 - a.0) * (d.1 - a.1) - (d.0 - a.0) * (b.1 - a.1);
        if det.abs() < 1e-300 {
            continue;
        }
        let l1 = ((u - a.0) * (d.1 - a.1) - (d.0 - a.0) * (w - a.1)) / det;
        let l2 = ((b.0 - a.0) * (w - a.1) - (u - a.0) * (b.1 - a.1)) / det;
        let l0 = 1.0 - l1 - l2;
        let outside = (-l0).max(-l1).max(-l2).max(0.0);
        if outside < best.0 {
            best = (outside, l0 * a.2 + l1 * b.2 + l2 * d.2);
            if outside == 0.0 {
                break;
            }
        }
    }
    best.1
}

/// 1-D greedy refinement of the line `x = coord` (`vertical`) or `z = coord`
/// over `span`: force `forced`, then split every interval at its worst valid
/// sample until all are within `target`.
#[allow(clippy::too_many_arguments)]
fn refine_line(
    cdt: &mut Cdt,
    grid: &Grid,
    vertical: bool,
    coord: u32,
    span: Span,
    forced: Option<u32>,
    target: f64,
    nested: bool,
) {
    let c = f64::from(coord);
    let (lo, hi) = (f64::from(span.0), f64::from(span.1));
    let mut pts: Vec<(f64, f64)> = cdt
        .vertices()
        .map(|v| *v.data())
        .filter_map(|v| {
            let (along, across) = if vertical { (v.p.y, v.p.x) } else { (v.p.x, v.p.y) };
            (across == c && along >= lo && along <= hi).then_some((along, v.h))
        })
        .collect();
    let sample = |t: u32| if vertical { (coord, t) } else { (t, coord) };
    if let Some(f) = forced
        && !pts.iter().any(|p| p.0 == f64::from(f))
    {
        let (j, i) = sample(f);
        insert_sample(cdt, grid, j, i, nested);
        pts.push((f64::from(f), grid.vertex_height(i as usize, j as usize)));
    }
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut stack: Vec<((f64, f64), (f64, f64))> = pts.windows(2).map(|w| (w[0], w[1])).collect();
    while let Some((a, b)) = stack.pop() {
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
            let err = (h - (a.1 + s * (b.1 - a.1))).abs();
            if err > target && worst.is_none_or(|w| err > w.0) {
                worst = Some((err, t as u32, h));
            }
        }
        if let Some((_, t, h)) = worst {
            let (j, i) = sample(t);
            insert_sample(cdt, grid, j, i, nested);
            let m = (f64::from(t), h);
            stack.push((a, m));
            stack.push((m, b));
        }
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
    fn new(cdt: &Cdt, footprint: (Span, Span), xs: [Option<u32>; 3], zs: [Option<u32>; 3]) -> Self {
        let ((x0, x1), (z0, z1)) = footprint;
        let width = (x1 - x0 + 1) as usize;
        let mut l = Lines { xs, zs, origin: (x0, z0), width, vertex: vec![false; width * (z1 - z0 + 1) as usize] };
        for v in cdt.vertices() {
            let p = v.data().p;
            if p.x.fract() == 0.0 && p.y.fract() == 0.0 {
                l.mark_vertex(p.y as u32, p.x as u32);
            }
        }
        l
    }
    #[inline]
    fn mark_vertex(&mut self, i: u32, j: u32) {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize] = true;
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

struct Candidate {
    err: f64,
    verts: [u32; 3],
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

fn push_face(
    heap: &mut BinaryHeap<Candidate>,
    grid: &Grid,
    lines: &Lines,
    clip: (Span, Span),
    cdt: &Cdt,
    face: FixedFaceHandle<spade::handles::InnerTag>,
    target: f64,
) {
    let f = cdt.face(face);
    let tri = f.vertices().map(|v| *v.data());
    let verts = face_key(cdt, face);
    let mut worst: Option<(f64, u32, u32)> = None;
    scan_triangle(grid, clip, &tri, |i, j, err| {
        if err > target
            && worst.is_none_or(|w| err > w.0)
            && !lines.row_is_line(i)
            && !lines.col_is_line(j)
            && !lines.is_vertex(i, j)
        {
            worst = Some((err, i, j));
        }
    });
    if let Some((err, i, j)) = worst {
        heap.push(Candidate { err, verts, i, j });
    }
}

/// A face's vertex indices, sorted: spade may rotate a face's starting edge
/// without changing the triangle, so only the set identifies it.
fn face_key(cdt: &Cdt, face: FixedFaceHandle<spade::handles::InnerTag>) -> [u32; 3] {
    let mut k = cdt.face(face).vertices().map(|v| v.fix().index() as u32);
    k.sort_unstable();
    k
}

/// The inner face with exactly these (sorted) vertices, if it exists.
fn find_face(cdt: &Cdt, key: [u32; 3]) -> Option<FixedFaceHandle<spade::handles::InnerTag>> {
    let v = spade::handles::FixedVertexHandle::from_index(key[0] as usize);
    if key[0] as usize >= cdt.num_vertices() {
        return None;
    }
    cdt.vertex(v).out_edges().filter_map(|e| e.face().as_inner()).map(|f| f.fix()).find(|&f| face_key(cdt, f) == key)
}

/// Calls `visit(i, j, |h − plane|)` for every valid sample in the closed
/// triangle `tri` (clipped to `clip`); returns whether any valid sample was
/// what it covers, or `None` for a zero-area triangle (which is not scanned).
fn scan_triangle(
    grid: &Grid,
    clip: (Span, Span),
    tri: &[V; 3],
    mut visit: impl FnMut(u32, u32, f64),
) -> Option<Coverage> {
    let [a, b, c] = tri.map(|v| (v.p.x, v.p.y, v.h));
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
    let first = (zmin - EPS).ceil() as i64;
    let last = (zmax + EPS).floor() as i64;
    let mut any = false;
    let mut seen = false;
    let edges = [(a, b), (b, c), (c, a)];
    for i in first..=last {
        let z = i as f64;
        let mut xl = f64::INFINITY;
        let mut xr = f64::NEG_INFINITY;
        for (p, q) in edges {
            let (lo, hi) = if p.1 <= q.1 { (p, q) } else { (q, p) };
            if z < lo.1 - EPS || z > hi.1 + EPS {
                continue;
            }
            if (hi.1 - lo.1).abs() < 1e-12 {
                xl = xl.min(lo.0.min(hi.0));
                xr = xr.max(lo.0.max(hi.0));
            } else {
                let s = ((z - lo.1) / (hi.1 - lo.1)).clamp(0.0, 1.0);
                let x = lo.0 + s * (hi.0 - lo.0);
                xl = xl.min(x);
                xr = xr.max(x);
            }
        }
        if xl > xr {
            continue;
        }
        let j0 = ((xl - EPS).ceil().max(f64::from(clip.0.0))) as i64;
        let j1 = ((xr + EPS).floor().min(f64::from(clip.0.1))) as i64;
        let row = &grid.heights[i as usize * grid.width..];
        let base = a.2 + gz * (z - a.1) - gx * a.0;
        for j in j0..=j1 {
            seen = true;
            let h = row[j as usize];
            if h.is_nan() {
                continue;
            }
            any = true;
            let err = (f64::from(h) - (base + gx * j as f64)).abs();
            visit(i as u32, j as u32, err);
        }
    }
    Some(match (seen, any) {
        (_, true) => Coverage::Valid,
        (true, false) => Coverage::NodataOnly,
        (false, _) => Coverage::NoSample,
    })
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
fn cell_has_data(grid: &Grid, tri: &[V; 3]) -> bool {
    let cx = (tri[0].p.x + tri[1].p.x + tri[2].p.x) / 3.0;
    let cz = (tri[0].p.y + tri[1].p.y + tri[2].p.y) / 3.0;
    let j = (cx.floor().max(0.0) as usize).min(grid.width - 2);
    let i = (cz.floor().max(0.0) as usize).min(grid.height - 2);
    [(i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)].iter().any(|&(i, j)| !grid.sample(i, j).is_nan())
}

fn finish(grid: &Grid, spec: &ChunkSpec, cdt: &Cdt, lines: &Lines, relief_m: f64) -> ChunkMesh {
    let vertices: Vec<MeshVertex> = cdt
        .vertices()
        .map(|v| MeshVertex { x: v.data().p.x, z: v.data().p.y, h: v.data().h, ph: v.data().ph })
        .collect();
    let mut triangles = Vec::with_capacity(cdt.num_inner_faces());
    let mut kept = Vec::with_capacity(cdt.num_inner_faces());
    let mut max_err: f64 = 0.0;
    for f in cdt.inner_faces() {
        let tri = f.vertices().map(|v| *v.data());
        // Vertices are exact; skipping them keeps a sliver's neighbour from
        // reporting a phantom error there (see `Lines`).
        let any = scan_triangle(grid, spec.footprint, &tri, |i, j, e| {
            if !lines.is_vertex(i, j) {
                max_err = max_err.max(e);
            }
        });
        // spade's faces are counter-clockwise with y up; in x-east, z-south
        // grid space that is clockwise, so store them reversed.
        let [a, b, c] = f.vertices().map(|v| v.fix().index() as u32);
        triangles.push([a, c, b]);
        // A zero-area sliver, or a small triangle with no sample inside,
        // covers nothing by itself: keep it unless its cell is all nodata.
        kept.push(match any {
            Some(Coverage::Valid) => true,
            Some(Coverage::NodataOnly) => false,
            _ => cell_has_data(grid, &tri),
        });
    }
    ChunkMesh {
        key: spec.key,
        footprint: spec.footprint,
        delta_m: spec.delta_m,
        vertices,
        triangles,
        kept,
        max_error_m: max_err,
        relief_m,
    }
}
