//! What the greedy mesher meshes each triangle to ([`Targets`]): δ where
//! every corner is written exactly, less a margin next to cut points.

use super::*;

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
    pub(super) fn over(&self, corners: &[V]) -> f64 {
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
    pub(super) fn off(&self, c: f64) -> bool {
        off_lattice(c, self.lattice)
    }

    /// Whether any of these corners is (a cut point the file rounds).
    pub(super) fn rounds(&self, corners: &[V]) -> bool {
        corners.iter().any(|v| self.off(v.x) || self.off(v.z))
    }
}

/// How far a height moves when the file rounds it to a multiple of `step`
/// (0: f32 output, which writes sample heights exactly).
pub(super) fn rounds_by(h: f64, step: f64) -> f64 {
    if step == 0.0 { 0.0 } else { (h - (h / step).round() * step).abs() }
}

/// Whether `c` (any finite coordinate) is a whole number.
pub(super) fn whole_f(c: f64) -> bool {
    c == c.round()
}

/// Whether grid coordinate `c` is off the grid of `lattice` steps per cell.
#[inline]
pub(super) fn off_lattice(c: f64, lattice: f64) -> bool {
    if lattice == 1.0 {
        return !whole(c);
    }
    let y = c * lattice;
    (y as i64) as f64 != y
}

/// Whether a corner is off the sample grid (a cut point).
pub(super) fn is_cut(corners: &[V]) -> bool {
    corners.iter().any(|v| !whole(v.x) || !whole(v.z))
}

/// Whether a grid coordinate (≥ 0, far below 2³²) is a whole sample index;
/// `fract` is a libm call on x86-64 without SSE4.1, and this runs per scan.
#[inline]
pub(super) fn whole(c: f64) -> bool {
    f64::from(c as u32) == c
}

/// Largest minus smallest valid height in a footprint (0 if none), and the
/// largest |height|.
pub(super) fn footprint_relief(grid: &Window, footprint: (Span, Span)) -> (f64, f64) {
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
