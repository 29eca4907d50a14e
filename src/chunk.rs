//! The plain data one chunk carries from the mesher to the writer.

use crate::quadtree::{ChunkKey, Span};

/// One drawable part of a chunk (the surface, or its skirts).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Part {
    /// World positions in metres: x east, y up, z south (DESIGN.md).
    pub positions: Vec<[f64; 3]>,
    /// Unit normals from the DEM.
    pub normals: Vec<[f32; 3]>,
    /// Morph target: y offset that puts each vertex on the parent surface.
    pub morph_dy: Vec<f64>,
    /// The x and z of each morph offset, in the curved frame only (empty:
    /// 0, the flat frame's vertical deltas).
    pub morph_dxz: Vec<[f64; 2]>,
    /// Where on the grid each vertex is, metres (column · s_x, row · s_z),
    /// in the curved frame only (empty: the positions' own x and z).
    pub plan_m: Vec<[f64; 2]>,
    /// The grid's x axis at each vertex, in the curved frame with a normal
    /// map only, whose `normals` are then the ground's up there (empty: x
    /// and y, the flat frame's axes).
    pub tangents: Vec<[f32; 3]>,
    /// Triangles, counter-clockwise seen from above (+y).
    pub indices: Vec<u32>,
}

impl Part {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Where on the grid vertex `k` is, metres: x east, z south.
    pub fn plan(&self, k: usize) -> [f64; 2] {
        match self.plan_m.get(k) {
            Some(&p) => p,
            None => [self.positions[k][0], self.positions[k][2]],
        }
    }

    /// The morph offset of vertex `k`, metres.
    pub fn morph(&self, k: usize) -> [f64; 3] {
        let [dx, dz] = self.morph_dxz.get(k).copied().unwrap_or([0.0; 2]);
        [dx, self.morph_dy[k], dz]
    }

    /// The vertices of `self` in `order` (indices into it), each field
    /// gathered at its final size; `indices` as given.
    pub fn gather(&self, order: &[usize], indices: Vec<u32>) -> Part {
        fn pick<T: Copy>(v: &[T], order: &[usize]) -> Vec<T> {
            if v.is_empty() { Vec::new() } else { order.iter().map(|&k| v[k]).collect() }
        }
        Part {
            positions: pick(&self.positions, order),
            normals: pick(&self.normals, order),
            morph_dy: pick(&self.morph_dy, order),
            morph_dxz: pick(&self.morph_dxz, order),
            plan_m: pick(&self.plan_m, order),
            tangents: pick(&self.tangents, order),
            indices,
        }
    }

    /// Appends vertex `k` of `from` (position, normal and morph, and the
    /// curved frame's fields where `from` has them).
    pub fn push_from(&mut self, from: &Part, k: usize) {
        self.positions.push(from.positions[k]);
        self.normals.push(from.normals[k]);
        self.morph_dy.push(from.morph_dy[k]);
        if !from.morph_dxz.is_empty() {
            self.morph_dxz.push(from.morph_dxz[k]);
        }
        if !from.plan_m.is_empty() {
            self.plan_m.push(from.plan_m[k]);
        }
        if !from.tangents.is_empty() {
            self.tangents.push(from.tangents[k]);
        }
    }
}

/// A finished chunk, ready to be written.
#[derive(Clone, Debug)]
pub struct Chunk {
    /// Level and position in the tree.
    pub key: ChunkKey,
    /// Footprint in samples, closed.
    pub footprint: (Span, Span),
    /// δ(L) in metres.
    pub delta_m: f64,
    /// Largest error the mesher measured over the footprint, metres.
    pub max_error_m: f64,
    /// The terrain surface.
    pub surface: Part,
    /// Its vertices' grid coordinates (column, row), exact: a cut point's
    /// place on its dividing line, which the metres of `positions` round.
    pub surface_grid: Vec<(f64, f64)>,
    /// Vertical strips under the borders (may be empty).
    pub skirt: Part,
}
