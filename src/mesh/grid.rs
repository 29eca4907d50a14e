//! The height grid every stage reads ([`Grid`]), and a chunk's compact copy
//! of it ([`Window`]).

use crate::quadtree::Span;
use crate::store::Memory;

/// Steps (splits, vertices, or rows of a scan) between looks at the memory
/// limit in a chunk at least [`RELIEF_SIDE`] cells wide: a coarse chunk of
/// a large grid touches pages all over its square (each fault maps the
/// pages around it too) faster than the limit's governor thread wakes.
pub const RELIEF_STEPS: u32 = 512;

/// The narrowest chunk, cells, whose passes look at the memory limit
/// themselves; a narrower one touches too few rows to outrun the governor.
pub const RELIEF_SIDE: u32 = 2048;

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
    /// Largest minus smallest valid height of the whole grid, metres: the
    /// f32 margin of the border lines, which neighbours must agree on.
    pub relief_m: f64,
    /// Some sample is nodata.
    pub has_nodata: bool,
    /// The memory limit the arrays above live under, if any: code that
    /// touches many of their pages quickly gives some back as it goes.
    pub memory: Option<&'a Memory>,
}

impl<'a> Grid<'a> {
    /// A grid over `heights` (row-major, NaN = nodata), with its relief.
    pub fn new(width: usize, height: usize, heights: &'a [f32], filled: Option<&'a [f32]>) -> Self {
        let (lo, hi, valid) = heights
            .iter()
            .filter(|h| !h.is_nan())
            .fold((f32::INFINITY, f32::NEG_INFINITY, 0usize), |(lo, hi, n), &h| (lo.min(h), hi.max(h), n + 1));
        let relief_m = if hi >= lo { f64::from(hi) - f64::from(lo) } else { 0.0 };
        let has_nodata = valid < heights.len();
        Grid { width, height, heights, filled, relief_m, has_nodata, memory: None }
    }

    /// The same grid, its pages given back under `memory` by
    /// [`Grid::relieve`].
    pub fn governed(self, memory: Option<&'a Memory>) -> Self {
        Grid { memory, ..self }
    }
}

impl Grid<'_> {
    /// Gives mapped pages back where the process holds more than its
    /// share of the memory limit. Passes that touch pages faster than the
    /// limit's governor thread wakes (a coarse chunk spans gigabytes of a
    /// large grid) call it every few thousand steps.
    #[inline]
    pub fn relieve(&self) {
        if let Some(m) = self.memory {
            m.relieve();
        }
    }

    /// [`Grid::relieve`] at every [`RELIEF_STEPS`]th `step` of a pass over
    /// a chunk `side` cells wide, if it is at least [`RELIEF_SIDE`] wide.
    #[inline]
    pub fn relieve_every(&self, side: u32, step: u32) {
        if side >= RELIEF_SIDE && step.is_multiple_of(RELIEF_STEPS) {
            self.relieve();
        }
    }

    #[inline]
    pub(crate) fn sample(&self, i: usize, j: usize) -> f32 {
        self.heights[i * self.width + j]
    }

    /// Height a vertex at sample (i, j) takes: the sample, or the fill.
    #[inline]
    pub(crate) fn vertex_height(&self, i: usize, j: usize) -> f64 {
        let h = self.sample(i, j);
        if h.is_nan() { self.filled.map_or(0.0, |f| f64::from(f[i * self.width + j])) } else { f64::from(h) }
    }
}

/// A chunk's footprint copied out of the grid into rows of its own: scanning
/// a window of a large grid strides a page or more per row, a compact copy
/// stays in cache. Indexed by grid (row, column), like [`Grid`].
pub(super) struct Window<'a> {
    pub(super) grid: &'a Grid<'a>,
    pub(super) x0: usize,
    pub(super) z0: usize,
    pub(super) width: usize,
    pub(super) heights: Vec<f32>,
}

impl<'a> Window<'a> {
    /// The last column and row the window holds (inclusive).
    pub(crate) fn last(&self) -> (usize, usize) {
        (self.x0 + self.width - 1, self.z0 + self.heights.len() / self.width - 1)
    }

    pub(crate) fn new(grid: &'a Grid<'a>, footprint: (Span, Span)) -> Self {
        let ((x0, x1), (z0, z1)) = footprint;
        let (x0, x1, z0, z1) = (x0 as usize, x1 as usize, z0 as usize, z1 as usize);
        let mut heights = Vec::with_capacity((x1 - x0 + 1) * (z1 - z0 + 1));
        for i in z0..=z1 {
            heights.extend_from_slice(&grid.heights[i * grid.width + x0..=i * grid.width + x1]);
        }
        Window { grid, x0, z0, width: x1 - x0 + 1, heights }
    }

    #[inline]
    pub(crate) fn sample(&self, i: usize, j: usize) -> f32 {
        self.heights[(i - self.z0) * self.width + (j - self.x0)]
    }

    /// Height a vertex at sample (i, j) takes: the sample, or the fill.
    #[inline]
    pub(crate) fn vertex_height(&self, i: usize, j: usize) -> f64 {
        let h = self.sample(i, j);
        if h.is_nan() { self.grid.vertex_height(i, j) } else { f64::from(h) }
    }

    /// Row `i` from column `x0` on.
    #[inline]
    pub(crate) fn row(&self, i: usize) -> &[f32] {
        &self.heights[(i - self.z0) * self.width..(i - self.z0 + 1) * self.width]
    }
}
