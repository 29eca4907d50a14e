//! Morph: each vertex's height on the parent chunk's surface.
//!
//! A child's triangles refine its parent's (decimate.rs keeps every parent
//! edge as a constraint), so moving each child vertex to the parent surface
//! at its (x, z) reproduces the parent exactly, everywhere (DESIGN.md,
//! promise 3). The glTF morph target stores `parent − own` as a y delta.
//! [`SurfaceLocator`] finds the parent triangle under a point; `verify` uses
//! it to re-measure the targets from the files.

use crate::mesh::MeshVertex;

/// Finds the triangle of a mesh under a point, with a bucket grid.
pub struct SurfaceLocator<'m> {
    verts: &'m [MeshVertex],
    tris: &'m [[u32; 3]],
    origin: (f64, f64),
    cell: f64,
    nx: usize,
    nz: usize,
    buckets: Vec<Vec<u32>>,
}

impl<'m> SurfaceLocator<'m> {
    /// Indexes the given triangles.
    pub fn from_parts(verts: &'m [MeshVertex], tris: &'m [[u32; 3]]) -> Self {
        let (mut x0, mut z0, mut x1, mut z1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for v in verts {
            x0 = x0.min(v.x);
            z0 = z0.min(v.z);
            x1 = x1.max(v.x);
            z1 = z1.max(v.z);
        }
        let area = ((x1 - x0) * (z1 - z0)).max(1.0);
        let cell = (area / (tris.len().max(1) as f64)).sqrt().max(1e-9) * 2.0;
        let nx = (((x1 - x0) / cell) as usize + 1).min(4096);
        let nz = (((z1 - z0) / cell) as usize + 1).min(4096);
        let mut buckets = vec![Vec::new(); nx * nz];
        let b = |v: f64, o: f64, n: usize| (((v - o) / cell).floor().max(0.0) as usize).min(n - 1);
        for (t, tri) in tris.iter().enumerate() {
            let p = tri.map(|k| verts[k as usize]);
            let (lx, hx) = (p[0].x.min(p[1].x).min(p[2].x), p[0].x.max(p[1].x).max(p[2].x));
            let (lz, hz) = (p[0].z.min(p[1].z).min(p[2].z), p[0].z.max(p[1].z).max(p[2].z));
            for bz in b(lz, z0, nz)..=b(hz, z0, nz) {
                for bx in b(lx, x0, nx)..=b(hx, x0, nx) {
                    buckets[bz * nx + bx].push(t as u32);
                }
            }
        }
        SurfaceLocator { verts, tris, origin: (x0, z0), cell, nx, nz, buckets }
    }

    /// The triangle containing (x, z): among those that contain it exactly,
    /// the one with the largest area (on an edge shared with a zero-width
    /// sliver, the sliver's plane means nothing); if rounding left it inside
    /// none, the nearest one within `tol` grid units. Returns it and the
    /// interpolated height there.
    pub fn locate(&self, x: f64, z: f64, tol: f64) -> Option<(u32, f64)> {
        let b = |v: f64, o: f64, n: usize| (((v - o) / self.cell).floor().max(0.0) as usize).min(n - 1);
        let bucket = &self.buckets[b(z, self.origin.1, self.nz) * self.nx + b(x, self.origin.0, self.nx)];
        let mut inside: Option<(f64, u32, f64)> = None; // (area, t, h)
        let mut nearest: Option<(f64, u32, f64)> = None; // (distance, t, h)
        for &t in bucket {
            let [a, p, q] = self.tris[t as usize].map(|k| self.verts[k as usize]);
            let (outside, h) = barycentric(&a, &p, &q, x, z);
            if !outside.is_finite() {
                continue;
            }
            let area = ((p.x - a.x) * (q.z - a.z) - (q.x - a.x) * (p.z - a.z)).abs();
            if outside == 0.0 && inside.is_none_or(|w| area > w.0) {
                inside = Some((area, t, h));
            }
            if nearest.is_none_or(|n| outside < n.0) {
                nearest = Some((outside, t, h));
            }
        }
        inside.map(|w| (w.1, w.2)).or(nearest.filter(|n| n.0 <= tol.max(1e-6)).map(|n| (n.1, n.2)))
    }

    /// Every triangle within `tol` grid units of (x, z), those containing it
    /// included, each with its plane's height there. A point read back with
    /// rounding `tol` truly lies in one of them (on a crease, not
    /// necessarily the one [`Self::locate`] picks).
    pub fn near(&self, x: f64, z: f64, tol: f64) -> Vec<(u32, f64)> {
        let tol = tol.max(1e-6);
        let b = |v: f64, o: f64, n: usize| (((v - o) / self.cell).floor().max(0.0) as usize).min(n - 1);
        let mut found: Vec<(u32, f64)> = Vec::new();
        for bz in b(z - tol, self.origin.1, self.nz)..=b(z + tol, self.origin.1, self.nz) {
            for bx in b(x - tol, self.origin.0, self.nx)..=b(x + tol, self.origin.0, self.nx) {
                for &t in &self.buckets[bz * self.nx + bx] {
                    let [a, p, q] = self.tris[t as usize].map(|k| self.verts[k as usize]);
                    let (outside, h) = barycentric(&a, &p, &q, x, z);
                    if outside <= tol && !found.iter().any(|f| f.0 == t) {
                        found.push((t, h));
                    }
                }
            }
        }
        found
    }
}

/// How far outside triangle (a, b, c) the point is, in grid units (0 when
/// inside or on it), and the linear interpolation of the heights there
/// (extrapolated when outside).
pub fn barycentric(a: &MeshVertex, b: &MeshVertex, c: &MeshVertex, x: f64, z: f64) -> (f64, f64) {
    let det = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
    if det.abs() < 1e-300 {
        return (f64::INFINITY, a.h);
    }
    let l1 = ((x - a.x) * (c.z - a.z) - (c.x - a.x) * (z - a.z)) / det;
    let l2 = ((b.x - a.x) * (z - a.z) - (x - a.x) * (b.z - a.z)) / det;
    let l0 = 1.0 - l1 - l2;
    let h = l0 * a.h + l1 * b.h + l2 * c.h;
    if l0 >= 0.0 && l1 >= 0.0 && l2 >= 0.0 {
        return (0.0, h);
    }
    let seg = |p: &MeshVertex, q: &MeshVertex| {
        let (dx, dz) = (q.x - p.x, q.z - p.z);
        let len2 = dx * dx + dz * dz;
        let t = if len2 > 0.0 { (((x - p.x) * dx + (z - p.z) * dz) / len2).clamp(0.0, 1.0) } else { 0.0 };
        ((x - p.x - t * dx).powi(2) + (z - p.z - t * dz).powi(2)).sqrt()
    };
    (seg(a, b).min(seg(b, c)).min(seg(c, a)), h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, z: f64, h: f64) -> MeshVertex {
        MeshVertex { x, z, h, ph: h }
    }

    /// A crease: a flat triangle beside a steep one along x = 1. A point read
    /// back a hair inside the flat one may truly lie on the steep one's side;
    /// `near` offers both, `locate` only the one it falls in.
    #[test]
    fn near_offers_both_sides_of_a_crease_within_the_rounding() {
        let verts = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(1.0, 1.0, 0.0), v(2.0, 0.5, 100.0)];
        let tris = [[0, 1, 2], [1, 3, 2]];
        let loc = SurfaceLocator::from_parts(&verts, &tris);
        let (x, z) = (1.0 - 1e-7, 0.5);
        assert_eq!(loc.locate(x, z, 1e-6).map(|t| t.0), Some(0));
        let mut near = loc.near(x, z, 1e-6);
        near.sort_by_key(|n| n.0);
        assert_eq!(near.iter().map(|n| n.0).collect::<Vec<_>>(), vec![0, 1]);
        // The steep plane extrapolated a hair outside: 100 m per unit × 1e-7.
        assert!(near[0].1.abs() < 1e-12 && (near[1].1 + 1e-5).abs() < 1e-9, "{near:?}");
        // Further than the rounding, only the flat triangle.
        assert_eq!(loc.near(0.9, 0.5, 1e-6).iter().map(|n| n.0).collect::<Vec<_>>(), vec![0]);
    }
}
