//! The curved frame: every vertex of a chunk at the WGS 84 position of its
//! grid point and height, in the east-north-up frame at the grid centre
//! (the frame the root `transform` takes to ECEF with no scale or shear).
//!
//! A flat chunk triangle between three such vertices is a chord of the
//! curved surface, so it sags below the surface the grid heights describe;
//! the mesher keeps that sag inside δ ([`Globe::margin_m`]) and `verify`
//! measures the result along the ellipsoid normal at every sample.

use super::{EnuFrame, NotPlaced, SourceCrs, ecef, keeps_its_degrees, probe_samples};
use crate::heightfield::Georef;

/// The smallest radius of curvature of the WGS 84 ellipsoid: the meridian's
/// at the equator, a(1 − e²), metres.
pub const MIN_RADIUS_M: f64 = 6_335_439.327;

/// The grid-to-Earth map of a placed grid, as the chunks are written in
/// the curved frame.
pub struct Globe {
    source: SourceCrs,
    origin: [f64; 2],
    step: [f64; 2],
    /// Longitude and latitude are the grid's own degrees (a WGS 84
    /// geographic grid): no projection library call per vertex.
    degrees: bool,
    frame: EnuFrame,
    /// World x and z (glTF, metres) of the grid centre.
    centre: [f64; 2],
    /// Longitude and latitude of the grid centre, degrees.
    pub lon_lat: [f64; 2],
    /// For a grid of degrees, per row and per column what a vertex at a
    /// sample needs ([`Row`], [`Col`]): no trigonometry, and the frame's
    /// rotation folded into each column.
    rows: Vec<Row>,
    cols: Vec<Col>,
    /// The frame's rotation applied to its origin, and its column for the
    /// ECEF z axis: ENU = R·p − R·o.
    rotated_origin: [f64; 3],
    frame_z: [f64; 3],
    /// Bounds on the second derivative of [`Globe::world`] with respect to
    /// grid metres (x = column · s_x, z = row · s_z), 1/m: its part along
    /// the ellipsoid normal (the Earth's curvature, which makes a chord
    /// sag) and across it (the projection's own bending, which moves a
    /// chord sideways).
    pub curvature: [f64; 2],
}

/// A row of a grid of degrees: sin φ, cos φ, and N cos φ and N(1 − e²) sin φ
/// (N the prime vertical radius).
#[derive(Clone, Copy, Debug)]
struct Row {
    sin: f64,
    cos: f64,
    n_cos: f64,
    n_sin: f64,
}

/// A column of a grid of degrees: sin λ, cos λ, and the frame's rotation of
/// the ECEF direction (cos λ, sin λ, 0).
#[derive(Clone, Copy, Debug)]
struct Col {
    sin: f64,
    cos: f64,
    rotated: [f64; 3],
}

impl Globe {
    /// The map of the `width` × `height` grid of `georef`, whose samples the
    /// tileset puts `spacing_m` apart; refused where the CRS is unknown or
    /// some sample on its border or inside does not come back as a point on
    /// the Earth.
    pub fn of_grid(georef: &Georef, width: usize, height: usize, spacing_m: [f64; 2]) -> Result<Globe, NotPlaced> {
        let source = SourceCrs::of(&georef.crs, georef.definition.as_deref())?;
        let (ci, cj) = ((height - 1) as f64 / 2.0, (width - 1) as f64 / 2.0);
        let src = [georef.origin[0] + georef.step[0] * cj, georef.origin[1] + georef.step[1] * ci];
        let name = source.name.clone();
        let off = || NotPlaced::OffTheEarth { name: name.clone(), x: src[0], y: src[1] };
        let (lat, lon) = source.to_wgs84(src).ok_or_else(off)?;
        // As `Placement::of_grid` decides.
        let degrees = keeps_its_degrees(&source, src, (lat, lon));
        let (lat, lon) = if degrees { (src[1], src[0]) } else { (lat, lon) };
        let mut globe = Globe {
            source,
            origin: georef.origin,
            step: georef.step,
            degrees,
            frame: EnuFrame::new(lat, lon),
            centre: [cj * spacing_m[0], ci * spacing_m[1]],
            lon_lat: [lon, lat],
            curvature: [0.0; 2],
            rows: Vec::new(),
            cols: Vec::new(),
            rotated_origin: [0.0; 3],
            frame_z: [0.0; 3],
        };
        let lat_edges = [0.0, (height - 1) as f64].map(|i| globe.origin[1] + globe.step[1] * i);
        if globe.source.geographic && lat_edges.iter().any(|l| l.abs() >= 90.0 - 1e-9) {
            return Err(NotPlaced::AtPole { name });
        }
        if globe.source.geographic && (width - 1) as f64 * globe.step[0].abs() >= 360.0 - 1e-9 {
            return Err(NotPlaced::WholeTurn { name });
        }
        for (i, j) in probe_samples(width, height) {
            if globe.lat_lon(j as f64, i as f64).is_none() {
                return Err(off());
            }
        }
        globe.curvature = globe.measure_curvature(width, height, spacing_m);
        if degrees {
            let e2 = super::WGS84_E2;
            globe.rows = (0..height)
                .map(|i| {
                    let (sp, cp) = (georef.origin[1] + georef.step[1] * i as f64).to_radians().sin_cos();
                    let n = super::WGS84_A / (1.0 - e2 * sp * sp).sqrt();
                    Row { sin: sp, cos: cp, n_cos: n * cp, n_sin: n * (1.0 - e2) * sp }
                })
                .collect();
            let axes = globe.frame.axes;
            globe.cols = (0..width)
                .map(|j| {
                    let (sl, cl) = (georef.origin[0] + georef.step[0] * j as f64).to_radians().sin_cos();
                    Col { sin: sl, cos: cl, rotated: axes.map(|a| a[0] * cl + a[1] * sl) }
                })
                .collect();
            globe.rotated_origin = axes.map(|a| (0..3).map(|k| a[k] * globe.frame.origin[k]).sum());
            globe.frame_z = axes.map(|a| a[2]);
        }
        Ok(globe)
    }

    /// Latitude and longitude, degrees, of grid point (column `j`, row `i`).
    pub fn lat_lon(&self, j: f64, i: f64) -> Option<(f64, f64)> {
        let src = [self.origin[0] + self.step[0] * j, self.origin[1] + self.step[1] * i];
        if self.degrees {
            return (src[1].abs() <= 90.0).then_some((src[1], src[0]));
        }
        self.source.to_wgs84(src)
    }

    /// World position (glTF: x east, y up, z south, metres, in the ENU frame
    /// at the grid centre shifted so that the centre keeps its flat place)
    /// of grid point (`j`, `i`) at ellipsoidal height `h`; NaN where the
    /// projection has no inverse there.
    pub fn world(&self, j: f64, i: f64, h: f64) -> [f64; 3] {
        match self.at_sample(j, i) {
            Some((row, col)) => self.world_from(row, col, h),
            None => {
                let Some((lat, lon)) = self.lat_lon(j, i) else { return [f64::NAN; 3] };
                self.placed(self.frame.enu(ecef(lat, lon, h)))
            }
        }
    }

    /// [`Globe::world`] of sample (`j`, `i`), the same bits, without
    /// testing that the place is a sample.
    #[inline]
    pub fn world_at_sample(&self, j: u32, i: u32, h: f64) -> [f64; 3] {
        match (self.rows.get(i as usize), self.cols.get(j as usize)) {
            (Some(row), Some(col)) => self.world_from(row, col, h),
            _ => self.world(f64::from(j), f64::from(i), h),
        }
    }

    #[inline]
    fn world_from(&self, row: &Row, col: &Col, h: f64) -> [f64; 3] {
        // ECEF (x, y, z) = ((N + h) cos φ (cos λ, sin λ), (N(1 − e²) + h) sin φ).
        let (across, z) = (row.n_cos + h * row.cos, row.n_sin + h * row.sin);
        self.placed([0, 1, 2].map(|k| across * col.rotated[k] + z * self.frame_z[k] - self.rotated_origin[k]))
    }

    /// World position of a point at `enu` in the frame at the grid centre.
    #[inline]
    fn placed(&self, enu: [f64; 3]) -> [f64; 3] {
        [self.centre[0] + enu[0], enu[2], self.centre[1] - enu[1]]
    }

    /// Unit east, north and up at grid point (`j`, `i`), in ECEF; NaN
    /// where the projection has no inverse there.
    fn local_axes(&self, j: f64, i: f64) -> [[f64; 3]; 3] {
        match self.at_sample(j, i) {
            Some((row, col)) => {
                let (sp, cp, sl, cl) = (row.sin, row.cos, col.sin, col.cos);
                [[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]]
            }
            None => self.lat_lon(j, i).map_or([[f64::NAN; 3]; 3], |(lat, lon)| EnuFrame::new(lat, lon).axes),
        }
    }

    /// The row's and column's tables where (`j`, `i`) is a sample of a grid
    /// of degrees.
    #[inline]
    fn at_sample(&self, j: f64, i: f64) -> Option<(&Row, &Col)> {
        // Whole and not negative: the casts saturate, so anything else
        // comes back changed (compared so, with no call to `trunc`).
        let (jj, ii) = (j as usize, i as usize);
        if jj as f64 != j || ii as f64 != i {
            return None;
        }
        Some((self.rows.get(ii)?, self.cols.get(jj)?))
    }

    /// The east, up and south unit vectors at grid point (`j`, `i`), in
    /// world coordinates: what a flat-frame normal is expressed in there.
    pub fn axes(&self, j: f64, i: f64) -> [[f64; 3]; 3] {
        let local = self.local_axes(j, i);
        let world = |v: [f64; 3]| {
            let [e, n, u] = self.frame.axes.map(|a| a[0] * v[0] + a[1] * v[1] + a[2] * v[2]);
            [e, u, -n]
        };
        let [east, north, up] = local.map(world);
        [east, up, north.map(|c| -c)]
    }

    /// A grid-frame unit normal `n` (x east, y up, z south, as
    /// `mesh::dem_normal` gives it) turned to world coordinates at grid
    /// point (`j`, `i`): what [`Globe::axes`] does for every vertex of a
    /// curved chunk, in ECEF first so that the frame's rotation is applied
    /// once. Both turns are orthonormal, so the length stays 1 without a
    /// square root.
    pub fn turn_normal(&self, j: f64, i: f64, n: [f32; 3]) -> [f32; 3] {
        let [east, north, up] = self.local_axes(j, i);
        let [e, u, s] = n.map(f64::from);
        let q = [0, 1, 2].map(|c| e * east[c] + u * up[c] - s * north[c]);
        let [x, y, z] = self.frame.axes.map(|a| a[0] * q[0] + a[1] * q[1] + a[2] * q[2]);
        [x as f32, z as f32, -y as f32]
    }

    /// How far, at most, a chunk triangle written between the world
    /// positions of its corners strays from the surface its grid heights
    /// describe, along the normal, for a triangle held by a circle of
    /// squared radius `r2` (grid metres²) and of planar slope `slope`:
    /// linear interpolation of a map with second derivative κ misses it by
    /// κ·r²/2. Along the normal that is the sag (the normal part of κ);
    /// across it, the projection's bending and, with heights, 2·slope/R
    /// (the normal turns by 1/R per metre), which moves a surface of that
    /// slope by slope times it.
    pub fn margin_m(curvature: [f64; 2], r2: f64, slope: f64) -> f64 {
        let [normal, across] = curvature;
        r2 / 2.0 * (normal + slope * (across + slope * (2.0 / MIN_RADIUS_M)))
    }

    /// The largest second derivative of `world` (at height 0) over a 9 × 9
    /// lattice of the grid, along the normal and across it, by second
    /// differences a sixteenth of the grid's narrower side apart, with a
    /// quarter more for what lies between lattice points and heights up to
    /// 10 km.
    fn measure_curvature(&self, width: usize, height: usize, spacing_m: [f64; 2]) -> [f64; 2] {
        let extent = [(width - 1) as f64 * spacing_m[0], (height - 1) as f64 * spacing_m[1]];
        let d = (extent[0].min(extent[1]) / 16.0).max(1e-3);
        let f = |x: f64, z: f64| self.world(x / spacing_m[0], z / spacing_m[1], 0.0);
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        // The largest |Q(u)| over unit u of a quadratic form whose
        // coefficients are bounded by xx, zz and xz.
        let largest = |xx: f64, zz: f64, xz: f64| {
            (xx.abs() + zz.abs()) / 2.0 + (((xx.abs() - zz.abs()) / 2.0).powi(2) + xz * xz).sqrt()
        };
        let mut worst = [0.0f64; 2];
        for a in 0..9 {
            for b in 0..9 {
                let at = |t: f64, e: f64| if e > 2.0 * d { d + t * (e - 2.0 * d) } else { e / 2.0 };
                let (x, z) = (at(a as f64 / 8.0, extent[0]), at(b as f64 / 8.0, extent[1]));
                let (dx, dz) = (d.min(x.max(extent[0] - x)).max(1e-3), d.min(z.max(extent[1] - z)).max(1e-3));
                let c = f(x, z);
                let up = self.axes(x / spacing_m[0], z / spacing_m[1])[1];
                let second = |p: [f64; 3], q: [f64; 3], s: f64| [0, 1, 2].map(|k| (p[k] + q[k] - 2.0 * c[k]) / (s * s));
                let xx = second(f(x + dx, z), f(x - dx, z), dx);
                let zz = second(f(x, z + dz), f(x, z - dz), dz);
                let (pp, pm, mp, mm) = (f(x + dx, z + dz), f(x + dx, z - dz), f(x - dx, z + dz), f(x - dx, z - dz));
                let xz = [0, 1, 2].map(|k| (pp[k] - pm[k] - mp[k] + mm[k]) / (4.0 * dx * dz));
                let along = |v: [f64; 3]| v[0] * up[0] + v[1] * up[1] + v[2] * up[2];
                let across = |v: [f64; 3]| {
                    let a = along(v);
                    norm([v[0] - a * up[0], v[1] - a * up[1], v[2] - a * up[2]])
                };
                let parts = [largest(along(xx), along(zz), along(xz)), largest(across(xx), across(zz), across(xz))];
                for k in 0..2 {
                    if parts[k].is_finite() {
                        worst[k] = worst[k].max(parts[k]);
                    }
                }
            }
        }
        let grow = 1.25 * (1.0 + 1e4 / MIN_RADIUS_M);
        [worst[0].max(1.0 / MIN_RADIUS_M) * grow, worst[1] * grow + 1e-3 / MIN_RADIUS_M]
    }
}

/// WGS 84 latitude, longitude (degrees) and ellipsoidal height of an ECEF
/// point (Bowring's iteration, to well under a micrometre near the Earth).
pub fn geodetic(p: [f64; 3]) -> (f64, f64, f64) {
    let e2 = super::WGS84_E2;
    let a = super::WGS84_A;
    let lon = p[1].atan2(p[0]);
    let r = p[0].hypot(p[1]);
    let mut lat = p[2].atan2(r * (1.0 - e2));
    for _ in 0..8 {
        let (s, c) = lat.sin_cos();
        let n = a / (1.0 - e2 * s * s).sqrt();
        let h = r * c + p[2] * s - a * (1.0 - e2 * s * s).sqrt();
        lat = p[2].atan2(r * (1.0 - e2 * n / (n + h)));
    }
    let (s, c) = lat.sin_cos();
    let h = r * c + p[2] * s - a * (1.0 - e2 * s * s).sqrt();
    (lat.to_degrees(), lon.to_degrees(), h)
}

/// The unit normal of the ellipsoid (ECEF) at a latitude/longitude, degrees.
pub fn up(lat_deg: f64, lon_deg: f64) -> [f64; 3] {
    EnuFrame::new(lat_deg, lon_deg).axes[2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesy::distance;
    use crate::heightfield::Crs;

    fn geographic(origin: [f64; 2], step: f64, n: usize) -> (Georef, [f64; 2]) {
        let g = Georef {
            crs: Crs::Geographic { epsg: Some(4326) },
            origin,
            step: [step, -step],
            local_tangent: None,
            definition: None,
        };
        let lat0 = origin[1] - step * (n - 1) as f64 / 2.0;
        let (mx, mz) = crate::heightfield::metres_per_degree(lat0);
        (g, [step * mx, step * mz])
    }

    #[test]
    fn a_turned_normal_is_the_grid_normal_in_the_local_axes_and_stays_unit() {
        let (g, s) = geographic([-10.0, 60.0], 0.5, 81);
        let globe = Globe::of_grid(&g, 81, 81, s).unwrap();
        let l = (0.3f64 * 0.3 + 1.0 + 0.2 * 0.2).sqrt();
        let n = [0.3 / l, 1.0 / l, -0.2 / l].map(|c| c as f32);
        for (j, i) in [(0.0, 0.0), (80.0, 0.0), (40.0, 40.0), (17.0, 63.0), (12.5, 3.0)] {
            let axes = globe.axes(j, i);
            let by_axes = [0, 1, 2].map(|c| (0..3).map(|a| f64::from(n[a]) * axes[a][c]).sum::<f64>());
            let turned = globe.turn_normal(j, i, n);
            let len = turned.iter().map(|&c| f64::from(c).powi(2)).sum::<f64>().sqrt();
            assert!((len - 1.0).abs() < 1e-6, "length {len} at ({j}, {i})");
            for c in 0..3 {
                assert!((f64::from(turned[c]) - by_axes[c]).abs() < 1e-6, "{turned:?} against {by_axes:?}");
            }
        }
    }

    #[test]
    fn geodetic_undoes_ecef() {
        for (lat, lon, h) in [(0.0, 0.0, 0.0), (45.5, -122.3, 2500.0), (-89.9, 170.0, -400.0), (89.99, -179.9, 8000.0)]
        {
            let (la, lo, hh) = geodetic(ecef(lat, lon, h));
            assert!((la - lat).abs() < 1e-11 && (lo - lon).abs() < 1e-9 && (hh - h).abs() < 1e-6, "{la} {lo} {hh}");
        }
    }

    #[test]
    fn the_centre_keeps_its_flat_place_and_the_frame_is_the_earth() {
        let (g, s) = geographic([-10.0, 20.0], 0.5, 81);
        let globe = Globe::of_grid(&g, 81, 81, s).unwrap();
        let c = globe.world(40.0, 40.0, 0.0);
        assert!((c[0] - 40.0 * s[0]).abs() < 1e-6 && c[1].abs() < 1e-6 && (c[2] - 40.0 * s[1]).abs() < 1e-6, "{c:?}");
        // Two corners 40° apart are their true chord apart, and a height
        // moves a point along the ellipsoid normal there.
        let (a, b) = (globe.world(0.0, 0.0, 0.0), globe.world(80.0, 80.0, 0.0));
        let truth = distance(ecef(20.0, -10.0, 0.0), ecef(-20.0, 30.0, 0.0));
        assert!((distance(a, b) - truth).abs() < 1e-6, "{} against {truth}", distance(a, b));
        let up = globe.axes(0.0, 0.0)[1];
        let lifted = globe.world(0.0, 0.0, 1000.0);
        assert!((0..3).all(|k| (lifted[k] - a[k] - 1000.0 * up[k]).abs() < 1e-6));
    }

    #[test]
    fn curvature_is_the_earth_s_on_a_small_grid_and_more_where_degrees_shear() {
        let (g, s) = geographic([7.0, 46.01], 1e-4, 101);
        let [normal, across] = Globe::of_grid(&g, 101, 101, s).unwrap().curvature;
        // Along the normal, the Earth's 1/R; across it, tan φ/R (1.04/R at
        // 46°) twice over on a grid of degrees: a parallel bends towards
        // the pole, and east metres shrink northwards (1.68/R together).
        assert!(normal > 1.0 / 6.4e6 && normal < 1.5 / 6.3e6, "{normal}");
        assert!(across > 1.5 / 6.4e6 && across < 2.5 / 6.3e6, "{across}");
        let (g, s) = geographic([0.0, 80.0], 0.1, 201);
        let north = Globe::of_grid(&g, 201, 201, s).unwrap().curvature;
        assert!(north[1] > 2.0 * across, "{north:?} against {across}");
    }
}
