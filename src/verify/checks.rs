//! One chunk against the DEM and its own contract: the error bound and
//! coverage, triangles over nodata or turned over, finite positions and
//! morph deltas, normals that are finite, unit and on the side the
//! triangles face. Each check takes the chunk as read and pushes what it
//! finds; another per-chunk check (the triangles' shape, say) is one more
//! such function, called from `Walk::check` beside these.

use super::read::ChunkFile;
use crate::heightfield::Heightfield;
use crate::mesh::MeshVertex;
use crate::mesh::locate::points_near_triangle;

/// Whether every position and morph delta of `c` is finite.
pub(super) fn finite(c: &ChunkFile) -> bool {
    std::iter::once(&c.surface)
        .chain(c.skirt.as_ref())
        .all(|p| p.positions.iter().flatten().all(|v| v.is_finite()) && p.morph_dy.iter().all(|d| d.is_finite()))
}

/// What in `c` is not finite, per primitive.
pub(super) fn not_finite(c: &ChunkFile) -> Vec<String> {
    let mut out = Vec::new();
    for (role, p) in std::iter::once(("surface", &c.surface)).chain(c.skirt.as_ref().map(|s| ("skirt", s))) {
        let positions = p.positions.iter().filter(|q| !q.iter().all(|v| v.is_finite())).count();
        let deltas = p.morph_dy.iter().filter(|d| !d.is_finite()).count();
        if positions > 0 {
            out.push(format!("{role}: {positions} positions are not finite (NaN or infinite)"));
        }
        if deltas > 0 {
            out.push(format!("{role}: {deltas} morph deltas are not finite (NaN or infinite)"));
        }
    }
    out
}

/// Normals: every primitive has one per vertex, finite and of unit length
/// (within the rounding of its encoding: an i8 component rounds by half of
/// 1/127), pointing up within that rounding (an i8 normal of a cliff
/// rounds to y = 0). Every written triangle faces up (a heightfield
/// seen from above; `turned_over` finds the ones that do not), so a normal
/// that agrees with the triangles it belongs to has a positive y; skirt
/// vertices carry their top vertex's normal. With a normal map, every
/// normal is the up itself, within the same rounding.
///
/// `ups`, given for the curved frame, are the ellipsoid's up at each
/// surface and skirt vertex, in the chunk's axes: there a heightfield faces
/// away from the Earth, which is the chunk's y only near its middle (a
/// chunk more than a hemisphere wide holds vertices whose up points below
/// its horizon).
pub(super) fn normals(c: &ChunkFile, ups: Option<&[Vec<[f64; 3]>; 2]>, problems: &mut Vec<String>) {
    let tolerance = if c.quantization_m.is_some() { 0.02 } else { 1e-3 };
    // A normal map's normals are given against the ground's up: every
    // vertex normal must be that up.
    let mapped = c.texture.as_ref().is_some_and(|t| t.normal.is_some());
    let prims = std::iter::once(("surface", &c.surface)).chain(c.skirt.as_ref().map(|s| ("skirt", s)));
    for (k, (role, p)) in prims.enumerate() {
        if p.normals.len() != p.positions.len() {
            problems.push(format!("{role}: {} normals for {} vertices", p.normals.len(), p.positions.len()));
            continue;
        }
        let (mut bad, mut down, mut tilted) = (0, 0, 0);
        for (v, n) in p.normals.iter().enumerate() {
            let len = n.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
            let upward = match ups {
                None => f64::from(n[1]),
                Some(ups) => ups[k][v].iter().zip(n).map(|(u, c)| u * f64::from(*c)).sum(),
            };
            if !(len - 1.0).abs().le(&tolerance) {
                bad += 1;
            } else if upward < -tolerance {
                down += 1;
            } else if mapped && upward < 1.0 - tolerance {
                tilted += 1;
            }
        }
        if tilted > 0 {
            problems.push(format!("{role}: {tilted} normals are not the ground's up, the normal map's tangent frame"));
        }
        if bad > 0 {
            problems.push(format!("{role}: {bad} normals are not finite unit vectors"));
        }
        if down > 0 {
            problems.push(format!("{role}: {down} normals point down, against the triangles they belong to"));
        }
    }
}

/// Largest |surface − sample| over the footprint; records uncovered samples
/// and vertices outside the footprint.
pub(super) fn check_error(hf: &Heightfield, c: &ChunkFile, spacing: [f64; 2], problems: &mut Vec<String>) -> f64 {
    let [x0, x1, z0, z1] = c.footprint;
    if x1 as usize >= hf.width || z1 as usize >= hf.height || x0 >= x1 || z0 >= z1 {
        problems.push(format!("footprint {:?} is outside the {}×{} grid", c.footprint, hf.width, hf.height));
        return f64::INFINITY;
    }
    let verts = c.surface.grid_vertices(spacing);
    let tol = 1e-4 * ((x1 - x0) + (z1 - z0)) as f64;
    if verts.iter().any(|v| {
        v.x < f64::from(x0) - tol || v.x > f64::from(x1) + tol || v.z < f64::from(z0) - tol || v.z > f64::from(z1) + tol
    }) {
        problems.push("a surface vertex lies outside the footprint".into());
    }
    // Each sample's error is taken from the triangle that fits it best: on a
    // shared edge all agree, and a zero-width sliver's neighbour must not
    // count a vertex it merely touches (within f32 rounding) against it.
    let w = (x1 - x0 + 1) as usize;
    let mut best = vec![f64::INFINITY; w * (z1 - z0 + 1) as usize];
    let (mut over_nodata, mut turned) = (0, 0);
    for t in &c.surface.triangles {
        let tri = t.map(|i| verts[i as usize]);
        turned += usize::from(turned_over(&tri));
        let alone = scan_written(hf, &tri, c.footprint, |i, j, e| {
            let best = &mut best[(i - z0 as usize) * w + (j - x0 as usize)];
            *best = best.min(e);
        });
        over_nodata += usize::from(alone);
    }
    if over_nodata > 0 {
        problems.push(format!("{over_nodata} triangles stand over nodata alone"));
    }
    if turned > 0 {
        problems.push(format!("{turned} triangles are turned over (wound against the rest in plan)"));
    }
    let covered: Vec<bool> = best.iter().map(|e| e.is_finite()).collect();
    let max_err = best.iter().copied().filter(|e| e.is_finite()).fold(0.0, f64::max);
    let mut uncovered = 0;
    for i in z0..=z1 {
        for j in x0..=x1 {
            if !hf.get(i as usize, j as usize).is_nan() && !covered[(i - z0) as usize * w + (j - x0) as usize] {
                uncovered += 1;
            }
        }
    }
    if uncovered > 0 {
        problems.push(format!("{uncovered} valid samples are not covered by any triangle"));
    }
    let max_err = snap_error(c, max_err, c.delta_m);
    if max_err > c.delta_m {
        problems.push(format!("error {max_err:.4} m exceeds δ {} m", c.delta_m));
    }
    max_err
}

/// Scans triangle `tri` (grid units, as read back) over the samples of
/// `footprint`: calls `valid(i, j, error)` for each valid sample within f32
/// rounding (10⁻⁴ grid units) of it, and says whether it stands over
/// nodata alone: no valid sample that near, and a nodata sample inside it
/// by more than that. A nodata sample only that near its edge is no more
/// covered by it than by the triangle across the edge (Seamount at 1 m,
/// 32-cell leaves: a cut piece 0.08 cells wide passed 9·10⁻⁵ cells from
/// one, which the mesher, meshing in f64, rightly saw outside it).
fn scan_written(
    hf: &Heightfield,
    tri: &[MeshVertex; 3],
    footprint: [u32; 4],
    mut valid: impl FnMut(usize, usize, f64),
) -> bool {
    const ROUNDING: f64 = 1e-4;
    let [x0, x1, z0, z1] = footprint.map(f64::from);
    let [a, b, d] = tri;
    let (zlo, zhi) = (a.z.min(b.z).min(d.z), a.z.max(b.z).max(d.z));
    let (xlo, xhi) = (a.x.min(b.x).min(d.x), a.x.max(b.x).max(d.x));
    let rows = ((zlo - ROUNDING).ceil().max(z0), (zhi + ROUNDING).floor().min(z1));
    let cols = ((xlo - ROUNDING).ceil().max(x0), (xhi + ROUNDING).floor().min(x1));
    let (mut any_valid, mut nodata_inside) = (false, false);
    points_near_triangle(tri, rows, cols, ROUNDING, |i, j, h| {
        let s = hf.get(i, j);
        if s.is_nan() {
            nodata_inside = nodata_inside || inside_by(tri, j as f64, i as f64, ROUNDING);
        } else {
            any_valid = true;
            valid(i, j, (h - f64::from(s)).abs());
        }
    });
    nodata_inside && !any_valid
}

/// Whether triangle `tri` (grid units, as read back, in file order) is
/// wound the wrong way in plan: the surface folds over itself there, drawn
/// twice or, with back faces culled, not at all. Chunks are written
/// counter-clockwise seen from above (+y), which in x-east, z-south grid
/// space is a negative signed area; a zero area (two corners on one point,
/// as a quantized file may put close crossings) is not turned.
fn turned_over([a, b, c]: &[MeshVertex; 3]) -> bool {
    let o = robust::orient2d(
        robust::Coord { x: a.x, y: a.z },
        robust::Coord { x: b.x, y: b.z },
        robust::Coord { x: c.x, y: c.z },
    );
    o > 0.0
}

/// Whether (x, z) lies inside triangle `tri` by more than `margin` from
/// each of its edges (never, for a triangle with no area).
fn inside_by(tri: &[MeshVertex; 3], x: f64, z: f64, margin: f64) -> bool {
    let [a, b, c] = tri;
    let area = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
    if area == 0.0 {
        return false;
    }
    [(a, b), (b, c), (c, a)].iter().all(|(p, q)| {
        let len = (q.x - p.x).hypot(q.z - p.z);
        let cross = (q.x - p.x) * (z - p.z) - (q.z - p.z) * (x - p.x);
        cross * area.signum() > margin * len
    })
}

/// What f64 arithmetic may add to an error measured over chunk `c`: this
/// interpolation and the mesher's own (which found a sample exactly δ off
/// within δ) each round by a few units in the last place of the heights
/// involved; 256 of them is ample and far below any real error (4·10⁻¹⁰ m
/// at 3 km). An error within that of a bound is the bound, as a coordinate
/// within f32 rounding of a sample index is that index.
pub(super) fn snap_error(c: &ChunkFile, err: f64, bound: f64) -> f64 {
    let (lo, hi) = c
        .surface
        .positions
        .iter()
        .map(|p| p[1])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| (lo.min(h), hi.max(h)));
    let slack = if lo > hi { 0.0 } else { 256.0 * f64::EPSILON * (lo.abs().max(hi.abs()) + (hi - lo)) };
    if err > bound && err <= bound + slack { bound } else { err }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, z: f64) -> MeshVertex {
        MeshVertex { x, z, h: 0.0, ph: 0.0 }
    }

    /// inside it by more than rounding and no valid one is that near.
    #[test]
    fn a_triangle_wound_against_the_file_order_is_turned_over_and_a_flat_one_is_not() {
        // Written counter-clockwise seen from above: clockwise in x-east,
        // z-south grid space.
        let written = [v(0.0, 0.0), v(0.0, 1.0), v(1.0, 0.0)];
        assert!(!turned_over(&written));
        let [a, b, c] = written;
        assert!(turned_over(&[a, c, b]));
        // A sliver a step wide, as the Sierra chunks had it, either way round.
        let sliver = [v(129.0, 276.0), v(120.7890625, 253.0), v(130.78515625, 281.0)];
        assert!(turned_over(&sliver));
        assert!(!turned_over(&[sliver[0], sliver[2], sliver[1]]));
        // Two corners on one point (close crossings on one lattice point).
        assert!(!turned_over(&[v(3.0, 2.0), v(3.0, 2.0), v(5.0, 7.0)]));
    }

    /// Seamount at 1 m with 32-cell leaves failed `verify` ("1 triangles
    /// stand over nodata alone"): a cut piece 0.08 cells wide, whose only
    /// sample within 10⁻⁴ was a nodata one 9·10⁻⁵ outside its edge. A
    /// triangle stands over nodata alone only where a nodata sample is
    /// inside it by more than rounding and no valid one is that near.

    #[test]
    fn a_sliver_passing_a_rounding_from_a_nodata_sample_does_not_stand_over_it() {
        let (w, h) = (460, 270);
        let mut heights = vec![f32::NAN; w * h];
        let footprint = [0, w as u32 - 1, 0, h as u32 - 1];
        let sliver =
            [v(445.188_640_792_341_23, 249.0), v(445.111_151_621_413_8, 249.0), v(436.0, 263.909_281_785_734_4)];
        let hf = Heightfield::ungeoreferenced(w, h, heights.clone(), "test".into());
        assert!(!scan_written(&hf, &sliver, footprint, |_, _, _| {}), "the sliver covers no sample");
        // A triangle with nodata well inside it, and nothing valid near.
        let over = [v(430.0, 250.0), v(440.0, 250.0), v(430.0, 260.0)];
        assert!(scan_written(&hf, &over, footprint, |_, _, _| {}));
        // One valid sample on its edge, within rounding: it covers data.
        heights[255 * w + 435] = -4100.0;
        let hf = Heightfield::ungeoreferenced(w, h, heights, "test".into());
        let mut seen = Vec::new();
        assert!(!scan_written(&hf, &over, footprint, |i, j, _| seen.push((i, j))));
        assert_eq!(seen, [(255, 435)]);
    }
}
