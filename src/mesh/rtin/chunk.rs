//! One chunk's descent through the bintree at its level's δ: its
//! triangles, vertices and each vertex's parent surface.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::atomic::{AtomicBool, Ordering};

use super::field::{Rtin, scan_triangle, vertex_height};
use super::plan::square_side;
use super::tri::{P, Place, Tri, square_triangles};
use crate::geodesy::Globe;
use crate::mesh::grid::Grid;
use crate::mesh::{ChunkMesh, MeshError, MeshVertex, ParentPoint};
use crate::quadtree::{ChunkKey, ChunkTree};

/// Hashes grid places for a chunk's vertex index: a multiply per word, as
/// places are few and not chosen by anyone hostile.
#[derive(Default)]
pub(super) struct PointHasher(u64);

impl Hasher for PointHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u32(u32::from(b));
        }
    }

    fn write_u32(&mut self, i: u32) {
        self.0 = (self.0.rotate_left(5) ^ u64::from(i)).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

impl Rtin {
    /// Meshes chunk `key` of `tree` at its level's δ: the bintree's
    /// triangles inside its square, with each vertex's parent-surface height.
    /// `max_vertices`: more makes [`MeshError::TooDense`]; `cancel`: set
    /// when another chunk failed. With a `globe` (the curved frame, and the
    /// grid's spacing in metres) a
    /// triangle is also split where its chord's sag ([`Globe::margin_m`])
    /// would take it past δ, and each vertex gets its parent-surface point.
    pub fn build_chunk(
        &self,
        grid: &Grid,
        tree: &ChunkTree,
        key: ChunkKey,
        max_vertices: usize,
        cancel: Option<&AtomicBool>,
        globe: Option<(&Globe, [f64; 2])>,
    ) -> Result<ChunkMesh, MeshError> {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            return Err(MeshError::Cancelled);
        }
        let level = key.level as usize;
        let footprint = tree.footprint(key);
        let delta_m = tree.delta_m[level];
        let side = square_side(tree, key.level);
        let ((x0, _), (z0, _)) = footprint;
        // Descend from the parent's square (its corners are parent vertices,
        // so their parent-surface height is their own), or the chunk's own.
        let (from, parent) = match level {
            0 => ((x0, z0, side), None),
            _ => {
                let ps = square_side(tree, key.level - 1);
                (((x0 / ps) * ps, (z0 / ps) * ps, ps), Some((ps, tree.delta_m[level - 1])))
            }
        };
        let mut m = Mesher {
            rtin: self,
            grid,
            side,
            square: (x0, z0),
            delta_m,
            parent,
            index: VertexIndex::over(side),
            vertices: Vec::new(),
            triangles: Vec::new(),
            bounds: Vec::new(),
            globe,
            parent_points: Vec::new(),
            curved_error_m: 0.0,
            splits: 0,
        };
        for (t, ph) in square_triangles(from.0, from.1, from.2) {
            match globe {
                None => {
                    let ph = ph.map(|p| vertex_height(grid, p));
                    m.descend(t, [&ph[0], &ph[1], &ph[2]]);
                }
                Some(_) => {
                    let ph = ph.map(|p| OnGlobe::own(globe, p, vertex_height(grid, p)));
                    m.descend(t, [&ph[0], &ph[1], &ph[2]]);
                }
            }
        }
        if m.vertices.len() > max_vertices {
            return Err(MeshError::TooDense { level: key.level, x: key.x, y: key.y, delta_m, limit: max_vertices });
        }
        let Mesher { vertices, triangles, bounds, parent_points, curved_error_m, .. } = m;
        // A triangle with a valid corner covers a valid sample; one with
        // none is scanned to see. The largest error is measured by scanning
        // in falling order of each triangle's stored bound (the error at
        // its split point, 0 where it has none: it covers its corners
        // alone) until no bound is above what was found.
        let mut kept = vec![true; triangles.len()];
        let mut max_error_m: f64 = 0.0;
        // Bounds in a heap (only the few largest are ever taken), as f32
        // bits, which order as the values do from +0 up, with NaN first.
        let order = |b: f32| {
            if b.is_nan() {
                u32::MAX
            } else if b > 0.0 {
                b.to_bits()
            } else {
                0
            }
        };
        let mut heap: Vec<(u32, std::cmp::Reverse<usize>)> = Vec::with_capacity(triangles.len());
        for (k, (t, &bound)) in triangles.iter().zip(&bounds).enumerate() {
            if grid.has_nodata {
                let corners = t.map(|v| vertices[v as usize]);
                let at = |v: &MeshVertex| grid.heights[v.z as usize * grid.width + v.x as usize];
                if corners.iter().all(|v| at(v).is_nan()) {
                    let scan = scan_triangle(grid, &corners);
                    kept[k] = scan.valid;
                    max_error_m = max_error_m.max(scan.error);
                    continue;
                }
            }
            // A bound of 0 is never above what is found.
            if order(bound) > 0 {
                heap.push((order(bound), std::cmp::Reverse(k)));
            }
        }
        let mut heap = std::collections::BinaryHeap::from(heap);
        while let Some((bound, std::cmp::Reverse(k))) = heap.pop() {
            if f64::from(f32::from_bits(bound)) <= max_error_m {
                break;
            }
            let corners = triangles[k].map(|v| vertices[v as usize]);
            max_error_m = max_error_m.max(scan_triangle(grid, &corners).error);
        }
        // The chunk is final only where its sag is inside the leaves' δ too.
        max_error_m = max_error_m.max(curved_error_m.min(delta_m));
        let n = triangles.len();
        Ok(ChunkMesh {
            key,
            footprint,
            delta_m,
            vertices,
            triangles,
            kept,
            max_error_m,
            max_error_near_cuts_m: 0.0,
            // Only cut points' targets read it, and the bintree has none.
            relief_m: 0.0,
            scans: vec![None; n],
            locator_index: std::sync::OnceLock::new(),
            parent_points,
        })
    }
}

/// One chunk's descent through the bintree.
pub(super) struct Mesher<'a> {
    rtin: &'a Rtin,
    grid: &'a Grid<'a>,
    /// The chunk's square: side and north-west corner.
    side: u32,
    square: P,
    delta_m: f64,
    /// The parent level's square side and δ (None at the top).
    parent: Option<(u32, f64)>,
    index: VertexIndex,
    vertices: Vec<MeshVertex>,
    triangles: Vec<[u32; 3]>,
    /// Per triangle, the field's error at its split point (0 where it has
    /// none): a bound on its own error, read as the descent kept it.
    bounds: Vec<f32>,
    /// The curved frame and the grid spacing (metres), if it is written in it.
    globe: Option<(&'a Globe, [f64; 2])>,
    /// Per vertex, its parent-surface point (the curved frame only).
    parent_points: Vec<ParentPoint>,
    /// The largest error bound plus sag of a written triangle (the curved
    /// frame only).
    curved_error_m: f64,
    /// Triangles split so far: every few thousand the grid's memory limit
    /// is looked at ([`Grid::relieve`]).
    splits: u32,
}

/// What the descent carries to each corner: the parent surface there, as
/// a height (the flat frame) or also as a world point (the curved one).
pub(super) trait ParentSurface: Copy {
    /// A vertex the parent has too: its own height `h` at `p`.
    fn own(globe: Option<(&Globe, [f64; 2])>, p: P, h: f64) -> Self;
    /// The middle of a parent edge: the parent's surface is linear along it.
    fn middle(a: Self, b: Self) -> Self;
    fn height(&self) -> f64;
    fn point(&self) -> Option<ParentPoint>;
}

impl ParentSurface for f64 {
    #[inline]
    fn own(_: Option<(&Globe, [f64; 2])>, _: P, h: f64) -> f64 {
        h
    }
    #[inline]
    fn middle(a: f64, b: f64) -> f64 {
        (a + b) / 2.0
    }
    #[inline]
    fn height(&self) -> f64 {
        *self
    }
    #[inline]
    fn point(&self) -> Option<ParentPoint> {
        None
    }
}

/// The parent surface in the curved frame: its chord triangles are linear
/// between their corners' world points, so the middle of an edge is the
/// middle of its ends' points.
#[derive(Clone, Copy)]
pub(super) struct OnGlobe {
    h: f64,
    p: [f64; 3],
    /// A vertex of the parent (not the middle of its edge).
    shared: bool,
}

impl ParentSurface for OnGlobe {
    fn own(globe: Option<(&Globe, [f64; 2])>, p: P, h: f64) -> OnGlobe {
        let (g, _) = globe.expect("the curved frame carries its globe");
        OnGlobe { h, p: g.world_at_sample(p.0, p.1, h), shared: true }
    }
    fn middle(a: OnGlobe, b: OnGlobe) -> OnGlobe {
        OnGlobe { h: (a.h + b.h) / 2.0, p: [0, 1, 2].map(|k| (a.p[k] + b.p[k]) / 2.0), shared: false }
    }
    fn height(&self) -> f64 {
        self.h
    }
    fn point(&self) -> Option<ParentPoint> {
        Some(ParentPoint { at: self.p, shared: self.shared })
    }
}

impl Mesher<'_> {
    /// `ph`: the parent surface at `t`'s corners a, b, r (borrowed from the
    /// frames above: a curved-frame point is 40 bytes, copied at every split
    /// otherwise).
    fn descend<S: ParentSurface>(&mut self, t: Tri, ph: [&S; 3]) {
        let (x0, x1, z0, z1) = t.bbox();
        let (sx, sz, c) = (self.square.0, self.square.1, self.side);
        // Only what reaches into the chunk's square.
        if x1 <= sx || x0 >= sx + c || z1 <= sz || z0 >= sz + c {
            return;
        }
        let place = self.rtin.place(&t);
        if place == Place::Outside {
            return;
        }
        let coarser = |side: u32| t.hyp2() > 2 * u64::from(side) * u64::from(side);
        let split = if coarser(c) { t.midpoint() } else { self.splits(&t, place, self.delta_m, c) };
        let Some(m) = split else {
            debug_assert_eq!(place, Place::Inside, "a triangle past the grid always splits");
            self.emit(t, ph);
            return;
        };
        // The parent's surface at m: m itself where the parent splits here
        // too, else the middle of the hypotenuse it lies on.
        let pm = match self.parent {
            None => S::own(self.globe, m, vertex_height(self.grid, m)),
            Some((ps, pd)) => {
                if coarser(ps) || self.splits(&t, place, pd, ps).is_some() {
                    S::own(self.globe, m, vertex_height(self.grid, m))
                } else {
                    S::middle(*ph[0], *ph[1])
                }
            }
        };
        self.splits += 1;
        self.grid.relieve_every(self.side, self.splits);
        let [k0, k1] = t.children(m);
        self.descend(k0, [ph[2], ph[0], &pm]);
        self.descend(k1, [ph[1], ph[2], &pm]);
    }

    /// Whether the mesh at `delta` (a level of squares of `side` cells)
    /// splits `t`. In the curved frame the field's errors hold each
    /// triangle's sag, and δ is lessened by what f32 rounds positions by in
    /// a chunk of that size: one threshold per level, so the meshes conform
    /// and nest as they do flat.
    #[inline]
    fn splits(&self, t: &Tri, place: Place, delta: f64, side: u32) -> Option<P> {
        self.rtin.splits(t, place, delta - self.rounding(side))
    }

    /// How far f32 may round chunk-local positions in a chunk of `side`
    /// cells, metres (0 in the flat frame, where samples are written exactly).
    #[inline]
    fn rounding(&self, side: u32) -> f64 {
        self.globe.map_or(0.0, |(_, s)| 4.0 * f64::from(f32::EPSILON) * f64::from(side) * s[0].max(s[1]))
    }

    fn emit<S: ParentSurface>(&mut self, t: Tri, ph: [&S; 3]) {
        // In the curved frame a triangle's error bound holds its sag too,
        // which decides whether the chunk needs children.
        let bound = match t.midpoint() {
            Some(m) => {
                let bound = self.rtin.error_at(m.0, m.1);
                if self.globe.is_some() {
                    self.curved_error_m = self.curved_error_m.max(f64::from(bound) + self.rounding(self.side));
                }
                bound
            }
            None => 0.0,
        };
        self.bounds.push(bound);
        let mut v = [(t.a, ph[0]), (t.b, ph[1]), (t.r, ph[2])].map(|(p, ph)| self.vertex(p, ph));
        // Counter-clockwise seen from above (y up), as the TIN's are stored:
        // clockwise in x-east, z-south grid space.
        let [a, b, c] = [t.a, t.b, t.r].map(|p| (i64::from(p.0), i64::from(p.1)));
        if (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0) > 0 {
            v.swap(1, 2);
        }
        self.triangles.push(v);
    }

    fn vertex<S: ParentSurface>(&mut self, p: P, ph: &S) -> u32 {
        let local = (p.0 - self.square.0, p.1 - self.square.1);
        let next = self.vertices.len() as u32;
        let v = self.index.entry(local, next);
        if v == next {
            let h = vertex_height(self.grid, p);
            self.vertices.push(MeshVertex { x: f64::from(p.0), z: f64::from(p.1), h, ph: ph.height() });
            if let Some(point) = ph.point() {
                self.parent_points.push(point);
            }
        }
        v
    }
}

/// A chunk's vertex numbers by position within its square: a table for the
/// common small squares, a hash map for the few large ones.
pub(super) enum VertexIndex {
    Table { row: usize, slots: Vec<u32> },
    Map(HashMap<P, u32, BuildHasherDefault<PointHasher>>),
}

impl VertexIndex {
    /// Squares up to this side get a table ((side + 1)² slots).
    const TABLE_SIDE: u32 = 256;

    fn over(side: u32) -> Self {
        if side <= Self::TABLE_SIDE {
            let row = side as usize + 1;
            VertexIndex::Table { row, slots: vec![u32::MAX; row * row] }
        } else {
            VertexIndex::Map(HashMap::default())
        }
    }

    /// The number of the vertex at `local` (offset from the square's
    /// corner), given `next` if it has none yet.
    #[inline]
    fn entry(&mut self, local: P, next: u32) -> u32 {
        match self {
            VertexIndex::Table { row, slots } => {
                let slot = &mut slots[local.1 as usize * *row + local.0 as usize];
                if *slot == u32::MAX {
                    *slot = next;
                }
                *slot
            }
            VertexIndex::Map(map) => *map.entry(local).or_insert(next),
        }
    }
}
