//! Mesh: per chunk, a TIN within δ(L) of every valid sample, nested in its
//! parent's ([`decimate`]); then skirts on its borders ([`skirt`]). Both
//! are re-measured independently, from the written files, by
//! [`crate::verify`].

pub mod decimate;
pub mod grid;
pub mod locate;
pub mod quality;
pub mod rtin;
pub mod skirt;
pub mod tin;

use crate::quadtree::{ChunkKey, Span};

/// A vertex of a chunk's TIN, in grid coordinates (column `x`, row `z`; may
/// be fractional where a dividing line crossed a parent edge) and metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshVertex {
    /// Column coordinate (east), in samples.
    pub x: f64,
    /// Row coordinate (south), in samples.
    pub z: f64,
    /// Height in metres (the DEM sample at sample positions).
    pub h: f64,
    /// Height of the parent chunk's surface at (x, z), metres (= `h` at the
    /// top level); the morph target is `ph − h`.
    pub ph: f64,
}

/// One chunk's surface as the mesher leaves it: every triangle of the
/// footprint's triangulation (the children refine all of them), with a flag
/// saying which ones are written (those that cover at least one valid sample).
#[derive(Clone, Debug)]
pub struct ChunkMesh {
    /// Which chunk.
    pub key: ChunkKey,
    /// Footprint in samples, closed: `((x0, x1), (z0, z1))`.
    pub footprint: (Span, Span),
    /// δ(L) this mesh was built to, metres.
    pub delta_m: f64,
    /// Vertices.
    pub vertices: Vec<MeshVertex>,
    /// Counter-clockwise (in x-east, z-south grid space) triangles.
    pub triangles: Vec<[u32; 3]>,
    /// `kept[t]`: triangle `t` covers a valid sample and is written.
    pub kept: Vec<bool>,
    /// Largest |surface − sample| over the footprint's valid samples, metres.
    pub max_error_m: f64,
    /// The same over the triangles with a cut point for a corner, which are
    /// held to a tighter target ([`decimate::Targets`]).
    pub max_error_near_cuts_m: f64,
    /// Largest minus smallest valid height in the footprint, metres.
    pub relief_m: f64,
    /// Per triangle, what its last scan found (`None`: not known to hold):
    /// a child that starts from an uncut triangle takes it instead of
    /// scanning the triangle again.
    pub scans: Vec<Option<decimate::TriangleScan>>,
    /// The bucket grid of [`ChunkMesh::locator`], built on first use and
    /// then shared (the four children's void checks each ask for one).
    pub locator_index: std::sync::OnceLock<crate::mesh::locate::LocatorIndex>,
    /// In the curved frame, each vertex's morph target as a world point:
    /// the parent's written (chord) surface there (empty in the flat frame).
    pub parent_points: Vec<ParentPoint>,
}

/// A curved-frame vertex's morph target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParentPoint {
    /// The parent's written surface at the vertex, world metres.
    pub at: [f64; 3],
    /// The parent has this vertex too: `at` is the vertex's own world
    /// position, worked out once for both.
    pub shared: bool,
}

impl ChunkMesh {
    /// Finds the triangle under a point, over every triangle (written or
    /// not); its bucket grid is built once per mesh.
    pub fn locator(&self) -> crate::mesh::locate::SurfaceLocator<'_> {
        let index =
            self.locator_index.get_or_init(|| crate::mesh::locate::LocatorIndex::new(&self.vertices, &self.triangles));
        crate::mesh::locate::SurfaceLocator::with_index(&self.vertices, &self.triangles, index)
    }

    /// Whether this mesh already meets `delta_m` with room for f32 output.
    pub fn meets(&self, delta_m: f64) -> bool {
        let t = decimate::Targets::new(delta_m, self.relief_m);
        self.max_error_m <= t.exact && self.max_error_near_cuts_m <= t.cut
    }
}

/// Orders a line's vertices, sorted by position along it, so that each is
/// joined to the next where `joined` says they can be: vertices at one point
/// (cut points closer together than the quantize grid, placed on it) come
/// in the order of the chain of edges through them, not of their indices.
pub fn chain_ties(on: &mut [(f64, u32)], joined: impl Fn(u32, u32) -> bool) {
    for k in 1..on.len() {
        if joined(on[k - 1].1, on[k].1) {
            continue;
        }
        // Another vertex at this point, or at the last one, that is joined.
        let at = [on[k - 1].0, on[k].0];
        if let Some(j) =
            (k + 1..on.len()).take_while(|&j| at.contains(&on[j].0)).find(|&j| joined(on[k - 1].1, on[j].1))
        {
            on.swap(k, j);
        }
    }
}

/// Unit normal of the DEM at grid point (x, z), from central differences of
/// the nearest sample (one-sided at edges and next to nodata).
pub fn dem_normal(grid: &grid::Grid, spacing_m: [f64; 2], x: f64, z: f64) -> [f32; 3] {
    let j = (x.round().max(0.0) as usize).min(grid.width - 1);
    let i = (z.round().max(0.0) as usize).min(grid.height - 1);
    let at = |i: usize, j: usize| {
        let h = grid.heights[i * grid.width + j];
        (!h.is_nan()).then_some(f64::from(h))
    };
    let slope = |lo: Option<f64>, mid: Option<f64>, hi: Option<f64>, step: f64| match (lo, mid, hi) {
        (Some(a), _, Some(b)) => (b - a) / (2.0 * step),
        (Some(a), Some(m), None) => (m - a) / step,
        (None, Some(m), Some(b)) => (b - m) / step,
        _ => 0.0,
    };
    let mid = at(i, j);
    let dx = slope(
        j.checked_sub(1).and_then(|j| at(i, j)),
        mid,
        (j + 1 < grid.width).then(|| at(i, j + 1)).flatten(),
        spacing_m[0],
    );
    let dz = slope(
        i.checked_sub(1).and_then(|i| at(i, j)),
        mid,
        (i + 1 < grid.height).then(|| at(i + 1, j)).flatten(),
        spacing_m[1],
    );
    let n = [-dx, 1.0, -dz];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    n.map(|c| (c / len) as f32)
}

/// What can stop the mesher.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// A chunk needs more vertices than `max_chunk_vertices` allows to meet its δ.
    #[error("chunk {level}/{x}/{y} needs more than {limit} vertices to stay within {delta_m} m")]
    TooDense {
        /// Level.
        level: u32,
        /// Column.
        x: u32,
        /// Row.
        y: u32,
        /// δ it had to meet.
        delta_m: f64,
        /// The vertex limit.
        limit: usize,
    },
    /// Stopped because another chunk of the same build failed.
    #[error("stopped: another chunk failed")]
    Cancelled,
}
