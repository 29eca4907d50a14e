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
    /// Triangles, counter-clockwise seen from above (+y).
    pub indices: Vec<u32>,
}

impl Part {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
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
