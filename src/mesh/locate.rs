//! Point location in a chunk's surface: [`SurfaceLocator`] finds the
//! triangle under a point (buckets over the triangles, [`LocatorIndex`]),
//! [`barycentric`] weighs its corners, [`points_near_triangle`] lists the
//! grid points a triangle reaches. The greedy mesher reads its morph targets
//! (each vertex's height on the parent's surface, DESIGN.md promise 3)
//! through it; `verify` re-measures them and the compressed output's error
//! with it.

use std::borrow::Cow;

use crate::mesh::MeshVertex;

/// Finds the triangle of a mesh under a point, with a bucket grid.
pub struct SurfaceLocator<'m> {
    verts: &'m [MeshVertex],
    tris: &'m [[u32; 3]],
    index: Cow<'m, LocatorIndex>,
}

/// A [`SurfaceLocator`]'s bucket grid, which owns nothing of the mesh: built
/// once, it can be kept beside the mesh and lent to every locator over it
/// (`ChunkMesh::locator`: the four children of a chunk ask for one each).
#[derive(Clone, Debug)]
pub struct LocatorIndex {
    origin: (f64, f64),
    cell: f64,
    nx: usize,
    nz: usize,
    /// Where each bucket's entries start in `entries` (one more at the end).
    starts: Vec<u32>,
    /// Per bucket, the triangles whose bounding box overlaps it.
    entries: Vec<u32>,
    /// Each triangle's bounding box: x low, x high, z low, z high.
    boxes: Vec<[f64; 4]>,
}

impl<'m> SurfaceLocator<'m> {
    /// Indexes the given triangles.
    pub fn from_parts(verts: &'m [MeshVertex], tris: &'m [[u32; 3]]) -> Self {
        SurfaceLocator { verts, tris, index: Cow::Owned(LocatorIndex::new(verts, tris)) }
    }

    /// A locator over `verts` and `tris` with `index`, which
    /// [`LocatorIndex::new`] built over the same.
    pub fn with_index(verts: &'m [MeshVertex], tris: &'m [[u32; 3]], index: &'m LocatorIndex) -> Self {
        SurfaceLocator { verts, tris, index: Cow::Borrowed(index) }
    }
}

impl LocatorIndex {
    /// Buckets the given triangles: each goes into every bucket it touches
    /// (row by row over its own span, not its bounding box), in buckets
    /// sized by [`bucket_side`].
    pub fn new(verts: &[MeshVertex], tris: &[[u32; 3]]) -> Self {
        Self::with_side(verts, tris, bucket_side(verts, tris))
    }

    /// [`Self::new`] with buckets `cell` grid units wide, or wider where
    /// the grid would pass 4 096 buckets a side.
    fn with_side(verts: &[MeshVertex], tris: &[[u32; 3]], cell: f64) -> Self {
        let (x0, x1, z0, z1) = extent(verts);
        let cell = cell.max((x1 - x0) / 4095.0).max((z1 - z0) / 4095.0);
        let nx = (((x1 - x0) / cell) as usize + 1).min(4096);
        let nz = (((z1 - z0) / cell) as usize + 1).min(4096);
        let boxes: Vec<[f64; 4]> = tris
            .iter()
            .map(|tri| {
                let p = tri.map(|k| verts[k as usize]);
                let (lx, hx) = (p[0].x.min(p[1].x).min(p[2].x), p[0].x.max(p[1].x).max(p[2].x));
                let (lz, hz) = (p[0].z.min(p[1].z).min(p[2].z), p[0].z.max(p[1].z).max(p[2].z));
                [lx, hx, lz, hz]
            })
            .collect();
        let grid = Buckets { origin: (x0, z0), cell, nx, nz };
        let corners = |t: usize| tris[t].map(|k| verts[k as usize]);
        // Each triangle's buckets found once, then put in bucket order, each
        // bucket's in triangle order (a counting sort by bucket).
        let mut touched: Vec<(u32, u32)> = Vec::with_capacity(2 * tris.len());
        for (t, bx) in boxes.iter().enumerate() {
            grid.touched(&corners(t), bx, |c| touched.push((c as u32, t as u32)));
        }
        let mut starts = vec![0u32; nx * nz + 1];
        for &(c, _) in &touched {
            starts[c as usize + 1] += 1;
        }
        for c in 0..nx * nz {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut entries = vec![0u32; touched.len()];
        for &(c, t) in &touched {
            entries[fill[c as usize] as usize] = t;
            fill[c as usize] += 1;
        }
        LocatorIndex { origin: (x0, z0), cell, nx, nz, starts, entries, boxes }
    }

    /// The bucket (x, z) falls in: the one that holds every triangle
    /// containing it.
    #[inline]
    fn bucket_at(&self, x: f64, z: f64) -> usize {
        bucket_index(z, self.origin.1, self.cell, self.nz) * self.nx
            + bucket_index(x, self.origin.0, self.cell, self.nx)
    }

    /// The buckets over the square of half-side `r` around (x, z), row by
    /// row: between them they hold every triangle within `r` of the point.
    fn buckets_near(&self, x: f64, z: f64, r: f64) -> impl Iterator<Item = usize> + '_ {
        let b = |v: f64, o: f64, n: usize| bucket_index(v, o, self.cell, n);
        let columns = b(x - r, self.origin.0, self.nx)..=b(x + r, self.origin.0, self.nx);
        (b(z - r, self.origin.1, self.nz)..=b(z + r, self.origin.1, self.nz))
            .flat_map(move |bz| columns.clone().map(move |bx| bz * self.nx + bx))
    }

    /// The entries of bucket `c`.
    #[inline]
    fn bucket(&self, c: usize) -> &[u32] {
        &self.entries[self.starts[c] as usize..self.starts[c + 1] as usize]
    }

    /// Whether (x, z) is further than `tol` from triangle `t`'s bounding
    /// box, and so from the triangle: no need to measure.
    #[inline]
    fn far(&self, t: u32, x: f64, z: f64, tol: f64) -> bool {
        let [lx, hx, lz, hz] = self.boxes[t as usize];
        x < lx - tol || x > hx + tol || z < lz - tol || z > hz + tol
    }
}

impl SurfaceLocator<'_> {
    /// The triangle containing (x, z): among those that contain it exactly,
    /// the one with the largest area (on an edge shared with a zero-width
    /// sliver, the sliver's plane means nothing); if rounding left it inside
    /// none, the nearest one within `tol` grid units. Returns it and the
    /// interpolated height there.
    pub fn locate(&self, x: f64, z: f64, tol: f64) -> Option<(u32, f64)> {
        let own = self.index.bucket_at(x, z);
        // Only a triangle within the tolerance can be returned.
        let reach = tol.max(1e-6);
        let mut found = Found::default();
        // A triangle containing the point has it in its bounding box, so it
        // is in the point's own bucket.
        for &t in self.index.bucket(own) {
            self.weigh(t, x, z, reach, &mut found);
        }
        // Inside none (a point rounded into a hole or off the border): the
        // nearest within reach may lie wholly in a neighbouring bucket,
        // across a bucket edge less than `reach` away.
        if found.inside.is_none() {
            for c in self.index.buckets_near(x, z, reach).filter(|&c| c != own) {
                for &t in self.index.bucket(c) {
                    self.weigh(t, x, z, reach, &mut found);
                }
            }
        }
        let Found { inside, nearest } = found;
        inside.map(|w| (w.1, w.2)).or(nearest.filter(|n| n.0 <= reach).map(|n| (n.1, n.2)))
    }

    /// Weighs triangle `t` for [`Self::locate`] at (x, z): whether it
    /// contains the point with a larger area than the best so far, or is
    /// nearer than the nearest so far. Farther than `reach` it is neither
    /// inside nor the nearest within reach ([`Self::measure`]).
    #[inline(always)]
    fn weigh(&self, t: u32, x: f64, z: f64, reach: f64, found: &mut Found) {
        let Some(([a, p, q], outside, h)) = self.measure(t, x, z, reach) else {
            return;
        };
        if !outside.is_finite() {
            return;
        }
        let area = ((p.x - a.x) * (q.z - a.z) - (q.x - a.x) * (p.z - a.z)).abs();
        if outside == 0.0 && found.inside.is_none_or(|w| area > w.0) {
            found.inside = Some((area, t, h));
        }
        if found.nearest.is_none_or(|n| outside < n.0) {
            found.nearest = Some((outside, t, h));
        }
    }

    /// Triangle `t`'s corners, how far (x, z) lies outside it and its
    /// plane's height there; `None`, unmeasured, where its bounding box or
    /// one edge's line puts the point surely farther than `reach`.
    #[inline(always)]
    fn measure(&self, t: u32, x: f64, z: f64, reach: f64) -> Option<([MeshVertex; 3], f64, f64)> {
        if self.index.far(t, x, z, reach) {
            return None;
        }
        let [a, p, q] = self.tris[t as usize].map(|k| self.verts[k as usize]);
        if surely_beyond(&a, &p, &q, x, z, reach) {
            return None;
        }
        let (outside, h) = barycentric(&a, &p, &q, x, z);
        Some(([a, p, q], outside, h))
    }

    /// Every triangle within `tol` grid units of (x, z), those containing it
    /// included, each with its plane's height there. A point read back with
    /// rounding `tol` truly lies in one of them (on a crease, not
    /// necessarily the one [`Self::locate`] picks).
    pub fn near(&self, x: f64, z: f64, tol: f64) -> Vec<(u32, f64)> {
        let tol = tol.max(1e-6);
        let mut found: Vec<(u32, f64)> = Vec::new();
        for c in self.index.buckets_near(x, z, tol) {
            for &t in self.index.bucket(c) {
                if let Some((_, outside, h)) = self.measure(t, x, z, tol)
                    && outside <= tol
                    && !found.iter().any(|f| f.0 == t)
                {
                    found.push((t, h));
                }
            }
        }
        found
    }
}

/// What [`SurfaceLocator::locate`] has found so far: the containing
/// triangle of largest area (area, triangle, height) and the nearest
/// (distance, triangle, height).
#[derive(Default)]
struct Found {
    inside: Option<(f64, u32, f64)>,
    nearest: Option<(f64, u32, f64)>,
}

/// The smallest and largest x and z of `verts`: (x0, x1, z0, z1).
fn extent(verts: &[MeshVertex]) -> (f64, f64, f64, f64) {
    let (mut x0, mut z0, mut x1, mut z1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for v in verts {
        x0 = x0.min(v.x);
        z0 = z0.min(v.z);
        x1 = x1.max(v.x);
        z1 = z1.max(v.z);
    }
    (x0, x1, z0, z1)
}

/// How wide a [`LocatorIndex`]'s buckets are: 1.5 times the side of a
/// square as large as the median triangle, so that a bucket where the
/// triangles are typical holds a few, but no narrower than half the side
/// of the mesh's area shared out over its triangles (at most four buckets
/// per triangle). A TIN is dense where the ground is rough and sparse
/// where it is smooth, and the points asked of it come mostly from where
/// it is dense (a child holds more triangles there too), so buckets sized
/// by the median triangle hold fewer triangles per lookup than buckets
/// sized by the average one (with each triangle only where it reaches,
/// [`Buckets::touched`]; docs/benchmarks.md).
fn bucket_side(verts: &[MeshVertex], tris: &[[u32; 3]]) -> f64 {
    let (x0, x1, z0, z1) = extent(verts);
    let area = ((x1 - x0) * (z1 - z0)).max(1.0);
    let mut areas: Vec<f64> = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|k| verts[k as usize]);
            (((b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z)) / 2.0).abs()
        })
        .filter(|a| a.is_finite())
        .collect();
    let median = match areas.len() {
        0 => 0.0,
        n => *areas.select_nth_unstable_by(n / 2, f64::total_cmp).1,
    };
    (1.5 * median.sqrt()).max(0.5 * (area / tris.len().max(1) as f64).sqrt()).max(1e-9)
}

/// A [`LocatorIndex`]'s grid of buckets, while it is filled.
struct Buckets {
    origin: (f64, f64),
    cell: f64,
    nx: usize,
    nz: usize,
}

impl Buckets {
    /// Calls `visit` with every bucket that a point of triangle `p` (with
    /// bounding box `bx`) falls in by [`bucket_index`], and perhaps a few
    /// next to them: for each row of buckets, the triangle's x over that
    /// row's band of z (each edge clipped to the band), both widened by a
    /// margin far above their rounding. The first and last rows and columns
    /// reach to infinity, as `bucket_index` clamps. A long, thin triangle
    /// across the grid touches a row of buckets, not the square its box
    /// spans: in nested TINs, where pieces cut along dividing lines are
    /// such triangles, bounding boxes put some 40 triangles in the bucket
    /// of an average point (`verify` on California's 4097² crop at 5 m),
    /// most of them nowhere near it. A corner that is not finite (a damaged
    /// file) makes the triangle fall back to its box.
    fn touched(&self, p: &[MeshVertex; 3], bx: &[f64; 4], mut visit: impl FnMut(usize)) {
        let (nx, nz, cell) = (self.nx, self.nz, self.cell);
        let (x0, z0) = self.origin;
        let b = |v: f64, o: f64, n: usize| bucket_index(v, o, cell, n);
        let [lx, hx, lz, hz] = *bx;
        if !p.iter().all(|v| v.x.is_finite() && v.z.is_finite()) {
            for bz in b(lz, z0, nz)..=b(hz, z0, nz) {
                for c in b(lx, x0, nx)..=b(hx, x0, nx) {
                    visit(bz * nx + c);
                }
            }
            return;
        }
        let scale = 1.0 + lx.abs().max(hx.abs()).max(lz.abs()).max(hz.abs());
        let margin = (cell * 1e-6).max(scale * 1e-9);
        for bz in b(lz - margin, z0, nz)..=b(hz + margin, z0, nz) {
            let lo = if bz == 0 { f64::NEG_INFINITY } else { z0 + bz as f64 * cell - margin };
            let hi = if bz + 1 == nz { f64::INFINITY } else { z0 + (bz + 1) as f64 * cell + margin };
            let Some((xmin, xmax)) = x_over_band(p, lo, hi) else {
                continue;
            };
            // Within the box: the clipped ends never leave it but by rounding.
            let (xmin, xmax) = (xmin.max(lx), xmax.min(hx));
            for c in b(xmin - margin, x0, nx)..=b(xmax + margin, x0, nx) {
                visit(bz * nx + c);
            }
        }
    }
}

/// The bucket of coordinate `v` along an axis starting at `o`, of `n`
/// buckets of `cell` grid units (clamped to the first and last).
///
/// The cast is the floor clamped at 0: it truncates toward zero, which is
/// the floor for what is not negative, and saturates what is negative (or
/// NaN) to 0. (`floor` is a call into libm on the baseline x86-64 target;
/// the locator asks this of every point `verify` reads.)
#[inline]
fn bucket_index(v: f64, o: f64, cell: f64, n: usize) -> usize {
    (((v - o) / cell) as usize).min(n - 1)
}

/// The least and greatest x of triangle `tri` over the band of z in
/// [`lo`, `hi`] (`None` if it does not reach the band): each edge clipped
/// to the band, its x at the clipped ends (x is linear along an edge).
fn x_over_band(tri: &[MeshVertex; 3], lo: f64, hi: f64) -> Option<(f64, f64)> {
    let [a, b, d] = tri;
    let (mut xmin, mut xmax) = (f64::INFINITY, f64::NEG_INFINITY);
    for (p, q) in [(a, b), (b, d), (d, a)] {
        let (z0, z1) = (p.z.min(q.z).max(lo), p.z.max(q.z).min(hi));
        if z0 > z1 {
            continue;
        }
        if q.z == p.z {
            (xmin, xmax) = (xmin.min(p.x.min(q.x)), xmax.max(p.x.max(q.x)));
            continue;
        }
        for zc in [z0, z1] {
            let x = p.x + (q.x - p.x) * ((zc - p.z) / (q.z - p.z));
            (xmin, xmax) = (xmin.min(x), xmax.max(x));
        }
    }
    (xmin <= xmax).then_some((xmin, xmax))
}

/// Visits every grid point (column `j`, row `i`) of `rows` × `cols` (whole
/// numbers, inclusive ranges) within `tol` grid units of triangle `tri`, by
/// [`barycentric`], with the triangle's plane height there.
///
/// Row by row over the triangle's own span on that row (its x over the band
/// of rows within `tol`, widened by `tol` and a margin for rounding), not
/// over its bounding box: a point outside costs three distances to the
/// edges, and a sliver's box is mostly outside. The points visited, and
/// what they are visited with, are exactly those of the box scan (tested).
pub fn points_near_triangle(
    tri: &[MeshVertex; 3],
    rows: (f64, f64),
    cols: (f64, f64),
    tol: f64,
    mut visit: impl FnMut(usize, usize, f64),
) {
    let [a, b, d] = tri;
    if rows.0 > rows.1 || cols.0 > cols.1 {
        return;
    }
    let band = tol + 1e-9;
    for i in rows.0 as usize..=rows.1 as usize {
        let z = i as f64;
        let (lo, hi) = (z - band, z + band);
        let Some((xmin, xmax)) = x_over_band(tri, lo, hi) else {
            continue;
        };
        let margin = band + 1e-9 * (1.0 + xmin.abs().max(xmax.abs()));
        let j0 = (xmin - margin).ceil().max(cols.0);
        let j1 = (xmax + margin).floor().min(cols.1);
        if j0 > j1 {
            continue;
        }
        for j in j0 as usize..=j1 as usize {
            let (outside, h) = barycentric(a, b, d, j as f64, z);
            if outside <= tol {
                visit(i, j, h);
            }
        }
    }
}

/// Whether (x, z) is surely more than `tol` grid units outside triangle
/// (a, b, c), as [`barycentric`] measures it: beyond one edge's line, on the
/// side away from the third corner, by more than `tol` and a margin (10⁻⁹
/// grid units) far above the rounding of either measure. The distance to a
/// triangle is at least the distance to the line of any edge it lies
/// beyond, so this turns away only what `barycentric` would, and costs no
/// division or root: the locator asks it first of every triangle whose box
/// is near the point (most of which are not under it).
#[inline]
fn surely_beyond(a: &MeshVertex, b: &MeshVertex, c: &MeshVertex, x: f64, z: f64, tol: f64) -> bool {
    let det = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
    let reach = tol + 1e-9;
    [(a, b), (b, c), (c, a)].into_iter().any(|(p, q)| {
        let (dx, dz) = (q.x - p.x, q.z - p.z);
        let cross = dx * (z - p.z) - dz * (x - p.x);
        cross * det < 0.0 && cross * cross > reach * reach * (dx * dx + dz * dz)
    })
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
    use crate::test_rng::{unit_draws, xorshift};

    fn v(x: f64, z: f64, h: f64) -> MeshVertex {
        MeshVertex { x, z, h, ph: h }
    }

    /// `points_near_triangle` visits exactly the points the bounding-box
    /// scan it replaced did (every point of the box within the tolerance,
    /// by `barycentric`), in the same order and with the same heights: with
    /// the box as `cut_error` takes it (whole points inside it) and as
    /// `verify` does (widened by 10⁻⁴ and clipped to a footprint), on
    /// slivers along a line with corners at 1/256 of a cell, triangles with
    /// corners a hair off a row or column, and random ones.
    #[test]
    fn rows_visit_what_the_bounding_box_did() {
        let (w, h) = (40.0f64, 33.0f64);
        let mut next = xorshift(0x2545_f491_4f6c_dd1d);
        let unit = |r: u64| (r % 1_000_000) as f64 / 1_000_000.0;
        let box_scan = |t: &[MeshVertex; 3], rows: (f64, f64), cols: (f64, f64), tol: f64| {
            let mut out = Vec::new();
            if rows.0 <= rows.1 && cols.0 <= cols.1 {
                for i in rows.0 as usize..=rows.1 as usize {
                    for j in cols.0 as usize..=cols.1 as usize {
                        let (outside, y) = barycentric(&t[0], &t[1], &t[2], j as f64, i as f64);
                        if outside <= tol {
                            out.push((i, j, y.to_bits()));
                        }
                    }
                }
            }
            out
        };
        let mut visited = 0;
        for n in 0..6000 {
            let tri = match n % 3 {
                0 => {
                    let line = (next() % 40) as f64;
                    let z0 = (next() % (33 * 256)) as f64 / 256.0;
                    let z1 = (z0 + 1.0 + (next() % 3000) as f64 / 256.0).min(h - 1.0);
                    let far = (line + 1.0 + (next() % 6) as f64).min(w - 1.0);
                    [v(line, z0, unit(next())), v(far, (z0 + z1) / 2.0 + unit(next()), 50.0), v(line, z1, -9.0)]
                }
                1 => [0, 1, 2].map(|_| {
                    let hair = |r: u64| (unit(r) - 0.5) * 4e-4;
                    let x = ((next() % 40) as f64 + hair(next())).clamp(0.0, w - 1.0);
                    let z = ((next() % 33) as f64 + hair(next())).clamp(0.0, h - 1.0);
                    v(x, z, 80.0 * unit(next()))
                }),
                _ => [0, 1, 2].map(|_| {
                    let c = |r: u64, n: f64| (r % (n as u64 * 256 - 255)) as f64 / 256.0;
                    v(c(next(), w), c(next(), h), 80.0 * unit(next()))
                }),
            };
            let [a, b, d] = &tri;
            let (zlo, zhi) = (a.z.min(b.z).min(d.z), a.z.max(b.z).max(d.z));
            let (xlo, xhi) = (a.x.min(b.x).min(d.x), a.x.max(b.x).max(d.x));
            // cut_error's box, then verify's over a footprint [3, 30] × [2, 25].
            let cut =
                ((zlo.ceil().max(0.0), zhi.floor().min(h - 1.0)), (xlo.ceil().max(0.0), xhi.floor().min(w - 1.0)));
            let ver = (
                ((zlo - 1e-4).ceil().max(2.0), (zhi + 1e-4).floor().min(25.0)),
                ((xlo - 1e-4).ceil().max(3.0), (xhi + 1e-4).floor().min(30.0)),
            );
            for (rows, cols) in [cut, ver] {
                let mut got = Vec::new();
                points_near_triangle(&tri, rows, cols, 1e-4, |i, j, y| got.push((i, j, y.to_bits())));
                let want = box_scan(&tri, rows, cols, 1e-4);
                assert_eq!(got, want, "triangle {n}: {tri:?}, rows {rows:?}, cols {cols:?}");
                visited += want.len();
            }
        }
        assert!(visited > 20_000, "the triangles covered points ({visited})");
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

    /// A point rounded into a hole, a hair from a triangle that lies wholly
    /// in the next bucket: `locate` still finds that triangle, as `near`
    /// does. (Before, it searched only the point's own bucket and found
    /// nothing.)
    #[test]
    fn locate_finds_the_nearest_across_a_bucket_edge() {
        // Over 10 × 10, in 5-unit buckets: a strip of 8 triangles ends
        // 10⁻⁸ short of x = 5, another of 8 lies over x ∈ [8, 10]; between
        // them is a hole. Heights are h = x.
        let edge = 5.0 - 1e-8;
        let mut verts = Vec::new();
        let mut tris = Vec::new();
        for (x0, x1) in [(0.0, edge), (8.0, 10.0)] {
            for k in 0..4 {
                let (z0, z1) = (2.5 * k as f64, 2.5 * (k + 1) as f64);
                let n = verts.len() as u32;
                verts.extend([v(x0, z0, x0), v(x1, z0, x1), v(x1, z1, x1), v(x0, z1, x0)]);
                tris.extend([[n, n + 2, n + 1], [n, n + 3, n + 2]]);
            }
        }
        let index = LocatorIndex::with_side(&verts, &tris, 5.0);
        let loc = SurfaceLocator::with_index(&verts, &tris, &index);
        assert_eq!(loc.index.cell, 5.0, "the buckets' edge is at x = 5");
        let (x, z) = (5.0 + 1e-9, 3.7);
        let near = loc.near(x, z, 1e-6);
        assert_eq!(near.len(), 1, "{near:?}");
        let (t, h) = loc.locate(x, z, 1e-6).expect("the strip is 1.1e-8 away");
        assert_eq!(t, near[0].0);
        assert!((h - x).abs() < 1e-9, "extrapolated on h = x: {h}");
        // Beyond the tolerance, nothing.
        assert_eq!(loc.locate(5.0 + 1e-5, z, 1e-6), None);
    }

    /// `bucket_index` without `floor` gives what `floor`, clamped at 0, gave,
    /// for values on and either side of every bucket edge, below the first
    /// and past the last, and for NaN and the infinities.
    #[test]
    fn bucket_index_is_the_clamped_floor() {
        let floor = |v: f64, o: f64, cell: f64, n: usize| (((v - o) / cell).floor().max(0.0) as usize).min(n - 1);
        let (o, cell, n) = (-3.25, 1.378_125_3, 40);
        for k in -5..50 {
            let edge = o + k as f64 * cell;
            for v in [edge, edge.next_down(), edge.next_up(), edge + 0.5 * cell, edge - 1e-9, edge + 1e-9] {
                assert_eq!(bucket_index(v, o, cell, n), floor(v, o, cell, n), "{v}");
            }
        }
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, f64::MAX, f64::MIN] {
            assert_eq!(bucket_index(v, o, cell, n), floor(v, o, cell, n), "{v}");
        }
    }

    /// `locate` and `near` agree on random meshes with holes, at points on,
    /// a hair off and away from the triangles' edges: `locate` answers
    /// exactly where `near` finds a triangle within the tolerance, and
    /// answers with one of those.
    #[test]
    fn locate_answers_where_near_finds_a_triangle() {
        let mut next = unit_draws(0x51f1_5eed_0bad_cafe);
        let (mut answered, mut refused) = (0, 0);
        for _ in 0..40 {
            // A 12 × 9 grid of jittered vertices, a third of its triangles
            // dropped (holes).
            let (w, h) = (12usize, 9usize);
            let mut verts: Vec<MeshVertex> = (0..=h)
                .flat_map(|i| (0..=w).map(move |j| (i, j)))
                .map(|(i, j)| v(j as f64 + 0.6 * (next() - 0.5), i as f64 + 0.6 * (next() - 0.5), 50.0 * next()))
                .collect();
            let at = |i: usize, j: usize| (i * (w + 1) + j) as u32;
            let mut tris = Vec::new();
            for i in 0..h {
                for j in 0..w {
                    for t in [[at(i, j), at(i + 1, j), at(i + 1, j + 1)], [at(i, j), at(i + 1, j + 1), at(i, j + 1)]] {
                        if next() > 0.33 {
                            tris.push(t);
                        }
                    }
                }
            }
            // Inner vertices near a bucket edge (x = origin + k · cell) moved
            // 10⁻⁸ to one side of it: a point 1.1 · 10⁻⁸ across is then
            // near triangles that may lie wholly in the other bucket. (The
            // buckets are kept as they were: moving vertices changes the
            // median triangle they are sized by, not the box.)
            let index = LocatorIndex::new(&verts, &tris);
            let (x0, cell) = (index.origin.0, index.cell);
            let mut across = Vec::new();
            for (n, p) in verts.iter_mut().enumerate() {
                let (i, j) = (n / (w + 1), n % (w + 1));
                let edge = x0 + ((p.x - x0) / cell).round() * cell;
                if i > 0 && i < h && j > 0 && j < w && (p.x - edge).abs() < 0.2 {
                    let side = if next() < 0.5 { -1.0 } else { 1.0 };
                    p.x = edge + side * 1e-8;
                    across.push((p.x - side * 1.1e-8, p.z));
                }
            }
            let index = LocatorIndex::with_side(&verts, &tris, cell);
            assert_eq!((index.origin.0, index.cell), (x0, cell));
            let loc = SurfaceLocator::with_index(&verts, &tris, &index);
            for &(x, z) in &across {
                let near = loc.near(x, z, 1e-6);
                assert_eq!(loc.locate(x, z, 1e-6).is_some(), !near.is_empty(), "({x}, {z}): near {near:?}");
            }
            for _ in 0..2000 {
                let tri = tris[(next() * tris.len() as f64) as usize].map(|k| verts[k as usize]);
                let k = (next() * 3.0) as usize % 3;
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let t = next();
                let (dx, dz) = (b.x - a.x, b.z - a.z);
                let len = (dx * dx + dz * dz).sqrt();
                // On the edge, a hair either side of it (within and beyond
                // the tolerance), or anywhere over the grid.
                let off = [0.0, 5e-7, -5e-7, 1.5e-6, -1.5e-6, 0.3][(next() * 6.0) as usize % 6];
                let (x, z) = if off == 0.3 {
                    (next() * w as f64, next() * h as f64)
                } else {
                    (a.x + t * dx - off * dz / len, a.z + t * dz + off * dx / len)
                };
                let near = loc.near(x, z, 1e-6);
                match loc.locate(x, z, 1e-6) {
                    Some((t, _)) => {
                        assert!(near.iter().any(|n| n.0 == t), "({x}, {z}): locate gave {t}, near {near:?}");
                        answered += 1;
                    }
                    None => {
                        assert!(near.is_empty(), "({x}, {z}): locate gave nothing, near {near:?}");
                        refused += 1;
                    }
                }
            }
        }
        assert!(answered > 20_000 && refused > 5_000, "{answered} answered, {refused} refused");
    }

    /// The locator's shortcut turns away only triangles `barycentric` puts
    /// more than the tolerance outside, and does turn those beyond an edge
    /// away: over random triangles (slivers among them, either orientation)
    /// and points near and on them, at the tolerances `verify` and the
    /// mesher use.
    #[test]
    fn surely_beyond_turns_away_only_what_barycentric_puts_outside() {
        let mut next = unit_draws(0x9e37_79b9_7f4a_7c15);
        let (mut turned, mut beyond) = (0, 0);
        for n in 0..200_000 {
            let o = (4000.0 * next(), 4000.0 * next());
            let mut corner = || v(o.0 + 8.0 * next(), o.1 + 8.0 * next(), 0.0);
            let (a, b, mut c) = (corner(), corner(), corner());
            if n % 5 == 0 {
                // A sliver: c a hair off the line through a and b.
                let t = next();
                c = v(a.x + t * (b.x - a.x) + 1e-7 * next(), a.z + t * (b.z - a.z), 0.0);
            }
            let (x, z) = if n % 3 == 0 {
                // On an edge, within rounding.
                let t = next();
                (a.x + t * (b.x - a.x), a.z + t * (b.z - a.z) + 1e-9 * (next() - 0.5))
            } else {
                (o.0 - 2.0 + 12.0 * next(), o.1 - 2.0 + 12.0 * next())
            };
            let tol = [1e-9, 1e-6, 1e-4, 0.01][n % 4];
            let outside = barycentric(&a, &b, &c, x, z).0;
            if surely_beyond(&a, &b, &c, x, z, tol) {
                turned += 1;
                assert!(outside > tol, "turned away at {outside} ≤ {tol}: {a:?} {b:?} {c:?} ({x}, {z})");
            }
            beyond += usize::from(outside > 0.1);
        }
        // Most points well outside are turned away without a division.
        assert!(turned * 10 > beyond * 9, "{turned} turned away of {beyond} beyond 0.1");
    }

    /// Every triangle goes into each bucket it touches and only those near
    /// it, and `locate` answers as a search over every triangle would: on
    /// fans of long, thin triangles across the grid (what pieces cut along
    /// dividing lines make), tiny ones, and zero-area ones, at points
    /// inside, on edges and corners, and a hair outside.
    #[test]
    fn locate_agrees_with_a_search_over_every_triangle() {
        let mut next = unit_draws(0x7a1e_b0c5_e77e_d6e5);
        for round in 0..30 {
            let mut verts = Vec::new();
            let mut tris = Vec::new();
            let mut add = |p: [(f64, f64); 3], verts: &mut Vec<MeshVertex>, h: [f64; 3]| {
                let n = verts.len() as u32;
                verts.extend((0..3).map(|k| v(p[k].0, p[k].1, h[k])));
                tris.push([n, n + 1, n + 2]);
            };
            for _ in 0..40 {
                let h = [100.0 * next(), 100.0 * next(), 100.0 * next()];
                let (x, z) = (64.0 * next(), 64.0 * next());
                let p = match (next() * 4.0) as usize {
                    // Long and thin, any direction.
                    0 => {
                        let (dx, dz) = (64.0 * next() - 32.0, 64.0 * next() - 32.0);
                        [(x, z), (x + dx, z + dz), (x + dx + 0.05 * next(), z + dz + 0.05 * next())]
                    }
                    // Tiny.
                    1 => [(x, z), (x + 0.01 * next(), z), (x, z + 0.01 * next())],
                    // Zero area: three points on a line.
                    2 => [(x, z), (x + 3.0, z + 1.0), (x + 6.0, z + 2.0)],
                    _ => [(x, z), (x + 8.0 * next(), z + 8.0 * next()), (x - 8.0 * next(), z + 8.0 * next())],
                };
                add(p, &mut verts, h);
            }
            let index = LocatorIndex::new(&verts, &tris);
            let loc = SurfaceLocator::with_index(&verts, &tris, &index);
            let tol = if round % 2 == 0 { 1e-6 } else { 0.02 };
            for _ in 0..500 {
                let t = (next() * tris.len() as f64) as usize % tris.len();
                let [a, b, c] = tris[t].map(|k| verts[k as usize]);
                let (u, w) = (next(), next());
                let (u, w) = if u + w > 1.0 { (1.0 - u, 1.0 - w) } else { (u, w) };
                let (mut x, mut z) = (a.x + u * (b.x - a.x) + w * (c.x - a.x), a.z + u * (b.z - a.z) + w * (c.z - a.z));
                match (next() * 4.0) as usize {
                    0 => (x, z) = (a.x + u * (b.x - a.x), a.z + u * (b.z - a.z)),
                    1 => (x, z) = (c.x, c.z),
                    2 => (x, z) = (x + 2.0 * tol * (next() - 0.5), z + 2.0 * tol * (next() - 0.5)),
                    _ => {}
                }
                // Every triangle holding the point is in its bucket.
                let own = index.bucket(index.bucket_at(x, z));
                let all: Vec<(usize, f64, f64, f64)> = tris
                    .iter()
                    .enumerate()
                    .map(|(t, tri)| {
                        let [a, b, c] = tri.map(|k| verts[k as usize]);
                        let (outside, h) = barycentric(&a, &b, &c, x, z);
                        let area = ((b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z)).abs();
                        (t, outside, h, area)
                    })
                    .collect();
                for &(t, outside, _, _) in &all {
                    if outside == 0.0 {
                        assert!(own.contains(&(t as u32)), "round {round}: triangle {t} holds ({x}, {z})");
                    }
                }
                // What a search over every triangle answers: the largest
                // holding the point, first in order; else the nearest
                // within the tolerance.
                let inside =
                    all.iter().filter(|e| e.1 == 0.0).fold(None::<&(usize, f64, f64, f64)>, |best, e| match best {
                        Some(b) if b.3 >= e.3 => Some(b),
                        _ => Some(e),
                    });
                let nearest = all.iter().filter(|e| e.1.is_finite()).map(|e| e.1).fold(f64::INFINITY, f64::min);
                match (loc.locate(x, z, tol), inside) {
                    (Some((t, h)), Some(e)) => assert_eq!((t as usize, h), (e.0, e.2), "round {round} ({x}, {z})"),
                    (Some((t, _)), None) => {
                        assert!(nearest <= tol, "round {round} ({x}, {z})");
                        assert_eq!(all[t as usize].1, nearest, "round {round} ({x}, {z})");
                    }
                    (None, found) => {
                        assert!(
                            found.is_none() && nearest > tol,
                            "round {round} ({x}, {z}): missed {found:?}, {nearest}"
                        )
                    }
                }
            }
        }
    }
}
