//! A triangulation that only grows, for greedy insertion inside a parent.
//!
//! Half-edges in flat arrays (delaunator's layout): triangle `t` owns
//! half-edges `3t`, `3t + 1`, `3t + 2`, counter-clockwise in (x, z) taken as a
//! right-handed plane. It is built directly from a triangle soup (the
//! parent's triangles), so a child costs nothing to set up beyond its parent's
//! triangles, and it only ever splits triangles and edges, then flips the
//! edges that are not fixed back to local Delaunay (Lawson). Fixed edges are
//! the parent's edges and the dividing lines: they are never flipped, so
//! whatever is inserted stays inside a parent triangle.
//!
//! Orientation and in-circle decisions use Shewchuk's exact predicates
//! (`robust`), so a point on an edge is on it, not a hair to one side.
//!
//! spade's constrained triangulation did this job first; it can only be
//! seeded by re-triangulating the parent's points and edges (a quarter of the
//! build went there) and its handles move between slots, which cost a lookup
//! by vertex set per queued candidate. Here a triangle slot carries a version
//! number instead.

use robust::{Coord, incircle, orient2d};

mod sanity;
pub use sanity::Broken;

/// `robust::incircle`'s sign, computed directly where that is exact: on
/// whole-number coordinates within 4 096 of `d` every product and sum below
/// stays under 2^52. Grid samples are such points, and four corners of a
/// grid square are cocircular (determinant exactly 0), the case where the
/// adaptive predicate falls through to its slowest, exact stage.
#[inline]
fn in_circle(a: Coord<f64>, b: Coord<f64>, c: Coord<f64>, d: Coord<f64>) -> f64 {
    let whole = |v: f64| f64::from(v as i32) == v;
    let [adx, ady, bdx, bdy, cdx, cdy] = [a.x - d.x, a.y - d.y, b.x - d.x, b.y - d.y, c.x - d.x, c.y - d.y];
    if [a.x, a.y, b.x, b.y, c.x, c.y, d.x, d.y].iter().all(|&v| whole(v))
        && [adx, ady, bdx, bdy, cdx, cdy].iter().all(|&v| v.abs() <= 4096.0)
    {
        let alift = adx * adx + ady * ady;
        let blift = bdx * bdx + bdy * bdy;
        let clift = cdx * cdx + cdy * cdy;
        alift * (bdx * cdy - cdx * bdy) + blift * (cdx * ady - adx * cdy) + clift * (adx * bdy - bdx * ady)
    } else {
        incircle(a, b, c, d)
    }
}

/// No half-edge: the twin of a border half-edge.
pub const NONE: u32 = u32::MAX;

/// A vertex: grid position (column `x`, row `z`), its height and the parent
/// surface's height at that position.
#[derive(Clone, Copy, Debug)]
pub struct V {
    /// Column coordinate (east), in samples.
    pub x: f64,
    /// Row coordinate (south), in samples.
    pub z: f64,
    /// Height, metres.
    pub h: f64,
    /// Parent surface height here, metres.
    pub ph: f64,
}

/// Where a point lies relative to the triangulation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Position {
    /// Strictly inside a triangle.
    Face(u32),
    /// On a half-edge, strictly between its ends.
    Edge(u32),
    /// On a vertex.
    Vertex(u32),
    /// Outside every triangle.
    Outside,
}

/// The triangulation.
pub struct Tin {
    /// Vertices, in insertion order (inherited ones first).
    pub pts: Vec<V>,
    /// Origin vertex of each half-edge.
    tv: Vec<u32>,
    /// Opposite half-edge, or [`NONE`] on the border.
    twin: Vec<u32>,
    /// Whether the edge may not be flipped (same on both half-edges).
    fixed: Vec<bool>,
    /// Per triangle, bumped each time the slot is rewritten.
    version: Vec<u32>,
    /// One half-edge leaving each vertex.
    out: Vec<u32>,
    /// Triangles rewritten since the last [`Tin::take_dirty`].
    dirty: Vec<u32>,
    /// Scratch for [`Tin::legalize`].
    stack: Vec<u32>,
}

#[inline]
fn next(e: u32) -> u32 {
    if e % 3 == 2 { e - 2 } else { e + 1 }
}

#[inline]
fn prev(e: u32) -> u32 {
    if e.is_multiple_of(3) { e + 2 } else { e - 1 }
}

impl Tin {
    /// Builds the half-edge structure from counter-clockwise triangles over
    /// `pts`, with a fixed flag per triangle edge (edge `k` runs from corner
    /// `k` to corner `k + 1`). Edges used once are the border.
    pub fn from_soup(pts: Vec<V>, tris: &[[u32; 3]], fixed: &[[bool; 3]]) -> Tin {
        let n = tris.len() * 3;
        let mut tin = Tin::unlinked(pts, tris.len());
        for (t, f) in tris.iter().zip(fixed) {
            for k in 0..3 {
                tin.out[t[k] as usize] = tin.tv.len() as u32;
                tin.tv.push(t[k]);
                tin.fixed.push(f[k]);
            }
        }
        // The twin of a → b is b → a: group the half-edges by origin (a
        // counting sort), then look for each one among its end's few.
        let mut start = vec![0u32; tin.pts.len() + 1];
        for &a in &tin.tv {
            start[a as usize + 1] += 1;
        }
        for v in 0..tin.pts.len() {
            start[v + 1] += start[v];
        }
        // Each entry holds the half-edge and its end, so the search reads
        // one small contiguous run instead of a corner of each candidate.
        let mut fill = start.clone();
        let mut by_origin = vec![(0u32, 0u32); n];
        for (t, c) in tin.tv.chunks_exact(3).enumerate() {
            for k in 0..3 {
                let a = c[k] as usize;
                by_origin[fill[a] as usize] = ((3 * t + k) as u32, c[(k + 1) % 3]);
                fill[a] += 1;
            }
        }
        for e in 0..n as u32 {
            if tin.twin[e as usize] != NONE {
                continue;
            }
            let (a, b) = (tin.tv[e as usize], tin.tv[next(e) as usize]);
            let around_b = &by_origin[start[b as usize] as usize..start[b as usize + 1] as usize];
            if let Some(&(f, _)) = around_b.iter().find(|&&(_, end)| end == a) {
                tin.pair(e, f);
            }
        }
        tin
    }

    /// A TIN over `pts` with room for `triangles` triangles, none added
    /// yet: every twin [`NONE`], every version 0.
    fn unlinked(pts: Vec<V>, triangles: usize) -> Tin {
        let n = triangles * 3;
        Tin {
            out: vec![NONE; pts.len()],
            pts,
            tv: Vec::with_capacity(n * 2),
            twin: vec![NONE; n],
            fixed: Vec::with_capacity(n * 2),
            version: vec![0; triangles],
            dirty: Vec::new(),
            stack: Vec::new(),
        }
    }

    /// Makes half-edges `e` and `f` twins; the edge is fixed if either was.
    fn pair(&mut self, e: u32, f: u32) {
        let (e, f) = (e as usize, f as usize);
        self.twin[e] = f as u32;
        self.twin[f] = e as u32;
        let fixed = self.fixed[e] || self.fixed[f];
        self.fixed[e] = fixed;
        self.fixed[f] = fixed;
    }

    /// Joins TINs over pieces of one footprint that meet only along their
    /// borders into one TIN over `pts`: each part with its vertices' indices
    /// in `pts`, its triangles numbered after the parts before it. It is
    /// what [`Tin::from_soup`] builds from the same triangles and fixed
    /// flags (the same twins, the same vertex's out half-edge), without
    /// its search: each part's twins stand, and only the half-edges on a
    /// part's border look for theirs, in the other parts. (Fuji's root at
    /// 1 m: 13 ms through `from_soup`, on one thread while the other waits.)
    ///
    /// A part may have been thinned ([`Tin::collapse`]): its collapsed
    /// triangles keep their slots, dead, and its collapsed vertices stay
    /// unconnected, as a collapse in the joined TIN would leave them.
    pub fn from_parts(pts: Vec<V>, parts: &[(&Tin, &[u32])]) -> Tin {
        let mut tin = Tin::unlinked(pts, parts.iter().map(|(sub, _)| sub.num_triangles()).sum());
        // Half-edges with no twin in their part, by their ends' indices.
        let mut open: Vec<([u32; 2], u32)> = Vec::new();
        for &(sub, id) in parts {
            let base = tin.tv.len() as u32;
            tin.tv.extend(sub.tv.iter().map(|&v| if v == NONE { NONE } else { id[v as usize] }));
            tin.fixed.extend_from_slice(&sub.fixed);
            for (k, &f) in sub.twin.iter().enumerate() {
                let e = base + k as u32;
                if f != NONE {
                    tin.twin[e as usize] = base + f;
                } else if tin.tv[e as usize] != NONE {
                    let (a, b) = (tin.tv[e as usize], tin.tv[(base + next(k as u32)) as usize]);
                    open.push(([a.min(b), a.max(b)], e));
                }
            }
        }
        tin.reset_out();
        // a → b and b → a meet in the sorted list; an edge alone is the border.
        open.sort_unstable();
        for pair in open.windows(2) {
            let ((k, e), (l, f)) = (pair[0], pair[1]);
            if k == l {
                tin.pair(e, f);
            }
        }
        tin
    }

    /// Points each connected vertex's out half-edge at the last live
    /// half-edge leaving it, the one [`Tin::from_soup`] and
    /// [`Tin::from_parts`] choose; a vertex with none is unconnected. Where
    /// a free vertex's star starts decides ties in thinning, so a part
    /// thinned on its own starts each star where the joined TIN would.
    pub fn reset_out(&mut self) {
        self.out.fill(NONE);
        for (e, &a) in self.tv.iter().enumerate() {
            if a != NONE {
                self.out[a as usize] = e as u32;
            }
        }
    }

    /// Number of triangles.
    pub fn num_triangles(&self) -> usize {
        self.version.len()
    }

    /// Corners of triangle `t`, counter-clockwise.
    #[inline]
    pub fn triangle(&self, t: u32) -> [u32; 3] {
        let e = 3 * t as usize;
        [self.tv[e], self.tv[e + 1], self.tv[e + 2]]
    }

    /// Corners of triangle `t` as vertices.
    #[inline]
    pub fn corners(&self, t: u32) -> [V; 3] {
        self.triangle(t).map(|v| self.pts[v as usize])
    }

    /// How many times triangle `t` has been rewritten.
    #[inline]
    pub fn version(&self, t: u32) -> u32 {
        self.version[t as usize]
    }

    /// Moves the triangles rewritten since the last call into `out`
    /// (cleared first), sorted, each once.
    pub fn take_dirty(&mut self, out: &mut Vec<u32>) {
        out.clear();
        std::mem::swap(out, &mut self.dirty);
        out.sort_unstable();
        out.dedup();
    }

    /// Adds a vertex (not yet connected).
    pub fn add_vertex(&mut self, v: V) -> u32 {
        self.pts.push(v);
        self.out.push(NONE);
        (self.pts.len() - 1) as u32
    }

    /// Origin and destination of half-edge `e`.
    #[inline]
    pub fn ends(&self, e: u32) -> (u32, u32) {
        (self.tv[e as usize], self.tv[next(e) as usize])
    }

    /// Whether the edge of half-edge `e` is fixed.
    #[inline]
    pub fn is_fixed(&self, e: u32) -> bool {
        self.fixed[e as usize]
    }

    #[inline]
    fn coord(&self, v: u32) -> Coord<f64> {
        let p = &self.pts[v as usize];
        Coord { x: p.x, y: p.z }
    }

    /// The half-edge from `a` to `b`, or from `b` to `a`, if that edge exists.
    pub fn find_edge(&self, a: u32, b: u32) -> Option<u32> {
        self.half_edge(a, b).or_else(|| self.half_edge(b, a))
    }

    /// The half-edge from `a` to `b`, if it exists.
    fn half_edge(&self, a: u32, b: u32) -> Option<u32> {
        let start = self.out[a as usize];
        if start == NONE {
            return None;
        }
        // Counter-clockwise around `a` until the border, then clockwise.
        let mut e = start;
        loop {
            if self.tv[next(e) as usize] == b {
                return Some(e);
            }
            let t = self.twin[prev(e) as usize];
            if t == NONE {
                break;
            }
            e = t;
            if e == start {
                return None;
            }
        }
        let mut e = start;
        loop {
            let t = self.twin[e as usize];
            if t == NONE {
                return None;
            }
            e = next(t);
            if e == start {
                return None;
            }
            if self.tv[next(e) as usize] == b {
                return Some(e);
            }
        }
    }

    /// Writes triangle `t` with its corners, the twins of its three edges and
    /// their fixed flags, linking the twins back.
    fn set(&mut self, t: u32, v: [u32; 3], twins: [u32; 3], fixed: [bool; 3]) {
        for k in 0..3 {
            let e = 3 * t + k as u32;
            self.tv[e as usize] = v[k];
            self.twin[e as usize] = twins[k];
            self.fixed[e as usize] = fixed[k];
            if twins[k] != NONE {
                self.twin[twins[k] as usize] = e;
            }
            self.out[v[k] as usize] = e;
        }
        self.version[t as usize] = self.version[t as usize].wrapping_add(1);
        self.dirty.push(t);
    }

    fn new_triangle(&mut self) -> u32 {
        let t = self.version.len() as u32;
        self.tv.extend([NONE; 3]);
        self.twin.extend([NONE; 3]);
        self.fixed.extend([false; 3]);
        self.version.push(0);
        t
    }

    /// Splits triangle `t` at vertex `v`, which lies strictly inside it.
    pub fn split_triangle(&mut self, t: u32, v: u32) {
        let [a, b, c] = self.triangle(t);
        let e = 3 * t as usize;
        let tw = [self.twin[e], self.twin[e + 1], self.twin[e + 2]];
        let fx = [self.fixed[e], self.fixed[e + 1], self.fixed[e + 2]];
        let t1 = self.new_triangle();
        let t2 = self.new_triangle();
        self.set(t, [a, b, v], [tw[0], 3 * t1 + 2, 3 * t2 + 1], [fx[0], false, false]);
        self.set(t1, [b, c, v], [tw[1], 3 * t2 + 2, 3 * t + 1], [fx[1], false, false]);
        self.set(t2, [c, a, v], [tw[2], 3 * t + 2, 3 * t1 + 1], [fx[2], false, false]);
        self.legalize(&[3 * t, 3 * t1, 3 * t2]);
    }

    /// Splits the edge of half-edge `e` at vertex `v`, which lies on it (or
    /// within rounding of it); the halves keep the edge's fixed flag.
    pub fn split_edge(&mut self, e: u32, v: u32) {
        let t = e / 3;
        let (e1, e2) = (next(e), prev(e));
        let (a, b, c) = (self.tv[e as usize], self.tv[e1 as usize], self.tv[e2 as usize]);
        let fe = self.fixed[e as usize];
        let (t_1, f_1) = (self.twin[e1 as usize], self.fixed[e1 as usize]);
        let (t_2, f_2) = (self.twin[e2 as usize], self.fixed[e2 as usize]);
        let f = self.twin[e as usize];
        let t1 = self.new_triangle();
        if f == NONE {
            self.set(t, [a, v, c], [NONE, 3 * t1 + 2, t_2], [fe, false, f_2]);
            self.set(t1, [v, b, c], [NONE, t_1, 3 * t + 1], [fe, f_1, false]);
            self.legalize(&[3 * t + 2, 3 * t1 + 1]);
            return;
        }
        let u = f / 3;
        let (f1, f2) = (next(f), prev(f));
        let d = self.tv[f2 as usize];
        let (u_1, g_1) = (self.twin[f1 as usize], self.fixed[f1 as usize]);
        let (u_2, g_2) = (self.twin[f2 as usize], self.fixed[f2 as usize]);
        let u1 = self.new_triangle();
        self.set(t, [a, v, c], [3 * u1, 3 * t1 + 2, t_2], [fe, false, f_2]);
        self.set(t1, [v, b, c], [3 * u, t_1, 3 * t + 1], [fe, f_1, false]);
        self.set(u, [b, v, d], [3 * t1, 3 * u1 + 2, u_2], [fe, false, g_2]);
        self.set(u1, [v, a, d], [3 * t, u_1, 3 * u + 1], [fe, g_1, false]);
        let (pa, pb, pd) = (self.coord(a), self.coord(b), self.coord(d));
        if !(pd.x == pa.x && pd.y == pa.y || pd.x == pb.x && pd.y == pb.y) {
            self.legalize(&[3 * t + 2, 3 * t1 + 1, 3 * u + 2, 3 * u1 + 1]);
            return;
        }
        let mut around = vec![t, t1, u, u1];
        self.unwall(v, &mut around);
        let edges: Vec<u32> = around
            .iter()
            .filter_map(|&t| (0..3).map(|k| 3 * t + k).find(|&e| self.tv[e as usize] == v).map(next))
            .collect();
        self.legalize(&edges);
    }

    /// The corners of the triangle across half-edge `e`, if any.
    pub fn across(&self, e: u32) -> Option<[V; 3]> {
        self.twin_of(e).map(|f| self.corners(f / 3))
    }

    /// Whether splitting half-edge `e` at `p` ([`Tin::split_edge`]), a point
    /// near it but not on it, leaves all four new triangles counter-clockwise
    /// (or flat where the twin was): beside a sliver whose far corner lies
    /// just past the edge's end, a point on the other side of the edge turns
    /// one of them over (Sierra 3 × 3 at 5 m, 32-cell leaves, `quantize`).
    pub fn splits_cleanly(&self, e: u32, p: Coord<f64>) -> bool {
        let (a, b) = self.ends(e);
        let (pa, pb, pc) = (self.coord(a), self.coord(b), self.coord(self.apex(e)));
        // A twin that is flat (its far corner on an end of the edge, as a
        // quantized file places close crossings) leaves a flat half.
        let same = |p: Coord<f64>, q: Coord<f64>| p.x == q.x && p.y == q.y;
        let holds = |[x, y, z]: [Coord<f64>; 3]| {
            let o = orient2d(x, y, z);
            o > 0.0 || o == 0.0 && (same(x, y) || same(y, z) || same(z, x))
        };
        let f = self.twin[e as usize];
        holds([pa, p, pc])
            && holds([p, pb, pc])
            && (f == NONE || {
                let pd = self.coord(self.apex(f));
                holds([pb, p, pd]) && holds([p, pa, pd])
            })
    }

    /// Where the edge just split at `v` bordered a flat triangle (two
    /// corners at one point: crossings that a quantized file places on one
    /// lattice point, each its own vertex), one half of that triangle has
    /// three distinct corners in a line, `v` between the other two: a wall
    /// with no area, across which the surface is two-valued (Sierra at 5 m,
    /// 32-cell leaves, `quantize`: a child's morph target read the wall's
    /// other height, 10 m off). Such a wall is flipped with the triangle
    /// across its long edge, which `v` then splits, so that edge keeps its
    /// fixed flag on both halves; again while the triangle across was flat
    /// too. `around`: the triangles to look at, to which the flips' are
    /// added.
    fn unwall(&mut self, v: u32, around: &mut Vec<u32>) {
        let mut k = 0;
        while k < around.len() {
            let t = around[k];
            k += 1;
            let Some(e) = (0..3).map(|k| 3 * t + k).find(|&e| self.tv[e as usize] == v) else { continue };
            // The long edge, opposite v, from x to y.
            let a = next(e);
            let (x, y) = self.ends(a);
            let (pv, px, py) = (self.coord(v), self.coord(x), self.coord(y));
            let distinct = |p: Coord<f64>, q: Coord<f64>| p.x != q.x || p.y != q.y;
            let wall = orient2d(pv, px, py) == 0.0 && distinct(pv, px) && distinct(px, py) && distinct(py, pv);
            let b = self.twin[a as usize];
            if !wall || b == NONE {
                continue;
            }
            let long = self.fixed[a as usize];
            let (t, u) = self.flip(a);
            // The wall's short edges, v–x in t and y–v in u, now lie along
            // the long one.
            for h in [3 * t, 3 * u + 1] {
                if long {
                    self.fixed[h as usize] = true;
                    let tw = self.twin[h as usize];
                    if tw != NONE {
                        self.fixed[tw as usize] = true;
                    }
                }
            }
            around.push(u);
            k -= 1; // t holds v again: look at it anew
        }
    }

    /// Flips the edge of half-edge `a` (not on the border): the triangles
    /// (pr, pl, p0) on `a` and (pl, pr, p1) across become (p0, pr, p1) and
    /// (p1, pl, p0), in the same slots, the new edge p1–p0 free. Returns the
    /// two slots (t, u); the new edge is half-edge `3 * t + 2`, and flipping
    /// it undoes the flip.
    pub fn flip(&mut self, a: u32) -> (u32, u32) {
        let b = self.twin[a as usize];
        let (an, ap, bn, bp) = (next(a), prev(a), next(b), prev(b));
        let (pr, pl, p0) = (self.tv[a as usize], self.tv[an as usize], self.tv[ap as usize]);
        let p1 = self.tv[bp as usize];
        let (t, u) = (a / 3, b / 3);
        let tw = [self.twin[an as usize], self.twin[ap as usize], self.twin[bn as usize], self.twin[bp as usize]];
        let fx = [self.fixed[an as usize], self.fixed[ap as usize], self.fixed[bn as usize], self.fixed[bp as usize]];
        self.set(t, [p0, pr, p1], [tw[1], tw[2], 3 * u + 2], [fx[1], fx[2], false]);
        self.set(u, [p1, pl, p0], [tw[3], tw[0], 3 * t + 2], [fx[3], fx[0], false]);
        (t, u)
    }

    /// The half-edge across `e`, if any.
    pub fn twin_of(&self, e: u32) -> Option<u32> {
        let f = self.twin[e as usize];
        (f != NONE).then_some(f)
    }

    /// Lawson flips from the given half-edges, each opposite the vertex just
    /// inserted: an edge that is not fixed is flipped while the far corner
    /// lies strictly inside the near triangle's circumcircle.
    fn legalize(&mut self, edges: &[u32]) {
        let mut stack = std::mem::take(&mut self.stack);
        stack.clear();
        stack.extend_from_slice(edges);
        while let Some(a) = stack.pop() {
            let b = self.twin[a as usize];
            if b == NONE || self.fixed[a as usize] {
                continue;
            }
            let (pr, pl, p0) = (self.tv[a as usize], self.tv[next(a) as usize], self.tv[prev(a) as usize]);
            let p1 = self.tv[prev(b) as usize];
            if in_circle(self.coord(pr), self.coord(pl), self.coord(p0), self.coord(p1)) <= 0.0 {
                continue;
            }
            let (t, u) = self.flip(a);
            stack.push(3 * t + 1);
            stack.push(3 * u);
        }
        self.stack = stack;
    }

    /// The corner of half-edge `e`'s triangle opposite it.
    #[inline]
    pub fn apex(&self, e: u32) -> u32 {
        self.tv[prev(e) as usize]
    }

    /// Whether triangle `t` was taken out by [`Tin::collapse`].
    #[inline]
    pub fn is_dead(&self, t: u32) -> bool {
        self.tv[3 * t as usize] == NONE
    }

    /// Whether vertex `v` is still connected (not collapsed away).
    #[inline]
    pub fn is_live(&self, v: u32) -> bool {
        self.out[v as usize] != NONE
    }

    /// The half-edges leaving `v`, counter-clockwise, into `out` (cleared
    /// first); false, with `out` unspecified, where `v` is on the border or
    /// one of its edges is fixed: only such a free vertex may be collapsed.
    pub fn free_star(&self, v: u32, out: &mut Vec<u32>) -> bool {
        out.clear();
        let start = self.out[v as usize];
        if start == NONE {
            return false;
        }
        let mut e = start;
        loop {
            if self.fixed[e as usize] {
                return false;
            }
            out.push(e);
            let t = self.twin[prev(e) as usize];
            if t == NONE || out.len() > 1024 {
                return false;
            }
            e = t;
            if e == start {
                return true;
            }
        }
    }

    /// Collapses half-edge `e` (v → u) of a free vertex v ([`Tin::free_star`])
    /// onto u: the two triangles on the edge go, every other triangle around
    /// v takes u for v. The caller checks that each of those stays
    /// counter-clockwise; they are rewritten (version bumped), and returned
    /// in `changed` (cleared first).
    pub fn collapse(&mut self, e: u32, changed: &mut Vec<u32>) {
        changed.clear();
        let f = self.twin[e as usize];
        let (v, u) = self.ends(e);
        let (en, ep, fnx, fp) = (next(e), prev(e), next(f), prev(f));
        let (x1, fx1, y1) = (self.twin[en as usize], self.fixed[en as usize], self.twin[ep as usize]);
        let (y2, x2, fx2) = (self.twin[fnx as usize], self.twin[fp as usize], self.fixed[fp as usize]);
        // Every half-edge leaving v outside the two triangles now leaves u.
        let mut g = self.twin[ep as usize];
        while g != fnx {
            self.tv[g as usize] = u;
            changed.push(g / 3);
            g = self.twin[prev(g) as usize];
        }
        self.twin[y1 as usize] = x1;
        self.fixed[y1 as usize] = fx1;
        if x1 != NONE {
            self.twin[x1 as usize] = y1;
        }
        self.twin[y2 as usize] = x2;
        self.fixed[y2 as usize] = fx2;
        if x2 != NONE {
            self.twin[x2 as usize] = y2;
        }
        let a = self.tv[ep as usize];
        let b = self.tv[fp as usize];
        self.out[v as usize] = NONE;
        self.out[u as usize] = y1;
        self.out[a as usize] = next(y1);
        self.out[b as usize] = y2;
        for t in [e / 3, f / 3] {
            for k in 0..3 {
                self.tv[(3 * t + k) as usize] = NONE;
                self.twin[(3 * t + k) as usize] = NONE;
            }
            self.version[t as usize] = self.version[t as usize].wrapping_add(1);
        }
        for &t in changed.iter() {
            self.version[t as usize] = self.version[t as usize].wrapping_add(1);
        }
    }

    /// Where `p` lies relative to triangle `t`: `Ok` inside or on it, else
    /// `Err` with a half-edge of `t` that `p` is strictly beyond.
    pub fn classify(&self, t: u32, p: Coord<f64>) -> Result<Position, u32> {
        let e = 3 * t;
        let v = self.triangle(t);
        let o = [0, 1, 2].map(|k| orient2d(self.coord(v[k]), self.coord(v[(k + 1) % 3]), p));
        if let Some(k) = (0..3).find(|&k| o[k] < 0.0) {
            return Err(e + k as u32);
        }
        // The edges `p` lies on, in order (no allocation: this runs once or
        // more per inserted vertex).
        let mut on = [0usize; 3];
        let mut n = 0;
        for k in (0..3).filter(|&k| o[k] == 0.0) {
            on[n] = k;
            n += 1;
        }
        match on[..n] {
            [] => Ok(Position::Face(t)),
            [k] => Ok(Position::Edge(e + k as u32)),
            [k, l] => {
                // On two edges: their common corner.
                let corner = if (k + 1) % 3 == l { v[l] } else { v[k] };
                Ok(Position::Vertex(corner))
            }
            _ => Err(e), // a zero-area triangle: look elsewhere
        }
    }

    /// Locates `p`, walking from triangle `t` (a few steps when `p` is in or
    /// next to it), falling back to trying every triangle.
    pub fn locate_from(&self, mut t: u32, p: Coord<f64>) -> Position {
        for _ in 0..64 {
            match self.classify(t, p) {
                Ok(pos) => return pos,
                Err(e) => match self.twin[e as usize] {
                    NONE => break,
                    f => t = f / 3,
                },
            }
        }
        self.locate(p)
    }

    /// Locates `p` by trying every triangle.
    pub fn locate(&self, p: Coord<f64>) -> Position {
        (0..self.num_triangles() as u32).find_map(|t| self.classify(t, p).ok()).unwrap_or(Position::Outside)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, z: f64) -> V {
        V { x, z, h: 0.0, ph: 0.0 }
    }

    /// The direct incircle on grid points has robust's sign everywhere,
    /// cocircular grid squares (0) and the 4 096-cell limit included, and
    /// off-grid points go to robust.
    #[test]
    fn in_circle_has_the_exact_sign() {
        let mut draw = crate::test_rng::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = |m: u64| (draw() % m) as f64;
        let c = |x: f64, y: f64| Coord { x, y };
        let sign = |v: f64| {
            if v > 0.0 {
                1
            } else if v < 0.0 {
                -1
            } else {
                0
            }
        };
        let (mut zeros, mut cases) = (0, 0);
        for k in 0..200_000 {
            let span = if k % 2 == 0 { 5 } else { 8193 };
            let base = next(100_000);
            let p: Vec<Coord<f64>> = (0..4).map(|_| c(base + next(span), base + next(span))).collect();
            let off = if k % 7 == 0 { 0.5 } else { 0.0 };
            let d = c(p[3].x + off, p[3].y);
            let (fast, exact) = (in_circle(p[0], p[1], p[2], d), incircle(p[0], p[1], p[2], d));
            assert_eq!(sign(fast), sign(exact), "{p:?} {d:?}");
            zeros += usize::from(exact == 0.0);
            cases += 1;
        }
        assert!(zeros > 1000, "{zeros} cocircular cases of {cases}");
        assert_eq!(in_circle(c(0.0, 0.0), c(1.0, 0.0), c(1.0, 1.0), c(0.0, 1.0)), 0.0);
    }

    fn square() -> Tin {
        let pts = vec![v(0.0, 0.0), v(4.0, 0.0), v(4.0, 4.0), v(0.0, 4.0)];
        Tin::from_soup(pts, &[[0, 1, 2], [0, 2, 3]], &[[false; 3]; 2])
    }

    #[track_caller]
    fn check(tin: &Tin) {
        if let Err(broken) = tin.sanity_check() {
            panic!("{broken}");
        }
    }

    #[test]
    fn splits_keep_a_valid_counter_clockwise_mesh_and_find_edges() {
        let mut tin = square();
        check(&tin);
        let c = tin.add_vertex(v(1.0, 2.5));
        let Position::Face(t) = tin.locate(Coord { x: 1.0, y: 2.5 }) else { panic!("inside") };
        tin.split_triangle(t, c);
        check(&tin);
        assert_eq!(tin.num_triangles(), 4);
        // A border point: on the edge from (4, 0) to (4, 4).
        let e = tin.find_edge(1, 2).expect("border edge");
        let m = tin.add_vertex(v(4.0, 2.0));
        tin.split_edge(e, m);
        check(&tin);
        assert_eq!(tin.num_triangles(), 5);
        assert!(tin.find_edge(1, m).is_some() && tin.find_edge(m, 2).is_some() && tin.find_edge(1, 2).is_none());
        assert_eq!(tin.locate(Coord { x: 4.0, y: 2.0 }), Position::Vertex(m));
        assert_eq!(tin.locate(Coord { x: 5.0, y: 2.0 }), Position::Outside);
    }

    /// Random whole-number points (some on edges, some on the fixed
    /// diagonal, some repeated) inserted into a square, then every free
    /// edge whose two triangles make a convex quadrilateral flipped, then
    /// free vertices collapsed onto a neighbour where that keeps every
    /// triangle counter-clockwise: the structure is sound after each step.
    #[test]
    fn every_operation_leaves_a_sound_structure() {
        let mut draw = crate::test_rng::xorshift(0x2545_f491_4f6c_dd1d);
        let pts = vec![v(0.0, 0.0), v(32.0, 0.0), v(32.0, 32.0), v(0.0, 32.0)];
        let mut tin = Tin::from_soup(pts, &[[0, 1, 2], [0, 2, 3]], &[[false, false, true], [true, false, false]]);
        check(&tin);
        let (mut faces, mut edges) = (0, 0);
        for _ in 0..300 {
            let (x, z) = ((draw() % 33) as f64, (draw() % 33) as f64);
            let n = tin.add_vertex(v(x, z));
            match tin.locate_from(0, Coord { x, y: z }) {
                Position::Face(t) => {
                    tin.split_triangle(t, n);
                    faces += 1;
                }
                Position::Edge(e) => {
                    tin.split_edge(e, n);
                    edges += 1;
                }
                // Already a vertex: the new one stays unconnected.
                Position::Vertex(_) => {}
                Position::Outside => panic!("({x}, {z}) is inside"),
            }
            check(&tin);
        }
        assert!(faces > 100 && edges > 10, "{faces} points in faces, {edges} on edges");
        let pos = |tin: &Tin, v: u32| tin.coord(v);
        let mut flips = 0;
        for e in 0..tin.tv.len() as u32 {
            let Some(f) = tin.twin_of(e) else { continue };
            if tin.is_fixed(e) {
                continue;
            }
            let (a, b) = tin.ends(e);
            let (c, d) = (tin.apex(e), tin.apex(f));
            let convex = orient2d(pos(&tin, c), pos(&tin, a), pos(&tin, d)) > 0.0
                && orient2d(pos(&tin, d), pos(&tin, b), pos(&tin, c)) > 0.0;
            if convex {
                tin.flip(e);
                check(&tin);
                flips += 1;
            }
        }
        assert!(flips > 100, "{flips} flips");
        let (mut star, mut changed, mut collapses) = (Vec::new(), Vec::new(), 0);
        for w in 4..tin.pts.len() as u32 {
            if !tin.free_star(w, &mut star) {
                continue;
            }
            let keeps = |u: u32| {
                star.iter().all(|&g| {
                    let (_, x) = tin.ends(g);
                    let y = tin.apex(g);
                    x == u || y == u || orient2d(pos(&tin, u), pos(&tin, x), pos(&tin, y)) > 0.0
                })
            };
            if let Some(&e) = star.iter().find(|&&e| keeps(tin.ends(e).1)) {
                tin.collapse(e, &mut changed);
                check(&tin);
                collapses += 1;
            }
        }
        assert!(collapses > 20, "{collapses} collapses");
    }

    #[test]
    fn fixed_edges_are_never_flipped() {
        // The diagonal (0, 2) is fixed; a point next to it would flip it if free.
        let pts = vec![v(0.0, 0.0), v(4.0, 0.0), v(4.0, 4.0), v(0.0, 4.0)];
        let mut tin = Tin::from_soup(pts, &[[0, 1, 2], [0, 2, 3]], &[[false, false, true], [true, false, false]]);
        let p = Coord { x: 2.2, y: 1.8 };
        let c = tin.add_vertex(v(p.x, p.y));
        let Position::Face(t) = tin.locate(p) else { panic!("inside") };
        tin.split_triangle(t, c);
        check(&tin);
        assert!(tin.find_edge(0, 2).is_some());
        let mut free = square();
        let c = free.add_vertex(v(p.x, p.y));
        let Position::Face(t) = free.locate(p) else { panic!("inside") };
        free.split_triangle(t, c);
        check(&free);
        assert!(free.find_edge(0, 2).is_none(), "an unfixed diagonal is flipped to Delaunay");
    }

    /// Two parts filled on their own and joined make the TIN that one
    /// soup of all their triangles makes: the same corners, twins, fixed
    /// flags and out half-edges (thinning starts each vertex's star there).
    #[test]
    fn joined_parts_are_the_tin_their_soup_makes() {
        // Two squares of 4 × 4 cells side by side, each two triangles, their
        // shared side (x = 4) fixed in both; each part then refined with
        // four points of its own.
        let mut pts: Vec<V> = Vec::new();
        let corner = |pts: &mut Vec<V>, x: f64, z: f64| {
            pts.push(v(x, z));
            (pts.len() - 1) as u32
        };
        let [a, b, c, d, e, f] = [(0.0, 0.0), (4.0, 0.0), (8.0, 0.0), (0.0, 4.0), (4.0, 4.0), (8.0, 4.0)]
            .map(|(x, z)| corner(&mut pts, x, z));
        let halves = [
            ([a, b, e, d], [[false, true, false], [false, false, false]]),
            ([b, c, f, e], [[false, false, false], [false, false, true]]),
        ];
        let mut parts = Vec::new();
        let mut first_new = pts.len();
        for (k, ([p, q, r, s], fixed)) in halves.into_iter().enumerate() {
            let whole = vec![p, q, r, s];
            let mut local: Vec<V> = whole.iter().map(|&w| pts[w as usize]).collect();
            let x0 = 4.0 * k as f64;
            let inner = [(x0 + 1.0, 2.0), (x0 + 3.0, 1.0), (x0 + 2.0, 3.0), (x0 + 1.0, 3.5)];
            local.extend(inner.iter().map(|&(x, z)| v(x, z)));
            let mut sub = Tin::from_soup(local, &[[0, 1, 2], [0, 2, 3]], &fixed);
            for n in 4..sub.pts.len() as u32 {
                let p = sub.pts[n as usize];
                match sub.locate(Coord { x: p.x, y: p.z }) {
                    Position::Face(t) => sub.split_triangle(t, n),
                    Position::Edge(e) => sub.split_edge(e, n),
                    other => panic!("{other:?}"),
                }
                check(&sub);
            }
            let id: Vec<u32> =
                whole.into_iter().chain((first_new..first_new + inner.len()).map(|v| v as u32)).collect();
            first_new += inner.len();
            pts.extend(inner.iter().map(|&(x, z)| v(x, z)));
            parts.push((sub, id));
        }
        let refs: Vec<(&Tin, &[u32])> = parts.iter().map(|(sub, id)| (sub, &id[..])).collect();
        let joined = Tin::from_parts(pts.clone(), &refs);
        let mut tris = Vec::new();
        let mut fixed = Vec::new();
        for (sub, id) in &parts {
            for t in 0..sub.num_triangles() as u32 {
                tris.push(sub.triangle(t).map(|v| id[v as usize]));
                fixed.push([0, 1, 2].map(|k| sub.is_fixed(3 * t + k)));
            }
        }
        let soup = Tin::from_soup(pts, &tris, &fixed);
        check(&joined);
        assert_eq!(joined.tv, soup.tv);
        assert_eq!(joined.twin, soup.twin);
        assert_eq!(joined.fixed, soup.fixed);
        assert_eq!(joined.out, soup.out);
        assert_eq!(joined.version, soup.version);
        // The cut b–e is one edge of the whole: its halves are twins across the parts.
        let left = parts[0].0.num_triangles();
        let across: Vec<usize> = (0..joined.tv.len())
            .filter(|&h| (h / 3 < left) != ((joined.twin[h] as usize) / 3 < left) && joined.twin[h] != NONE)
            .collect();
        assert_eq!(across.len(), 2);
        assert!(across.iter().all(|&h| joined.fixed[h] && [b, e].contains(&joined.tv[h])));
    }

    /// Sierra 3 × 3 at 5 m with 32-cell leaves in `quantize` failed `verify`
    /// (a morph target 10.5 m off its parent): three parent edges from one
    /// vertex crossed a dividing line within one lattice step, so their cut
    /// points sat at one point as three vertices, with flat triangles
    /// between them; a sample exactly on one of those edges split it, and
    /// the flat triangle beside it became a wall, three distinct corners in
    /// a line, over which the surface had two heights. The split now flips
    /// the wall away, on through every flat triangle in the fan, and keeps
    /// the edges along the spokes fixed.
    #[test]
    fn splitting_an_edge_beside_flat_triangles_leaves_no_wall() {
        // A, B and C are one point; spokes to X; `top` and `w` close the fan.
        let pts = vec![v(0.0, 0.0), v(0.0, 0.0), v(0.0, 0.0), v(4.0, 4.0), v(0.0, 4.0), v(4.0, 0.0)];
        let (a, b, c, x, top, w) = (0, 1, 2, 3, 4, 5);
        let tris = [[a, x, top], [x, a, b], [x, b, c], [c, w, x]];
        let mut tin = Tin::from_soup(
            pts,
            &tris,
            &[[true, false, false], [true, false, true], [true, false, true], [false, false, true]],
        );
        check(&tin);
        let p = Coord { x: 2.0, y: 2.0 };
        let Position::Edge(e) = tin.locate_from(0, p) else { panic!("(2, 2) lies on the spoke A–X") };
        let m = tin.add_vertex(v(p.x, p.y));
        tin.split_edge(e, m);
        check(&tin);
        let same = |p: u32, q: u32| tin.coord(p).x == tin.coord(q).x && tin.coord(p).y == tin.coord(q).y;
        let mut area = 0.0;
        for t in 0..tin.num_triangles() as u32 {
            let [p, q, r] = tin.triangle(t);
            let o = orient2d(tin.coord(p), tin.coord(q), tin.coord(r));
            assert!(o >= 0.0, "triangle {:?} turned over", tin.corners(t));
            assert!(o > 0.0 || same(p, q) || same(q, r) || same(r, p), "a wall: {:?}", tin.corners(t));
            area += o / 2.0;
        }
        assert_eq!(area, 16.0, "the fan's area, covered once");
        // The new vertex joins the far corners on both sides, and every
        // spoke's half towards the fan's point stays fixed, as does X–m.
        assert!(tin.find_edge(m, top).is_some() && tin.find_edge(m, w).is_some());
        for end in [a, b, c, x] {
            let h = tin.find_edge(m, end).unwrap_or_else(|| panic!("no edge from the new vertex to {end}"));
            assert!(tin.is_fixed(h), "edge to {end} is not fixed");
        }
    }

    #[test]
    fn an_edge_is_not_split_at_a_point_beside_it_where_the_sliver_across_would_turn_over() {
        // Edge A–B, fixed; C above it; across it a sliver whose far corner D
        // lies a thousandth of a cell below the line, past B.
        let pts = vec![v(0.0, 0.0), v(10.0, 0.0), v(5.0, 5.0), v(12.0, -0.001)];
        let (a, b, c, d) = (0, 1, 2, 3);
        let tin = Tin::from_soup(pts, &[[a, b, c], [b, a, d]], &[[true, false, false], [true, false, false]]);
        let e = tin.find_edge(a, b).unwrap();
        let e = if tin.ends(e) == (a, b) { e } else { tin.twin[e as usize] };
        // A hundredth of a cell above A–B: [B, p, D] would be clockwise.
        assert!(!tin.splits_cleanly(e, Coord { x: 7.0, y: 0.01 }));
        // A ten-thousandth above: all four halves stay counter-clockwise.
        assert!(tin.splits_cleanly(e, Coord { x: 7.0, y: 0.0001 }));
        // On a border (no triangle across) only the near side counts.
        let lone = Tin::from_soup(vec![v(0.0, 0.0), v(10.0, 0.0), v(5.0, 5.0)], &[[0, 1, 2]], &[[true; 3]]);
        let e = lone.find_edge(0, 1).unwrap();
        assert!(lone.splits_cleanly(e, Coord { x: 7.0, y: 0.01 }));
    }
}
