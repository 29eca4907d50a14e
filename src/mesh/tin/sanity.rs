//! [`Tin::sanity_check`]: walks the whole half-edge structure and names the
//! first broken invariant, so that tests can call it after every mutation
//! (spade's `sanity_check` is the model) instead of trusting the meshes a
//! broken structure might still write.
//!
//! What holds, from how the TIN is built and changed: triangle slots are
//! live (three distinct corners) or dead (collapsed: no corners, no twins);
//! twins pair a → b with b → a and share the fixed flag; every live
//! triangle is counter-clockwise by the exact predicate, or flat with two
//! corners at one point (crossings a quantized file places on one lattice
//! point stay separate vertices, joined by zero-length edges), never a wall
//! of three distinct corners in a line; each connected vertex's out
//! half-edge leaves it and its star is one fan; and the triangles make a
//! disc whose border is one convex loop around it once. Positive triangles
//! over a disc whose border winds once around every inside point cover
//! each point once (the degree of the map is the border's winding number),
//! so these local checks are enough for a planar triangulation.
//!
//! Faces are implicit (triangle `t` owns half-edges `3t..3t + 2`, `next`
//! is arithmetic), so next∘next∘next is the identity by construction; the
//! array lengths that layout needs are checked instead.

use std::cmp::Ordering;

use robust::orient2d;

use super::{NONE, Tin, next, prev};

/// The first broken invariant [`Tin::sanity_check`] met.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Broken {
    /// The per-half-edge arrays are not three entries per triangle, or the
    /// out half-edges not one per vertex.
    #[error("array lengths do not match the triangle and vertex counts")]
    Lengths,
    /// A triangle listed as rewritten is not a slot.
    #[error("dirty triangle {t} is past the last slot")]
    Dirty {
        /// The triangle.
        t: u32,
    },
    /// A slot is neither live (three corners) nor dead (no corners, no twins).
    #[error("triangle {t} is half dead")]
    HalfDead {
        /// The triangle.
        t: u32,
    },
    /// A corner is not a vertex.
    #[error("triangle {t} has corner {v}, past the last vertex")]
    CornerOutOfRange {
        /// The triangle.
        t: u32,
        /// The corner.
        v: u32,
    },
    /// A corner appears twice in one triangle.
    #[error("triangle {t} has corner {v} twice")]
    RepeatedCorner {
        /// The triangle.
        t: u32,
        /// The corner.
        v: u32,
    },
    /// A corner of a live triangle has no out half-edge.
    #[error("vertex {v}, a corner of triangle {t}, has no out half-edge")]
    Unlinked {
        /// The vertex.
        v: u32,
        /// The triangle.
        t: u32,
    },
    /// A vertex's out half-edge does not leave it, or is dead.
    #[error("vertex {v}'s out half-edge {e} does not leave it")]
    OutEdge {
        /// The vertex.
        v: u32,
        /// Its out half-edge.
        e: u32,
    },
    /// A connected vertex's position is not finite.
    #[error("vertex {v} is not at a finite position")]
    NotFinite {
        /// The vertex.
        v: u32,
    },
    /// Two connected vertices share a position without a chain of
    /// zero-length edges between them.
    #[error("vertices {a} and {b} share a position but no zero-length edge joins them")]
    SharedPosition {
        /// One vertex.
        a: u32,
        /// The other.
        b: u32,
    },
    /// A live triangle is clockwise.
    #[error("triangle {t} is clockwise")]
    Clockwise {
        /// The triangle.
        t: u32,
    },
    /// A live triangle has three distinct corners in a line.
    #[error("triangle {t} is a wall: three distinct corners in a line")]
    Wall {
        /// The triangle.
        t: u32,
    },
    /// A half-edge's twin does not point back at it.
    #[error("half-edge {e}'s twin {f} does not point back")]
    TwinNotBack {
        /// The half-edge.
        e: u32,
        /// Its twin.
        f: u32,
    },
    /// A half-edge and its twin do not run between the same vertices the
    /// other way round.
    #[error("half-edge {e} and its twin {f} do not run between the same vertices")]
    TwinEnds {
        /// The half-edge.
        e: u32,
        /// Its twin.
        f: u32,
    },
    /// An edge is fixed on one half only.
    #[error("half-edge {e} and its twin {f} disagree on being fixed")]
    FixedDiffers {
        /// The half-edge.
        e: u32,
        /// Its twin.
        f: u32,
    },
    /// Two live half-edges run from one vertex to the same other one.
    #[error("half-edges {e} and {f} both run from {a} to {b}")]
    DuplicateEdge {
        /// One half-edge.
        e: u32,
        /// The other.
        f: u32,
        /// Their origin.
        a: u32,
        /// Their end.
        b: u32,
    },
    /// Walking around a vertex from its out half-edge misses some of the
    /// half-edges leaving it: its star is not one fan.
    #[error("walking around vertex {v} meets {walked} of the {leaving} half-edges leaving it")]
    Star {
        /// The vertex.
        v: u32,
        /// Half-edges the walk met.
        walked: u32,
        /// Half-edges leaving the vertex.
        leaving: u32,
    },
    /// V − E + F is not 1, a disc's Euler characteristic.
    #[error("V − E + F = {vertices} − {edges} + {faces}, not 1")]
    Euler {
        /// Connected vertices.
        vertices: u32,
        /// Edges, each counted once.
        edges: u32,
        /// Live triangles.
        faces: u32,
    },
    /// The half-edges without a twin do not make exactly one loop.
    #[error("the border is {loops} loops, not one")]
    BorderLoops {
        /// Loops found.
        loops: u32,
    },
    /// The border turns right, or doubles back, at a vertex.
    #[error("the border is not convex at vertex {v}")]
    BorderNotConvex {
        /// The vertex.
        v: u32,
    },
    /// The border's convex loop goes around more than once (or never).
    #[error("the border goes around {turns} times, not once")]
    BorderWinding {
        /// Full turns.
        turns: u32,
    },
}

impl Tin {
    /// Checks every invariant of the structure (see the module comment)
    /// and names the first one broken. Linear in its size but for one
    /// sort (of the connected vertices by position); for tests and debug
    /// builds.
    pub fn sanity_check(&self) -> Result<(), Broken> {
        self.check_slots()?;
        self.check_vertex_links()?;
        self.check_positions()?;
        self.check_orientation()?;
        self.check_twins()?;
        self.check_stars()?;
        self.check_euler()?;
        self.check_border()
    }

    fn live_triangles(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.num_triangles() as u32).filter(|&t| !self.is_dead(t))
    }

    fn live_half_edges(&self) -> impl Iterator<Item = u32> + '_ {
        self.live_triangles().flat_map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
    }

    fn same_place(&self, a: u32, b: u32) -> bool {
        let (p, q) = (&self.pts[a as usize], &self.pts[b as usize]);
        p.x == q.x && p.z == q.z
    }

    fn check_slots(&self) -> Result<(), Broken> {
        let n = 3 * self.num_triangles();
        if self.tv.len() != n || self.twin.len() != n || self.fixed.len() != n || self.out.len() != self.pts.len() {
            return Err(Broken::Lengths);
        }
        if let Some(&t) = self.dirty.iter().find(|&&t| t as usize >= self.num_triangles()) {
            return Err(Broken::Dirty { t });
        }
        for t in 0..self.num_triangles() as u32 {
            let e = 3 * t as usize;
            let corners = &self.tv[e..e + 3];
            let dead = corners.iter().all(|&v| v == NONE) && self.twin[e..e + 3].iter().all(|&f| f == NONE);
            if dead {
                continue;
            }
            if corners.contains(&NONE) {
                return Err(Broken::HalfDead { t });
            }
            if let Some(&v) = corners.iter().find(|&&v| v as usize >= self.pts.len()) {
                return Err(Broken::CornerOutOfRange { t, v });
            }
            if corners[0] == corners[1] || corners[0] == corners[2] {
                return Err(Broken::RepeatedCorner { t, v: corners[0] });
            }
            if corners[1] == corners[2] {
                return Err(Broken::RepeatedCorner { t, v: corners[1] });
            }
        }
        Ok(())
    }

    /// Every corner of a live triangle is connected, and every connected
    /// vertex's out half-edge is live and leaves it.
    fn check_vertex_links(&self) -> Result<(), Broken> {
        for t in self.live_triangles() {
            if let Some(v) = self.triangle(t).into_iter().find(|&v| !self.is_live(v)) {
                return Err(Broken::Unlinked { v, t });
            }
        }
        for (v, &e) in self.out.iter().enumerate() {
            let leaves = e == NONE || (e as usize) < self.tv.len() && self.tv[e as usize] == v as u32;
            if !leaves {
                return Err(Broken::OutEdge { v: v as u32, e });
            }
        }
        Ok(())
    }

    /// Finite positions, and vertices at one position only where
    /// zero-length edges join them (crossings on one lattice point).
    fn check_positions(&self) -> Result<(), Broken> {
        let live: Vec<u32> = (0..self.pts.len() as u32).filter(|&v| self.is_live(v)).collect();
        if let Some(&v) =
            live.iter().find(|&&v| !(self.pts[v as usize].x.is_finite() && self.pts[v as usize].z.is_finite()))
        {
            return Err(Broken::NotFinite { v });
        }
        // By position's bits (0.0 for −0.0, so equal positions sort
        // together), then index.
        let key = |v: u32| {
            let p = &self.pts[v as usize];
            ((p.x + 0.0).to_bits(), (p.z + 0.0).to_bits(), v)
        };
        let mut keyed: Vec<(u64, u64, u32)> = live.iter().map(|&v| key(v)).collect();
        keyed.sort_unstable();
        let shared = |w: &[(u64, u64, u32)]| w[0].0 == w[1].0 && w[0].1 == w[1].1;
        if !keyed.windows(2).any(shared) {
            return Ok(());
        }
        // Union the ends of every zero-length edge; each group of vertices
        // at one position must then be one set.
        let mut parent: Vec<u32> = (0..self.pts.len() as u32).collect();
        fn root(parent: &mut [u32], mut v: u32) -> u32 {
            while parent[v as usize] != v {
                parent[v as usize] = parent[parent[v as usize] as usize];
                v = parent[v as usize];
            }
            v
        }
        for e in self.live_half_edges() {
            let (a, b) = self.ends(e);
            if self.same_place(a, b) {
                let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                parent[ra as usize] = rb;
            }
        }
        for w in keyed.windows(2).filter(|w| shared(w)) {
            let (a, b) = (w[0].2, w[1].2);
            if root(&mut parent, a) != root(&mut parent, b) {
                return Err(Broken::SharedPosition { a, b });
            }
        }
        Ok(())
    }

    /// Counter-clockwise by the exact predicate, or flat with two corners
    /// at one point.
    fn check_orientation(&self) -> Result<(), Broken> {
        for t in self.live_triangles() {
            let [a, b, c] = self.triangle(t);
            let o = orient2d(self.coord(a), self.coord(b), self.coord(c));
            if o < 0.0 {
                return Err(Broken::Clockwise { t });
            }
            if o == 0.0 && !(self.same_place(a, b) || self.same_place(b, c) || self.same_place(c, a)) {
                return Err(Broken::Wall { t });
            }
        }
        Ok(())
    }

    /// Twins point back, run the other way between the same vertices and
    /// agree on the fixed flag.
    fn check_twins(&self) -> Result<(), Broken> {
        for e in self.live_half_edges() {
            let f = self.twin[e as usize];
            if f == NONE {
                continue;
            }
            if f as usize >= self.twin.len() || self.twin[f as usize] != e {
                return Err(Broken::TwinNotBack { e, f });
            }
            // The two halves point at each other: the rest reads the same
            // from either, so the first of the two checks it.
            if f < e {
                continue;
            }
            let (a, b) = self.ends(e);
            if self.is_dead(f / 3) || self.ends(f) != (b, a) {
                return Err(Broken::TwinEnds { e, f });
            }
            if self.fixed[e as usize] != self.fixed[f as usize] {
                return Err(Broken::FixedDiffers { e, f });
            }
        }
        Ok(())
    }

    /// Each connected vertex's star is one fan: the walk around it from its
    /// out half-edge (as [`Tin::find_edge`] walks) meets every half-edge
    /// leaving it, each to a different vertex (positive triangles could not
    /// repeat one; flat ones could).
    fn check_stars(&self) -> Result<(), Broken> {
        let mut leaving = vec![0u32; self.pts.len()];
        for e in self.live_half_edges() {
            leaving[self.tv[e as usize] as usize] += 1;
        }
        // Per vertex, the half-edge the current walk reached it by.
        let mut reached: Vec<(u32, u32)> = vec![(NONE, NONE); self.pts.len()];
        for v in 0..self.pts.len() as u32 {
            let start = self.out[v as usize];
            if start == NONE {
                continue;
            }
            let most = leaving[v as usize];
            let mut walked = 0;
            let mut visit = |e: u32| {
                walked += 1;
                let b = self.tv[next(e) as usize];
                match reached[b as usize] {
                    (owner, f) if owner == v => Err(Broken::DuplicateEdge { e: f, f: e, a: v, b }),
                    _ => {
                        reached[b as usize] = (v, e);
                        Ok(())
                    }
                }
            };
            visit(start)?;
            // Counter-clockwise until the border or back at the start,
            // then clockwise from the start to the other border.
            let (mut e, mut closed, mut steps) = (start, false, 1);
            while steps <= most {
                match self.twin[prev(e) as usize] {
                    NONE => break,
                    f if f == start => {
                        closed = true;
                        break;
                    }
                    f => {
                        e = f;
                        steps += 1;
                        visit(e)?;
                    }
                }
            }
            let mut e = start;
            while !closed && steps <= most {
                match self.twin[e as usize] {
                    NONE => break,
                    f => {
                        e = next(f);
                        steps += 1;
                        visit(e)?;
                    }
                }
            }
            if walked != most {
                return Err(Broken::Star { v, walked, leaving: most });
            }
        }
        Ok(())
    }

    fn border_half_edges(&self) -> impl Iterator<Item = u32> + '_ {
        self.live_half_edges().filter(|&e| self.twin[e as usize] == NONE)
    }

    fn check_euler(&self) -> Result<(), Broken> {
        let vertices = self.out.iter().filter(|&&e| e != NONE).count() as u32;
        let faces = self.live_triangles().count() as u32;
        let border = self.border_half_edges().count() as u32;
        let edges = (3 * faces + border) / 2;
        if i64::from(vertices) - i64::from(edges) + i64::from(faces) != 1 {
            return Err(Broken::Euler { vertices, edges, faces });
        }
        Ok(())
    }

    /// The border half-edge that follows `e` (a border half-edge into b):
    /// the last one out of b turning counter-clockwise from `e`'s triangle.
    fn next_on_border(&self, e: u32) -> u32 {
        let mut g = next(e);
        while self.twin[g as usize] != NONE {
            g = next(self.twin[g as usize]);
        }
        g
    }

    /// One loop of border half-edges, convex (every turn left or straight
    /// on, zero-length edges aside) and going around once: its edges'
    /// directions cross into the upper half-plane once.
    fn check_border(&self) -> Result<(), Broken> {
        let border: Vec<u32> = self.border_half_edges().collect();
        if border.is_empty() {
            return match self.live_triangles().next() {
                Some(_) => Err(Broken::BorderLoops { loops: 0 }),
                None => Ok(()),
            };
        }
        let mut seen = vec![false; self.tv.len()];
        let mut loops = 0;
        let mut ring = Vec::new();
        for &first in &border {
            if seen[first as usize] {
                continue;
            }
            loops += 1;
            let mut e = first;
            while !seen[e as usize] {
                seen[e as usize] = true;
                if loops == 1 {
                    ring.push(self.tv[e as usize]);
                }
                e = self.next_on_border(e);
            }
        }
        if loops != 1 {
            return Err(Broken::BorderLoops { loops });
        }
        // The loop's corners, each run of vertices at one point taken once.
        ring.dedup_by(|a, b| self.same_place(*a, *b));
        while ring.len() > 1 && self.same_place(ring[0], ring[ring.len() - 1]) {
            ring.pop();
        }
        let n = ring.len();
        if n < 3 {
            return Err(Broken::BorderNotConvex { v: ring[0] });
        }
        let p = |k: usize| self.coord(ring[k % n]);
        for k in 0..n {
            let (a, b, c) = (p(k), p(k + 1), p(k + 2));
            let o = orient2d(a, b, c);
            // On a line, b must lie between a and c, not where the
            // border doubles back.
            let straight =
                || a.x.partial_cmp(&b.x) == b.x.partial_cmp(&c.x) && a.y.partial_cmp(&b.y) == b.y.partial_cmp(&c.y);
            if o < 0.0 || o == 0.0 && !straight() {
                return Err(Broken::BorderNotConvex { v: ring[(k + 1) % n] });
            }
        }
        // Each turn is left by less than half a turn, so the directions
        // enter the half-plane [0, π) once per time around.
        let upper = |k: usize| {
            let (a, b) = (p(k), p(k + 1));
            match b.y.partial_cmp(&a.y) {
                Some(Ordering::Greater) => true,
                Some(Ordering::Equal) => b.x > a.x,
                _ => false,
            }
        };
        let turns = (0..n).filter(|&k| !upper(k) && upper(k + 1)).count() as u32;
        if turns != 1 {
            return Err(Broken::BorderWinding { turns });
        }
        Ok(())
    }
}

/// One test per kind of violation: each corrupts a valid TIN (or builds a
/// bad one from a soup, which [`Tin::from_soup`] does not check) and
/// expects that kind named, so the check cannot pass everything.
#[cfg(test)]
mod tests {
    use robust::Coord;

    use super::super::{Position, V};
    use super::*;

    fn v(x: f64, z: f64) -> V {
        V { x, z, h: 0.0, ph: 0.0 }
    }

    fn insert(tin: &mut Tin, x: f64, z: f64) -> u32 {
        let n = tin.add_vertex(v(x, z));
        match tin.locate(Coord { x, y: z }) {
            Position::Face(t) => tin.split_triangle(t, n),
            Position::Edge(e) => tin.split_edge(e, n),
            other => panic!("({x}, {z}): {other:?}"),
        }
        n
    }

    /// A square of 8 × 8 cells with points inserted inside it and on its
    /// border: interior and border vertices, flipped edges.
    fn valid() -> Tin {
        let pts = vec![v(0.0, 0.0), v(8.0, 0.0), v(8.0, 8.0), v(0.0, 8.0)];
        let mut tin = Tin::from_soup(pts, &[[0, 1, 2], [0, 2, 3]], &[[false; 3]; 2]);
        for (x, z) in [(3.0, 2.0), (5.0, 6.0), (2.0, 5.0), (6.0, 3.0), (8.0, 4.0), (4.0, 4.0)] {
            insert(&mut tin, x, z);
        }
        assert_eq!(tin.sanity_check(), Ok(()));
        tin
    }

    fn soup(pts: &[(f64, f64)], tris: &[[u32; 3]]) -> Tin {
        let pts = pts.iter().map(|&(x, z)| v(x, z)).collect();
        Tin::from_soup(pts, tris, &vec![[false; 3]; tris.len()])
    }

    /// A live interior half-edge of `tin` (it has a twin).
    fn inner(tin: &Tin) -> u32 {
        (0..tin.tv.len() as u32).find(|&e| tin.twin[e as usize] != NONE).expect("an inner edge")
    }

    #[test]
    fn a_half_edge_array_of_the_wrong_length_is_caught() {
        let mut tin = valid();
        tin.fixed.push(false);
        assert_eq!(tin.sanity_check(), Err(Broken::Lengths));
    }

    #[test]
    fn a_dirty_triangle_past_the_last_slot_is_caught() {
        let mut tin = valid();
        let t = tin.num_triangles() as u32;
        tin.dirty.push(t);
        assert_eq!(tin.sanity_check(), Err(Broken::Dirty { t }));
    }

    #[test]
    fn a_half_dead_triangle_is_caught() {
        let mut tin = valid();
        tin.tv[6] = NONE;
        assert_eq!(tin.sanity_check(), Err(Broken::HalfDead { t: 2 }));
    }

    #[test]
    fn a_corner_past_the_last_vertex_is_caught() {
        let mut tin = valid();
        let v = tin.pts.len() as u32;
        tin.tv[4] = v;
        assert_eq!(tin.sanity_check(), Err(Broken::CornerOutOfRange { t: 1, v }));
    }

    #[test]
    fn a_corner_twice_in_a_triangle_is_caught() {
        let mut tin = valid();
        tin.tv[4] = tin.tv[3];
        assert_eq!(tin.sanity_check(), Err(Broken::RepeatedCorner { t: 1, v: tin.tv[3] }));
    }

    #[test]
    fn a_corner_without_an_out_half_edge_is_caught() {
        let mut tin = valid();
        let v = tin.tv[0];
        tin.out[v as usize] = NONE;
        assert!(matches!(tin.sanity_check(), Err(Broken::Unlinked { v: u, .. }) if u == v));
    }

    #[test]
    fn an_out_half_edge_that_leaves_another_vertex_is_caught() {
        let mut tin = valid();
        let (a, b) = tin.ends(0);
        let e = tin.out[b as usize];
        tin.out[a as usize] = e;
        assert_eq!(tin.sanity_check(), Err(Broken::OutEdge { v: a, e }));
    }

    #[test]
    fn a_vertex_at_no_finite_position_is_caught() {
        let mut tin = valid();
        tin.pts[5].z = f64::NAN;
        assert_eq!(tin.sanity_check(), Err(Broken::NotFinite { v: 5 }));
    }

    /// Two vertices at one point are allowed only joined by zero-length
    /// edges (crossings on one lattice point); a vertex moved onto another
    /// it shares no edge with is a duplicate.
    #[test]
    fn a_duplicate_vertex_is_caught() {
        let mut tin = valid();
        let n = tin.pts.len() as u32;
        let (a, b) = (0..n)
            .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
            .find(|&(a, b)| tin.find_edge(a, b).is_none())
            .expect("two vertices without an edge");
        tin.pts[b as usize] = tin.pts[a as usize];
        assert_eq!(tin.sanity_check(), Err(Broken::SharedPosition { a, b }));
        // Joined by an edge they may share a point: the triangles on that
        // edge are flat, the others still counter-clockwise.
        let pts = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0), (0.0, 0.0)];
        let tin = soup(&pts, &[[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]);
        assert_eq!(tin.sanity_check(), Ok(()));
    }

    #[test]
    fn a_triangle_turned_clockwise_is_caught() {
        let mut tin = valid();
        tin.tv.swap(4, 5);
        tin.reset_out();
        assert_eq!(tin.sanity_check(), Err(Broken::Clockwise { t: 1 }));
    }

    /// Three distinct corners in a line: the centre of a fan moved onto the
    /// square's south side.
    #[test]
    fn a_wall_is_caught() {
        let pts = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0), (2.0, 0.0)];
        let tin = soup(&pts, &[[1, 2, 4], [2, 3, 4], [3, 0, 4], [0, 1, 4]]);
        assert_eq!(tin.sanity_check(), Err(Broken::Wall { t: 3 }));
    }

    #[test]
    fn a_twin_link_that_does_not_point_back_is_caught() {
        let mut tin = valid();
        let e = inner(&tin);
        let f = tin.twin[e as usize];
        tin.twin[f as usize] = NONE;
        assert_eq!(tin.sanity_check(), Err(Broken::TwinNotBack { e, f }));
    }

    #[test]
    fn twins_that_join_different_edges_are_caught() {
        let mut tin = valid();
        let e = inner(&tin);
        let f = tin.twin[e as usize];
        let g = (e + 1..tin.tv.len() as u32)
            .find(|&g| g != f && tin.twin[g as usize] != NONE && tin.twin[g as usize] > g)
            .expect("another edge");
        let h = tin.twin[g as usize];
        for (p, q) in [(e, g), (f, h)] {
            tin.twin[p as usize] = q;
            tin.twin[q as usize] = p;
        }
        assert_eq!(tin.sanity_check(), Err(Broken::TwinEnds { e, f: g }));
    }

    #[test]
    fn an_edge_fixed_on_one_half_only_is_caught() {
        let mut tin = valid();
        let e = inner(&tin);
        tin.fixed[e as usize] = true;
        assert_eq!(tin.sanity_check(), Err(Broken::FixedDiffers { e, f: tin.twin[e as usize] }));
    }

    /// Four flat triangles around vertex 0, every vertex at one point,
    /// whose fan meets vertex 1 twice: no area rules that out, the walk
    /// around 0 does.
    #[test]
    fn an_edge_used_twice_the_same_way_is_caught() {
        let mut tin = soup(&[(0.0, 0.0); 4], &[[0, 1, 2], [0, 2, 1], [0, 1, 3], [0, 3, 1]]);
        // The twins of the fan closing around 0 (the soup's search pairs
        // the repeated edges as it finds them).
        for (e, f) in [(2usize, 3usize), (1, 4), (5, 6), (8, 9), (7, 10), (11, 0)] {
            tin.twin[e] = f as u32;
            tin.twin[f] = e as u32;
        }
        assert_eq!(tin.sanity_check(), Err(Broken::DuplicateEdge { e: 0, f: 6, a: 0, b: 1 }));
    }

    /// Two triangles that meet at one vertex only, and two on one side of
    /// one edge that both keep it as their border: a star of two fans.
    #[test]
    fn a_vertex_pinched_between_two_fans_is_caught() {
        let tin = soup(&[(0.0, 0.0), (2.0, -1.0), (2.0, 1.0), (-2.0, 1.0), (-2.0, -1.0)], &[[0, 1, 2], [0, 3, 4]]);
        assert_eq!(tin.sanity_check(), Err(Broken::Star { v: 0, walked: 1, leaving: 2 }));
        let tin = soup(&[(0.0, 0.0), (4.0, 0.0), (2.0, 2.0), (2.0, 3.0)], &[[0, 1, 2], [0, 1, 3]]);
        assert_eq!(tin.sanity_check(), Err(Broken::Star { v: 0, walked: 1, leaving: 2 }));
    }

    /// A square with a square hole: 8 vertices, 16 edges, 8 triangles.
    fn ring() -> (Vec<(f64, f64)>, Vec<[u32; 3]>) {
        let pts = vec![(0.0, 0.0), (3.0, 0.0), (3.0, 3.0), (0.0, 3.0), (1.0, 1.0), (2.0, 1.0), (2.0, 2.0), (1.0, 2.0)];
        let mut tris = Vec::new();
        for k in 0..4 {
            let (o, o1, i, i1) = (k, (k + 1) % 4, k + 4, (k + 1) % 4 + 4);
            tris.extend([[o, o1, i1], [o, i1, i]]);
        }
        (pts, tris)
    }

    #[test]
    fn a_tin_with_a_hole_breaks_eulers_formula() {
        let (pts, tris) = ring();
        assert_eq!(soup(&pts, &tris).sanity_check(), Err(Broken::Euler { vertices: 8, edges: 16, faces: 8 }));
    }

    /// A ring and a triangle apart from it: V − E + F is 1 again, but the
    /// border is three loops.
    #[test]
    fn a_border_of_several_loops_is_caught() {
        let (mut pts, mut tris) = ring();
        pts.extend([(10.0, 0.0), (12.0, 0.0), (11.0, 1.0)]);
        tris.push([8, 9, 10]);
        assert_eq!(soup(&pts, &tris).sanity_check(), Err(Broken::BorderLoops { loops: 3 }));
    }

    /// A quadrilateral whose fourth corner lies a hair below the line of
    /// one side, past its end: the border turns right there.
    #[test]
    fn a_concave_border_is_caught() {
        let tin = soup(&[(0.0, 0.0), (10.0, 0.0), (5.0, 5.0), (12.0, -0.001)], &[[0, 1, 2], [1, 0, 3]]);
        assert_eq!(tin.sanity_check(), Err(Broken::BorderNotConvex { v: 1 }));
    }

    /// Twelve counter-clockwise triangles around one vertex that wind
    /// twice around it (a spiral rim, so no two vertices meet): every
    /// local check holds, and only the border's winding shows the overlap.
    #[test]
    fn a_fan_that_goes_around_twice_is_caught() {
        let n = 6;
        let mut pts = vec![(0.0, 0.0)];
        for k in 0..2 * n {
            let (r, a) = (10.0 + 0.1 * f64::from(k), std::f64::consts::TAU * f64::from(k) / f64::from(n));
            pts.push((r * a.cos(), r * a.sin()));
        }
        let tris: Vec<[u32; 3]> = (0..2 * n).map(|k| [0, 1 + k, 1 + (k + 1) % (2 * n)]).collect();
        assert_eq!(soup(&pts, &tris).sanity_check(), Err(Broken::BorderWinding { turns: 2 }));
    }
}
