//! Morph targets: every vertex moved by its target lands on the parent's
//! surface, and every child triangle lies inside one parent triangle, so
//! the morphed chunk coincides with its parent everywhere (DESIGN.md,
//! promise 3).

use super::curved::{Curved, CurvedChunk};
use super::name;
use super::read::ChunkFile;
use crate::mesh::MeshVertex;
use crate::mesh::locate::{LocatorIndex, SurfaceLocator, barycentric};

/// A read parent's surface as its children's morph checks read it: in grid
/// units, with the bucket index that finds the triangle under a point. Made
/// once for all its children: each child made its own before, and on
/// California's 2049² crop at 1 m those four indexes took a tenth of
/// `verify`'s time.
pub(super) struct ParentSurface<'a> {
    file: &'a ChunkFile,
    verts: Vec<MeshVertex>,
    index: LocatorIndex,
    /// Its written surface in ECEF, for a tileset in the curved frame.
    curved: Option<&'a CurvedChunk>,
}

impl<'a> ParentSurface<'a> {
    pub(super) fn new(file: &'a ChunkFile, spacing: [f64; 2]) -> Self {
        let verts = file.surface.grid_vertices(spacing);
        let index = LocatorIndex::new(&verts, &file.surface.triangles);
        ParentSurface { file, verts, index, curved: None }
    }

    /// The same, with the parent's written surface in ECEF.
    pub(super) fn with_curved(self, curved: Option<&'a CurvedChunk>) -> Self {
        ParentSurface { curved, ..self }
    }

    pub(super) fn curved(&self) -> Option<&'a CurvedChunk> {
        self.curved
    }

    pub(super) fn locator(&self) -> SurfaceLocator<'_> {
        SurfaceLocator::with_index(&self.verts, &self.file.surface.triangles, &self.index)
    }

    /// Triangle `t`'s corners.
    pub(super) fn triangle(&self, t: u32) -> [u32; 3] {
        self.file.surface.triangles[t as usize]
    }

    /// Vertex `v` in grid units.
    pub(super) fn vertex(&self, v: u32) -> MeshVertex {
        self.verts[v as usize]
    }
}

/// Morph targets on the parent surface; child triangles inside parent ones.
pub(super) fn check_morph(c: &ChunkFile, parent: &ParentSurface, spacing: [f64; 2], problems: &mut Vec<String>) -> f64 {
    let (p, pv, loc) = (parent.file, &parent.verts, parent.locator());
    // f32 rounding of both chunks' chunk-local coordinates: horizontally (in
    // metres and in grid units), where a slope turns it into a height
    // difference, and vertically.
    let [rx, ry, rz] = [0, 1, 2].map(|a| f32_rounding(c, p)[a] + half_steps(c, p, a));
    let round_grid = (rx / spacing[0]).max(rz / spacing[1]);
    let allowed = |t: u32| {
        let [gx, gz] = plane_gradient(p.surface.triangles[t as usize].map(|i| pv[i as usize]), spacing);
        1e-5 + 2.0 * ry + gx.abs() * rx + gz.abs() * rz
    };
    let (mut gap, mut worst_excess): (f64, f64) = (0.0, 0.0);
    let mut missing = 0;
    let cv = c.surface.grid_vertices(spacing);
    let skirt_tops: Vec<(MeshVertex, f64)> = c
        .skirt
        .iter()
        .flat_map(|s| s.grid_vertices(spacing).into_iter().zip(s.morph_dy.iter().copied()))
        .filter(|(_, dy)| *dy != 0.0)
        .collect();
    for (v, dy) in cv.iter().copied().zip(c.surface.morph_dy.iter().copied()).chain(skirt_tops) {
        // The vertex truly lies in one of the parent triangles within the
        // rounding of where it was read; the one that explains its target
        // best decides (on a crease, the triangle it was read into may be
        // the neighbour of the one it is on).
        // The gap reported is the smallest over those triangles: the one
        // with the most allowance may be a steep sliver whose plane, read a
        // rounding away, says nothing of how far the target is (Sierra
        // N36W119 with `quantize`: 103 m "gaps" beside clustered cut points,
        // where the vertex sat exactly on the parent surface).
        // A sliver's plane is not read from its gradient (which says
        // nothing a rounding away, see above) but from the heights it takes
        // within rounding of the vertex: the target may be any of them (DFW
        // at 2 m, 16-cell leaves: a parent sliver 6·10⁻⁵ cells wide rose
        // 5 m across, and the child's vertex on it read 0.1 m "off").
        let target = v.h + dy;
        let best = loc
            .near(v.x, v.z, round_grid)
            .into_iter()
            .map(|(t, h)| {
                let g = (target - h).abs();
                let excess = g - allowed(t);
                if excess <= 0.0 {
                    return (excess, g);
                }
                let corners = p.surface.triangles[t as usize].map(|i| pv[i as usize]);
                let within = heights_within(corners, (v.x, v.z), [rx / spacing[0], rz / spacing[1]])
                    .map_or(f64::INFINITY, |(lo, hi)| (lo - target).max(target - hi).max(0.0) - 1e-5 - 2.0 * ry);
                (excess.min(within), g)
            })
            .reduce(|a, b| (a.0.min(b.0), a.1.min(b.1)));
        match best {
            Some((excess, g)) => {
                gap = gap.max(g);
                worst_excess = worst_excess.max(excess);
            }
            None => missing += 1,
        }
    }
    if missing > 0 {
        problems.push(format!("{missing} vertices lie outside the parent {}'s surface", name(p.key)));
    }
    let mut straddling = 0;
    for t in &c.surface.triangles {
        let child = t.map(|i| cv[i as usize]);
        let [a, b, d] = child;
        let (cx, cz) = ((a.x + b.x + d.x) / 3.0, (a.z + b.z + d.z) / 3.0);
        if let Some((pt, _)) = loc.locate(cx, cz, round_grid) {
            let parent = p.surface.triangles[pt as usize].map(|i| pv[i as usize]);
            if straddles(child, parent, 1e-4 + 2.0 * round_grid) {
                straddling += 1;
            }
        }
    }
    if straddling > 0 {
        problems.push(format!("{straddling} triangles straddle an edge of the parent {}", name(p.key)));
    }
    if worst_excess > 0.0 {
        problems.push(format!(
            "morph target misses the parent {} surface by {gap:.6} m (beyond f32 rounding)",
            name(p.key)
        ));
    }
    if c.surface.largest_dxz() != 0.0 {
        problems.push("morph target has nonzero x/z deltas".into());
    }
    gap
}

/// Whether a child triangle reaches more than `tol` grid units outside the
/// parent triangle that holds its centroid, i.e. straddles one of its
/// edges. A sliver whose height over its longest side is within `tol` has
/// no inside to straddle with: it is a segment as far as the rounding can
/// tell, and which side of a parent edge its centroid reads on is noise.
/// Such slivers come from cut points: one on the line through two collinear
/// parent edges makes a zero-area child triangle with their shared vertex,
/// whose f64 coordinates leave it a hair of area (Sierra N36W119 at 1 m,
/// `quantize`). Its corners are checked on the parent surface like every
/// vertex, and it covers no sample the triangles beside it do not.
fn straddles(child: [MeshVertex; 3], parent: [MeshVertex; 3], tol: f64) -> bool {
    let [a, b, d] = child;
    let twice_area = ((b.x - a.x) * (d.z - a.z) - (d.x - a.x) * (b.z - a.z)).abs();
    // Compared squared: grid coordinates are far from overflow, and no root
    // is needed (this runs once per child triangle).
    let side2 = |p: &MeshVertex, q: &MeshVertex| (p.x - q.x).powi(2) + (p.z - q.z).powi(2);
    let longest2 = side2(&a, &b).max(side2(&b, &d)).max(side2(&d, &a));
    if twice_area * twice_area <= tol * tol * longest2 {
        return false;
    }
    let [pa, pb, pd] = parent;
    child.iter().any(|v| barycentric(&pa, &pb, &pd, v.x, v.z).0 > tol)
}

/// The f32 rounding, metres, of positions written chunk-local in two chunks,
/// per axis (x, y, z) from that axis' extent: with 1 mm cells under 400 m of
/// relief, or 1 mm by 10 km cells, the axes differ by orders of magnitude.
pub(super) fn f32_rounding(a: &ChunkFile, b: &ChunkFile) -> [f64; 3] {
    let four_eps = 4.0 * f64::from(f32::EPSILON);
    [0, 1, 2].map(|k| four_eps * (a.surface.local_extent[k] + b.surface.local_extent[k]))
}

/// Half the quantization steps of two chunks along axis `a`, metres (0 for
/// f32 files): how far each may have rounded one vertex.
fn half_steps(a: &ChunkFile, b: &ChunkFile, axis: usize) -> f64 {
    [a, b].iter().map(|c| c.quantization_m.map_or(0.0, |s| s[axis] / 2.0)).sum()
}

/// The lowest and highest heights triangle `t` (grid units) takes within
/// the box of half-widths `half` (grid units) around `at`, or `None` if
/// none of it lies there: its plane's extremes over the triangle clipped
/// to the box, at the clipped polygon's corners, each interpolated along a
/// segment (no barycentric weights, which a sliver makes ill-conditioned).
fn heights_within(t: [MeshVertex; 3], at: (f64, f64), half: [f64; 2]) -> Option<(f64, f64)> {
    let mut poly: Vec<[f64; 3]> = t.iter().map(|v| [v.x, v.z, v.h]).collect();
    let sides =
        [(0, at.0 - half[0], 1.0), (0, at.0 + half[0], -1.0), (1, at.1 - half[1], 1.0), (1, at.1 + half[1], -1.0)];
    for (axis, bound, sign) in sides {
        let inside = |p: &[f64; 3]| sign * (p[axis] - bound) >= 0.0;
        let mut out = Vec::with_capacity(poly.len() + 1);
        for (k, p) in poly.iter().enumerate() {
            let q = &poly[(k + 1) % poly.len()];
            if inside(p) {
                out.push(*p);
            }
            if inside(p) != inside(q) {
                let s = (bound - p[axis]) / (q[axis] - p[axis]);
                out.push([0, 1, 2].map(|c| p[c] + s * (q[c] - p[c])));
            }
        }
        poly = out;
        if poly.is_empty() {
            return None;
        }
    }
    Some(poly.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[2]), hi.max(p[2]))))
}

/// Gradient `[∂h/∂x, ∂h/∂z]` (m per m) of a triangle given in grid coordinates.
fn plane_gradient(t: [MeshVertex; 3], spacing: [f64; 2]) -> [f64; 2] {
    let [a, b, c] = t.map(|v| [v.x * spacing[0], v.z * spacing[1], v.h]);
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if det.abs() < 1e-3 * spacing[0] * spacing[1] {
        return [0.0; 2]; // a sliver: no vertex is located in it (see SurfaceLocator)
    }
    let gx = ((b[2] - a[2]) * (c[1] - a[1]) - (c[2] - a[2]) * (b[1] - a[1])) / det;
    let gz = ((b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2])) / det;
    [gx, gz]
}

/// Each surface vertex's morph target against the parent's written
/// triangle at the vertex's grid point, in ECEF; returns the largest gap.
pub(super) fn check_curved_morph(
    curved: &Curved,
    flat: &ChunkFile,
    bent: &CurvedChunk,
    parent: &ParentSurface,
    parent_bent: &CurvedChunk,
    problems: &mut Vec<String>,
) -> f64 {
    let allowed = 2.0 * (bent.rounding_m + parent_bent.rounding_m) + 1e-6;
    let verts = flat.surface.grid_vertices(curved.spacing);
    let loc = parent.locator();
    let (mut gap, mut missing, mut over): (f64, usize, usize) = (0.0, 0, 0);
    for (k, v) in verts.iter().enumerate() {
        let Some((t, _)) = loc.locate(v.x, v.z, 1e-6) else {
            missing += 1;
            continue;
        };
        let corners = parent.triangle(t);
        let on = [0, 1, 2].map(|axis| {
            let with = |c: usize| MeshVertex {
                h: parent_bent.surface[corners[c] as usize][axis],
                ..parent.vertex(corners[c])
            };
            barycentric(&with(0), &with(1), &with(2), v.x, v.z).1
        });
        let g = (0..3).map(|a| (bent.targets[k][a] - on[a]).powi(2)).sum::<f64>().sqrt();
        gap = gap.max(g);
        over += usize::from(g > allowed);
    }
    if missing > 0 {
        problems.push(format!("{missing} vertices lie outside the parent's surface in grid space"));
    }
    if over > 0 {
        problems.push(format!(
            "{over} morph targets miss the parent's written surface, by up to {gap:.6} m (allowed {allowed:.6} m \
             of f32 rounding)"
        ));
    }
    gap
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, z: f64) -> MeshVertex {
        MeshVertex { x, z, h: 0.0, ph: 0.0 }
    }

    /// Sierra N36W119 at 1 m, `quantize`: chunk 4/12/0 holds a zero-area
    /// triangle along two collinear edges of its parent 3/6/0, through their
    /// shared vertex (929, 48); as read back, its centroid falls in the
    /// parent's sliver beside them and its far corner is 9.5 cells outside
    /// it. `verify` failed the build for it.
    #[test]
    fn a_sliver_along_collinear_parent_edges_does_not_straddle() {
        let child = [v(937.0, 42.888_671_875), v(929.0, 48.0), v(900.0, 66.529_296_875)];
        let parent = [v(927.0, 49.0), v(900.0, 66.531_25), v(929.0, 48.0)];
        // Half the child's step (1/512 cell) plus half the parent's (1/256).
        let tol = 1e-4 + 2.0 * (1.0 / 1024.0 + 1.0 / 512.0);
        assert!(barycentric(&parent[0], &parent[1], &parent[2], 937.0, 42.888_671_875).0 > 9.0);
        assert!(!straddles(child, parent, tol));
        // A real triangle across the same parent edge still straddles it.
        let across = [v(937.0, 42.0), v(929.0, 48.0), v(915.0, 50.0)];
        assert!(straddles(across, parent, tol));
        // And one inside the parent triangle does not.
        let inside = [v(928.0, 48.6), v(927.5, 48.9), v(910.0, 60.1)];
        assert!(!straddles(inside, parent, tol));
    }

    /// DFW at 2 m with 16-cell leaves failed `verify` (a morph target
    /// 0.099 m "off"): the parent 3/1/6 holds a sliver 6·10⁻⁵ cells wide
    /// along x + z = 358 whose plane rises 5 m across it, and the child's
    /// vertex (56, 302), on it, took the height of its upper edge. Within
    /// rounding of the vertex the sliver takes every height from its lower
    /// edge's to its upper edge's, and the target is one of them.
    #[test]
    fn a_morph_target_on_a_steep_parent_sliver_is_on_the_parent_surface() {
        let h = |x: f64, z: f64, h: f64| MeshVertex { x, z, h, ph: 0.0 };
        let sliver =
            [h(53.0, 305.0, 240.0), h(67.999_913_671_474_19, 290.0, 248.000_085_830_688_48), h(48.0, 310.0, 229.0)];
        let at = (56.0, 301.999_982);
        let (lo, hi) = heights_within(sliver, at, [2e-5, 2e-5]).expect("the sliver passes the vertex");
        assert!(lo < 237.0 && hi > 241.6, "{lo}..{hi}");
        // Away from the sliver, nothing; inside a broad triangle, its plane
        // a rounding either way.
        assert_eq!(heights_within(sliver, (56.0, 300.0), [2e-5, 2e-5]), None);
        let flat = [h(0.0, 0.0, 0.0), h(10.0, 0.0, 10.0), h(0.0, 10.0, 0.0)];
        let (lo, hi) = heights_within(flat, (5.0, 2.0), [0.01, 0.01]).unwrap();
        assert!((lo - 4.99).abs() < 1e-9 && (hi - 5.01).abs() < 1e-9, "{lo}..{hi}");
    }
}
