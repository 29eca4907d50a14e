//! Where the tileset sits on the Earth: the root `transform` of
//! `tileset.json` for a georeferenced grid.
//!
//! The chunks are in grid metres (tileset frame: x east, y north, z up; see
//! `output::tileset`). 3D Tiles clients place content in Earth-centred,
//! Earth-fixed (ECEF) WGS 84 coordinates, so the root carries a 4×4
//! transform: the local east-north-up (ENU) frame at the grid centre's
//! longitude/latitude (ellipsoidal height 0), times the linear map that takes
//! tileset metres around the grid centre to ENU metres there.
//!
//! That linear map is the derivative of "source coordinates → local ENU" at
//! the centre, taken by central differences of an exact inverse projection:
//! - geographic grids (degrees): none needed, the local tangent plane of
//!   `heightfield::LocalTangent` already is the ENU plane at the centre (the
//!   map comes out as the identity);
//! - UTM (WGS 84: EPSG 326zz north, 327zz south; NAD83: 269zz; ETRS89:
//!   258zz; NAD27: 267zz, shifted to WGS 84 by the CONUS mean geocentric
//!   offset, ±5–10 m): the inverse transverse Mercator of Karney (2011), "Transverse
//!   Mercator with an accuracy of a few nanometers", J. Geodesy 85, eqs. 7,
//!   11, 15 and 36 (Krüger's series to n⁶, nanometre accuracy within a
//!   zone); the map then holds the grid's meridian convergence γ (grid north
//!   against true north) and its point scale k (grid metres are k·ground
//!   metres), so both are undone;
//! - Web Mercator (EPSG 3857 and aliases): the spherical inverse.
//!
//! Every other or unknown CRS gets no transform (the tileset stays in its
//! local frame, as before). What a planar tileset cannot be: the terrain
//! stays flat on the centre's tangent plane, so ground d metres from the
//! centre floats d²/(2R) above the ellipsoid (2 m at 5 km); heights are the
//! DEM's (orthometric, above the geoid) used as ellipsoidal heights (the
//! geoid undulation, up to ±100 m, is not applied: no geoid model ships);
//! and NAD83 or ETRS89 are taken as WGS 84 (1–2 m apart).

use serde::{Deserialize, Serialize};

use crate::heightfield::{Crs, Georef};

/// WGS 84 semi-major axis, metres.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS 84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// The placement of a grid on the WGS 84 ellipsoid (tileset extras).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// Longitude of the grid centre (the ENU origin), degrees east.
    pub lon_deg: f64,
    /// Latitude of the grid centre, degrees north.
    pub lat_deg: f64,
    /// Ellipsoidal height of the ENU origin, metres (0: tileset heights are
    /// taken as heights above the ellipsoid).
    pub height_m: f64,
    /// The grid centre in tileset coordinates (east, north, up), metres: the
    /// point the transform puts at the ENU origin.
    pub centre: [f64; 3],
    /// The linear part of the transform: east and north metres of the ENU
    /// frame per tileset metre along x (first column) and y (second), at
    /// the centre, row-major `[[∂E/∂x, ∂E/∂y], [∂N/∂x, ∂N/∂y]]`. The
    /// identity for geographic grids; for UTM a rotation by the convergence
    /// times 1/scale.
    pub enu_per_tileset_m: [[f64; 2]; 2],
    /// Grid convergence at the centre, degrees: the angle from true north to
    /// grid north (the tileset's y axis), positive clockwise (0 for
    /// geographic and Web Mercator).
    pub convergence_deg: f64,
    /// Point scale at the centre: grid metres per ground metre along the
    /// tileset's x axis (1 for geographic grids; UTM scales equally in every
    /// direction, Web Mercator does not on the ellipsoid).
    pub scale: f64,
    /// How the transform was made, and what it leaves out.
    pub method: String,
}

impl Placement {
    /// Where the grid described by `georef` (`width` × `height` samples,
    /// `spacing_m` between them on the ground as the tileset has it) sits on
    /// the Earth; `None` when its CRS is not one this module can invert.
    pub fn of_grid(georef: &Georef, width: usize, height: usize, spacing_m: [f64; 2]) -> Option<Placement> {
        let inverse = Inverse::for_crs(&georef.crs)?;
        let [dx, dy] = georef.step;
        if !(dx.is_finite() && dy.is_finite() && dx != 0.0 && dy != 0.0) {
            return None;
        }
        // Grid centre in source units, and in tileset metres (x east, y north).
        let (ci, cj) = ((height - 1) as f64 / 2.0, (width - 1) as f64 / 2.0);
        let src = [georef.origin[0] + dx * cj, georef.origin[1] + dy * ci];
        let centre = [cj * spacing_m[0], -ci * spacing_m[1], 0.0];
        let (lat, lon) = inverse.geodetic(src)?;
        if !(lat.abs() < 90.0 && lon.is_finite()) {
            return None;
        }
        // Source units per tileset metre along east and north.
        let per_m = [dx.abs() / spacing_m[0], dy.abs() / spacing_m[1]];
        // Derivative of ENU(at centre) with respect to tileset metres: the
        // identity for the local tangent plane (it is the ENU plane, with the
        // centre's radii), else by central differences over ±h metres (h
        // small against the Earth, large against f64 rounding of ECEF: 1e-9 m
        // in 6.4e6 m).
        let frame = EnuFrame::new(lat, lon);
        let h = 1.0;
        let mut jac = [[1.0, 0.0], [0.0, 1.0]];
        for axis in 0..2 {
            if matches!(inverse, Inverse::Geographic) {
                break;
            }
            let mut plus = src;
            let mut minus = src;
            let sign = if axis == 0 { dx.signum() } else { -dy.signum() };
            plus[axis] += sign * h * per_m[axis];
            minus[axis] -= sign * h * per_m[axis];
            let (lp, gp) = inverse.geodetic(plus)?;
            let (lm, gm) = inverse.geodetic(minus)?;
            let a = frame.enu(ecef(lp, gp, 0.0));
            let b = frame.enu(ecef(lm, gm, 0.0));
            for row in 0..2 {
                jac[row][axis] = (a[row] - b[row]) / (2.0 * h);
            }
        }
        // For a conformal map (UTM) the derivative is a rotation times a
        // scale: grid east lies γ clockwise of true east, (cos γ, −sin γ)/k.
        let scale = 1.0 / jac[0][0].hypot(jac[1][0]);
        let convergence_deg = -jac[1][0].atan2(jac[0][0]).to_degrees();
        Some(Placement {
            lon_deg: lon,
            lat_deg: lat,
            height_m: 0.0,
            centre,
            enu_per_tileset_m: jac,
            convergence_deg,
            scale,
            method: format!(
                "{}; root transform = ENU frame at (lon, lat, height) x the derivative of that \
                 inverse at the grid centre (undoes convergence and scale) x translation by -centre; \
                 the tileset stays planar (ground d m from the centre floats d^2/2R above the \
                 ellipsoid), DEM heights are used as ellipsoidal (no geoid)",
                inverse.name()
            ),
        })
    }

    /// The root `transform`: column-major 4×4, tileset metres → ECEF metres.
    pub fn transform(&self) -> [f64; 16] {
        let frame = EnuFrame::new(self.lat_deg, self.lon_deg);
        let j = self.enu_per_tileset_m;
        let [e, n, u] = frame.axes;
        let o = ecef(self.lat_deg, self.lon_deg, self.height_m);
        let col = |a: f64, b: f64| [0, 1, 2].map(|r| a * e[r] + b * n[r]);
        let c0 = col(j[0][0], j[1][0]);
        let c1 = col(j[0][1], j[1][1]);
        let [cx, cy, cz] = self.centre;
        let t = [0, 1, 2].map(|r| o[r] - c0[r] * cx - c1[r] * cy - u[r] * cz);
        [c0[0], c0[1], c0[2], 0.0, c1[0], c1[1], c1[2], 0.0, u[0], u[1], u[2], 0.0, t[0], t[1], t[2], 1.0]
    }
}

/// An exact map from a CRS's coordinates to WGS 84 latitude/longitude.
#[derive(Clone, Copy, Debug)]
enum Inverse {
    /// Longitude/latitude degrees already.
    Geographic,
    /// UTM zone 1..=60, northern hemisphere or not, on a datum.
    Utm { zone: u32, north: bool, datum: Datum },
    /// Spherical (Web) Mercator on the WGS 84 semi-major axis.
    WebMercator,
}

impl Inverse {
    fn for_crs(crs: &Crs) -> Option<Inverse> {
        match *crs {
            // Unnamed geographic grids (SRTM .hgt, degree .asc) are WGS 84;
            // NAD83 and ETRS89 lie within 1–2 m of it. NAD27 (4267) and
            // other datums are tens to hundreds of metres away: not placed.
            Crs::Geographic { epsg: None | Some(4326 | 4269 | 4258) } => Some(Inverse::Geographic),
            Crs::Projected { epsg: Some(code) } => match code {
                32601..=32660 => Some(Inverse::Utm { zone: code - 32600, north: true, datum: DATUM_WGS84 }),
                32701..=32760 => Some(Inverse::Utm { zone: code - 32700, north: false, datum: DATUM_WGS84 }),
                26901..=26923 => Some(Inverse::Utm { zone: code - 26900, north: true, datum: DATUM_NAD83 }),
                25828..=25838 => Some(Inverse::Utm { zone: code - 25800, north: true, datum: DATUM_ETRS89 }),
                // NAD27 UTM (legacy USGS DEMs, Mount St Helens' fixture):
                // placed to the CONUS mean shift's ±5–10 m.
                26703..=26722 => Some(Inverse::Utm { zone: code - 26700, north: true, datum: DATUM_NAD27 }),
                3857 | 3785 | 900_913 | 102_100 | 102_113 => Some(Inverse::WebMercator),
                _ => None,
            },
            _ => None,
        }
    }

    fn name(&self) -> String {
        match self {
            Inverse::Geographic => "geographic degrees (WGS 84) on the local tangent plane".into(),
            Inverse::Utm { zone, north, datum } => format!(
                "UTM zone {zone}{} ({}), inverse transverse Mercator by Krüger's series to n^6 (Karney 2011)",
                if *north { "N" } else { "S" },
                datum.name
            ),
            Inverse::WebMercator => "Web Mercator, spherical inverse".into(),
        }
    }

    /// `(latitude, longitude)` in degrees of the source point `[x, y]`.
    fn geodetic(&self, p: [f64; 2]) -> Option<(f64, f64)> {
        match *self {
            Inverse::Geographic => Some((p[1], p[0])),
            Inverse::Utm { zone, north, datum } => {
                let lon0 = f64::from(zone) * 6.0 - 183.0;
                let northing = if north { p[1] } else { p[1] - 10_000_000.0 };
                let (lat, lon) = tm_inverse_on(datum.ellipsoid, p[0] - 500_000.0, northing, lon0, UTM_K0);
                if datum.to_wgs84_m == [0.0; 3] {
                    return Some((lat, lon));
                }
                let q = ecef_on(datum.ellipsoid, lat, lon, 0.0);
                Some(geodetic_of_ecef([0, 1, 2].map(|a| q[a] + datum.to_wgs84_m[a])))
            }
            Inverse::WebMercator => Some(((p[1] / WGS84_A).sinh().atan().to_degrees(), (p[0] / WGS84_A).to_degrees())),
        }
    }
}

/// UTM's central scale factor.
pub const UTM_K0: f64 = 0.9996;

/// An ellipsoid: semi-major axis (m) and flattening.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-major axis, metres.
    pub a: f64,
    /// Flattening.
    pub f: f64,
}

/// WGS 84 (GRS 80 differs from it by 0.1 mm in the semi-minor axis).
pub const WGS84: Ellipsoid = Ellipsoid { a: WGS84_A, f: WGS84_F };
/// Clarke 1866, NAD27's ellipsoid (a = 6 378 206.4 m, b = 6 356 583.8 m).
pub const CLARKE_1866: Ellipsoid = Ellipsoid { a: 6_378_206.4, f: 1.0 - 6_356_583.8 / 6_378_206.4 };

/// A datum as this module uses it: its ellipsoid and the geocentric shift
/// that takes its ECEF coordinates to WGS 84's.
#[derive(Clone, Copy, Debug)]
struct Datum {
    name: &'static str,
    ellipsoid: Ellipsoid,
    to_wgs84_m: [f64; 3],
}

const DATUM_WGS84: Datum = Datum { name: "WGS 84", ellipsoid: WGS84, to_wgs84_m: [0.0; 3] };
const DATUM_NAD83: Datum = Datum { name: "NAD83 as WGS 84", ellipsoid: WGS84, to_wgs84_m: [0.0; 3] };
const DATUM_ETRS89: Datum = Datum { name: "ETRS89 as WGS 84", ellipsoid: WGS84, to_wgs84_m: [0.0; 3] };
/// NAD27 → WGS 84, the mean for the conterminous US (NIMA TR8350.2, table
/// B.1, "NAS-C": ±5 m, ±5 m, ±6 m); NADCON's grids would do better (0.15 m)
/// but do not ship.
const DATUM_NAD27: Datum = Datum {
    name: "NAD27 to WGS 84 by the CONUS mean shift (-8, 160, 176) m, +-5-10 m",
    ellipsoid: CLARKE_1866,
    to_wgs84_m: [-8.0, 160.0, 176.0],
};

/// Krüger series coefficients for an ellipsoid, from its third flattening
/// n: the rectifying radius A, and α (forward) and β (inverse), Karney
/// (2011) eqs. 14, 35 and 36.
struct Kruger {
    a_rect: f64,
    alpha: [f64; 6],
    beta: [f64; 6],
    e: f64,
}

fn kruger(ell: Ellipsoid) -> Kruger {
    let f = ell.f;
    let n = f / (2.0 - f);
    let (n2, n3) = (n * n, n * n * n);
    let (n4, n5, n6) = (n3 * n, n3 * n2, n3 * n3);
    let a_rect = ell.a / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0 + n6 / 256.0);
    let alpha = [
        n / 2.0 - 2.0 * n2 / 3.0 + 5.0 * n3 / 16.0 + 41.0 * n4 / 180.0 - 127.0 * n5 / 288.0 + 7891.0 * n6 / 37800.0,
        13.0 * n2 / 48.0 - 3.0 * n3 / 5.0 + 557.0 * n4 / 1440.0 + 281.0 * n5 / 630.0 - 1_983_433.0 * n6 / 1_935_360.0,
        61.0 * n3 / 240.0 - 103.0 * n4 / 140.0 + 15061.0 * n5 / 26880.0 + 167_603.0 * n6 / 181_440.0,
        49561.0 * n4 / 161_280.0 - 179.0 * n5 / 168.0 + 6_601_661.0 * n6 / 7_257_600.0,
        34729.0 * n5 / 80640.0 - 3_418_889.0 * n6 / 1_995_840.0,
        212_378_941.0 * n6 / 319_334_400.0,
    ];
    let beta = [
        n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0 - n4 / 360.0 - 81.0 * n5 / 512.0 + 96199.0 * n6 / 604_800.0,
        n2 / 48.0 + n3 / 15.0 - 437.0 * n4 / 1440.0 + 46.0 * n5 / 105.0 - 1_118_711.0 * n6 / 3_870_720.0,
        17.0 * n3 / 480.0 - 37.0 * n4 / 840.0 - 209.0 * n5 / 4480.0 + 5569.0 * n6 / 90720.0,
        4397.0 * n4 / 161_280.0 - 11.0 * n5 / 504.0 - 830_251.0 * n6 / 7_257_600.0,
        4583.0 * n5 / 161_280.0 - 108_847.0 * n6 / 3_991_680.0,
        20_648_693.0 * n6 / 638_668_800.0,
    ];
    let e = (f * (2.0 - f)).sqrt();
    Kruger { a_rect, alpha, beta, e }
}

/// τ′ = tan of the conformal latitude for τ = tan φ (Karney 2011, eq. 7).
fn conformal_tan(tau: f64, e: f64) -> f64 {
    let sigma = (e * (e * tau / tau.hypot(1.0)).atanh()).sinh();
    tau * sigma.hypot(1.0) - sigma * tau.hypot(1.0)
}

/// Inverse transverse Mercator on WGS 84: `(latitude, longitude)` degrees of
/// the point `x` metres east and `y` metres north of where the central
/// meridian `lon0_deg` crosses the equator, with central scale `k0`.
pub fn tm_inverse(x: f64, y: f64, lon0_deg: f64, k0: f64) -> (f64, f64) {
    tm_inverse_on(WGS84, x, y, lon0_deg, k0)
}

/// [`tm_inverse`] on another ellipsoid (latitude and longitude on it).
pub fn tm_inverse_on(ell: Ellipsoid, x: f64, y: f64, lon0_deg: f64, k0: f64) -> (f64, f64) {
    let k = kruger(ell);
    let xi = y / (k0 * k.a_rect);
    let eta = x / (k0 * k.a_rect);
    // ζ′ = ζ − Σ β_j sin 2jζ with ζ = ξ + iη (eq. 11).
    let (mut xi1, mut eta1) = (xi, eta);
    for (j, b) in k.beta.iter().enumerate() {
        let m = 2.0 * (j + 1) as f64;
        xi1 -= b * (m * xi).sin() * (m * eta).cosh();
        eta1 -= b * (m * xi).cos() * (m * eta).sinh();
    }
    // Conformal latitude and longitude on the sphere (eq. 15's inverse).
    let tau1 = xi1.sin() / eta1.sinh().hypot(xi1.cos());
    let lam = eta1.sinh().atan2(xi1.cos());
    // τ from τ′ by Newton's method (eq. 19); converges in 2–3 steps.
    let e2 = k.e * k.e;
    let mut tau = tau1;
    for _ in 0..8 {
        let t1 = conformal_tan(tau, k.e);
        let d = (tau1 - t1) * (1.0 + (1.0 - e2) * tau * tau) / ((1.0 - e2) * t1.hypot(1.0) * tau.hypot(1.0));
        tau += d;
        if d.abs() < 1e-15 * tau.abs().max(1.0) {
            break;
        }
    }
    (tau.atan().to_degrees(), lon0_deg + lam.to_degrees())
}

/// Forward transverse Mercator on WGS 84 (Karney 2011, eqs. 7, 9, 10):
/// metres `(x, y)` east and north of the central meridian's equator
/// crossing, for latitude/longitude in degrees. The inverse's test partner.
pub fn tm_forward(lat_deg: f64, lon_deg: f64, lon0_deg: f64, k0: f64) -> (f64, f64) {
    let k = kruger(WGS84);
    let tau1 = conformal_tan(lat_deg.to_radians().tan(), k.e);
    let lam = (lon_deg - lon0_deg).to_radians();
    let xi1 = tau1.atan2(lam.cos());
    let eta1 = (lam.sin() / tau1.hypot(lam.cos())).asinh();
    let (mut xi, mut eta) = (xi1, eta1);
    for (j, a) in k.alpha.iter().enumerate() {
        let m = 2.0 * (j + 1) as f64;
        xi += a * (m * xi1).sin() * (m * eta1).cosh();
        eta += a * (m * xi1).cos() * (m * eta1).sinh();
    }
    (k0 * k.a_rect * eta, k0 * k.a_rect * xi)
}

/// ECEF metres of a WGS 84 latitude/longitude (degrees) and ellipsoidal height.
pub fn ecef(lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    ecef_on(WGS84, lat_deg, lon_deg, h)
}

/// [`ecef`] on another ellipsoid (centred, axes aligned).
pub fn ecef_on(ell: Ellipsoid, lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    let e2 = ell.f * (2.0 - ell.f);
    let (sp, cp) = lat_deg.to_radians().sin_cos();
    let (sl, cl) = lon_deg.to_radians().sin_cos();
    let n = ell.a / (1.0 - e2 * sp * sp).sqrt();
    [(n + h) * cp * cl, (n + h) * cp * sl, (n * (1.0 - e2) + h) * sp]
}

/// WGS 84 `(latitude, longitude)` degrees of an ECEF point near the surface
/// (fixed-point iteration on the latitude; sub-millimetre in 5 steps for
/// heights of a few km).
pub fn geodetic_of_ecef(p: [f64; 3]) -> (f64, f64) {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let r = p[0].hypot(p[1]);
    let mut lat = p[2].atan2(r * (1.0 - e2));
    for _ in 0..8 {
        let n = WGS84_A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
        let h = r / lat.cos() - n;
        lat = p[2].atan2(r * (1.0 - e2 * n / (n + h)));
    }
    (lat.to_degrees(), p[1].atan2(p[0]).to_degrees())
}

/// The east-north-up frame at a latitude/longitude on the ellipsoid.
struct EnuFrame {
    origin: [f64; 3],
    /// Unit east, north and up, in ECEF.
    axes: [[f64; 3]; 3],
}

impl EnuFrame {
    fn new(lat_deg: f64, lon_deg: f64) -> EnuFrame {
        let (sp, cp) = lat_deg.to_radians().sin_cos();
        let (sl, cl) = lon_deg.to_radians().sin_cos();
        EnuFrame {
            origin: ecef(lat_deg, lon_deg, 0.0),
            axes: [[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]],
        }
    }

    /// ENU coordinates of an ECEF point.
    fn enu(&self, p: [f64; 3]) -> [f64; 3] {
        let d = [0, 1, 2].map(|a| p[a] - self.origin[a]);
        self.axes.map(|ax| ax[0] * d[0] + ax[1] * d[1] + ax[2] * d[2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Reference values from PROJ 9 (pyproj 3.7.2, "+proj=utm +zone=Z
    // [+south] +datum=WGS84" and its get_factors), which implements the same
    // Krüger series ("etmerc"); PROJ's own tests hold it to a few nm.
    // (lat, lon, zone, north, easting, northing, convergence °, scale)
    type UtmPoint = (f64, f64, u32, bool, f64, f64, f64, f64);
    const UTM_POINTS: [UtmPoint; 4] = [
        (
            46.2,
            -122.19,
            10,
            true,
            562_493.727_139_248_5,
            5_116_588.096_568_971,
            0.584_644_624_601_959,
            0.999_648_008_137_934_3,
        ),
        (
            -33.8688,
            151.2093,
            56,
            false,
            334_368.633_648_097,
            6_250_948.345_385_009,
            0.998_171_855_894_576_5,
            0.999_938_200_544_060_1,
        ),
        (0.0, 0.0, 31, true, 166_021.443_080_540_57, 0.0, 0.0, 1.000_981_061_558_583),
        (71.0, 27.0, 35, true, 500_000.0, 7_877_396.766_691_192, 0.0, 0.999_599_999_950_525_4),
    ];

    fn lon0(zone: u32) -> f64 {
        f64::from(zone) * 6.0 - 183.0
    }

    #[test]
    fn tm_inverse_matches_proj_to_a_micrometre() {
        for (lat, lon, zone, north, e, n, _, _) in UTM_POINTS {
            let y = if north { n } else { n - 10_000_000.0 };
            let (la, lo) = tm_inverse(e - 500_000.0, y, lon0(zone), UTM_K0);
            // 1e-11 degree is about 1 µm.
            assert!((la - lat).abs() < 1e-11 && (lo - lon).abs() < 1e-11, "({lat}, {lon}) came back ({la}, {lo})");
        }
    }

    #[test]
    fn tm_forward_matches_proj_to_a_micrometre() {
        for (lat, lon, zone, north, e, n, _, _) in UTM_POINTS {
            let (x, y) = tm_forward(lat, lon, lon0(zone), UTM_K0);
            let y = if north { y } else { y + 10_000_000.0 };
            assert!((x + 500_000.0 - e).abs() < 1e-6 && (y - n).abs() < 1e-6, "({lat}, {lon}) went to ({x}, {y})");
        }
    }

    #[test]
    fn tm_round_trips_across_a_zone_to_a_nanometre() {
        for lat in [-80.0, -45.5, -0.3, 0.0, 12.0, 46.2, 84.0] {
            for dlon in [-3.5, -1.0, 0.0, 0.7, 3.0] {
                let (x, y) = tm_forward(lat, 9.0 + dlon, 9.0, UTM_K0);
                let (la, lo) = tm_inverse(x, y, 9.0, UTM_K0);
                assert!((la - lat).abs() < 1e-14 * 90.0 && (lo - 9.0 - dlon).abs() < 1e-12, "{lat} {dlon}");
            }
        }
    }

    #[test]
    fn ecef_of_known_points() {
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-6);
        assert!(close(ecef(0.0, 0.0, 0.0), [WGS84_A, 0.0, 0.0]));
        assert!(close(ecef(0.0, 90.0, 10.0), [0.0, WGS84_A + 10.0, 0.0]));
        // The pole: the semi-minor axis b = a(1 − f).
        assert!(close(ecef(90.0, 0.0, 0.0), [0.0, 0.0, WGS84_A * (1.0 - WGS84_F)]));
    }

    fn utm_georef(zone: u32, north: bool, centre: [f64; 2]) -> (Georef, usize, usize) {
        let (w, h) = (401, 301);
        let epsg = if north { 32600 + zone } else { 32700 + zone };
        let origin = [centre[0] - 200.0 * 30.0, centre[1] + 150.0 * 30.0];
        (Georef { crs: Crs::Projected { epsg: Some(epsg) }, origin, step: [30.0, -30.0], local_tangent: None }, w, h)
    }

    #[test]
    fn utm_placement_matches_proj_position_convergence_and_scale() {
        for (lat, lon, zone, north, e, n, gamma, k) in UTM_POINTS {
            let (g, w, h) = utm_georef(zone, north, [e, n]);
            let p = Placement::of_grid(&g, w, h, [30.0, 30.0]).expect("UTM is placed");
            assert!((p.lat_deg - lat).abs() < 1e-11 && (p.lon_deg - lon).abs() < 1e-11);
            // Central differences over ±1 m of ECEF coordinates near 6.4e6 m
            // carry ~1e-9 of rounding: 1e-7° (2e-9 rad) is 9 µm at 5 km.
            assert!((p.convergence_deg - gamma).abs() < 1e-7, "γ {} against {gamma}", p.convergence_deg);
            assert!((p.scale - k).abs() < 1e-8, "k {} against {k}", p.scale);
            // The transform takes the grid centre to the ECEF point of (lat, lon, 0).
            let t = p.transform();
            let c = p.centre;
            let got = [0, 1, 2].map(|r| t[r] * c[0] + t[4 + r] * c[1] + t[8 + r] * c[2] + t[12 + r]);
            let want = ecef(lat, lon, 0.0);
            assert!((0..3).all(|r| (got[r] - want[r]).abs() < 1e-6), "{got:?} against {want:?}");
        }
    }

    #[test]
    fn the_transform_is_a_rotation_with_the_scale_on_the_ground_axes_only() {
        let (g, w, h) = utm_georef(10, true, [562_637.862, 5_116_496.641]);
        let p = Placement::of_grid(&g, w, h, [30.0, 30.0]).unwrap();
        let t = p.transform();
        let col = |c: usize| [t[4 * c], t[4 * c + 1], t[4 * c + 2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (x, y, z) = (col(0), col(1), col(2));
        // Orthogonal to the finite differences' 1e-9 (UTM is conformal), and
        // the up axis exactly a unit vector.
        assert!(dot(x, y).abs() < 1e-8 && dot(x, z).abs() < 1e-12 && dot(y, z).abs() < 1e-12);
        assert!((dot(x, x).sqrt() - 1.0 / p.scale).abs() < 1e-12 && (dot(z, z) - 1.0).abs() < 1e-12);
        assert!((dot(x, x) - dot(y, y)).abs() < 1e-8);
        assert_eq!([t[3], t[7], t[11], t[15]], [0.0, 0.0, 0.0, 1.0]);
    }

    /// The transform applied to a grid corner 10 km from the centre lands
    /// where that corner's exact position is, in the centre's ENU frame, up
    /// to what a linear map of a planar grid cannot follow: the projection's
    /// scale varies across the grid (for UTM, ∇ ln k ≈ x/R², x the distance
    /// from the central meridian: 7 cm at 10 km; for Web Mercator tan φ/R:
    /// metres), so the error grows as d²·|∇ ln k|/2. Vertically the corner
    /// floats by the tangent plane's d²/(2R).
    #[test]
    fn a_corner_lands_where_the_exact_inverse_puts_it() {
        let r2 = WGS84_A * WGS84_A;
        let cases: [(Crs, [f64; 2], [f64; 2], f64); 4] = [
            (Crs::Projected { epsg: Some(32610) }, [562_493.7, 5_116_588.1], [30.0, -30.0], 62_494.0 / r2),
            (Crs::Projected { epsg: Some(32756) }, [334_368.6, 6_250_948.3], [30.0, -30.0], 165_631.0 / r2),
            (Crs::Projected { epsg: Some(32631) }, [500_000.0, 5_000_000.0], [30.0, -30.0], 0.0),
            (Crs::Projected { epsg: Some(3857) }, [-13_803_616.9, 6_274_861.4], [45.0, -45.0], 1.15 / WGS84_A),
        ];
        for (crs, centre, step, grad_ln_k) in cases {
            let (w, h) = (471, 471);
            let origin = [centre[0] - 235.0 * step[0], centre[1] - 235.0 * step[1]];
            let g = Georef { crs: crs.clone(), origin, step, local_tangent: None };
            let inverse = Inverse::for_crs(&crs).unwrap();
            // The grid's own ground spacing, as a loader would measure it.
            let (lat0, _) = inverse.geodetic(centre).unwrap();
            let k = if matches!(crs, Crs::Projected { epsg: Some(3857) }) { lat0.to_radians().cos() } else { 1.0 };
            let p = Placement::of_grid(&g, w, h, [step[0].abs() * k, step[1].abs() * k]).unwrap();
            let t = p.transform();
            let (lat, lon) = inverse.geodetic(origin).unwrap();
            // Sample (0, 0) sits at tileset (0, 0, 0).
            let got = [t[12], t[13], t[14]];
            let frame = EnuFrame::new(p.lat_deg, p.lon_deg);
            let (a, b) = (frame.enu(got), frame.enu(ecef(lat, lon, 0.0)));
            let horizontal = (a[0] - b[0]).hypot(a[1] - b[1]);
            let d = b[0].hypot(b[1]);
            let predicted = d * d * grad_ln_k / 2.0;
            assert!(horizontal < 0.01 + 1.5 * predicted, "{crs:?}: corner {horizontal} m off, predicted {predicted}");
            // d²/2R with R between the meridian and prime-vertical radii.
            assert!((a[2] - b[2] - d * d / (2.0 * WGS84_A)).abs() < 0.25, "{crs:?}: height {} {}", a[2], b[2]);
        }
    }

    #[test]
    fn geographic_grids_sit_on_their_own_tangent_plane() {
        // 1201 × 1201 samples of 3″ from (−97°, 33°): centre (−96.5°, 32.5°).
        let step = 1.0 / 1200.0;
        let g = Georef {
            crs: Crs::Geographic { epsg: Some(4326) },
            origin: [-97.0, 33.0],
            step: [step, -step],
            local_tangent: None,
        };
        let (mx, mz) = crate::heightfield::metres_per_degree(32.5);
        let p = Placement::of_grid(&g, 1201, 1201, [step * mx, step * mz]).unwrap();
        assert!((p.lon_deg + 96.5).abs() < 1e-12 && (p.lat_deg - 32.5).abs() < 1e-12);
        assert_eq!((p.convergence_deg, p.scale, p.enu_per_tileset_m), (0.0, 1.0, [[1.0, 0.0], [0.0, 1.0]]));
        assert!((p.centre[0] - 600.0 * step * mx).abs() < 1e-9 && (p.centre[1] + 600.0 * step * mz).abs() < 1e-9);
    }

    #[test]
    fn unknown_and_unsupported_crs_are_not_placed() {
        let mut g = Georef::default();
        assert!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]).is_none());
        g.crs = Crs::Projected { epsg: None };
        assert!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]).is_none());
        g.crs = Crs::Projected { epsg: Some(2154) }; // Lambert-93: not inverted here.
        assert!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]).is_none());
        g.crs = Crs::Geographic { epsg: Some(4267) }; // NAD27 degrees: ~100 m off WGS 84.
        assert!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]).is_none());
    }

    #[test]
    fn nad27_utm_is_shifted_onto_wgs84_as_proj_does_with_the_same_parameters() {
        // PROJ: "+proj=utm +zone=10 +ellps=clrk66 +towgs84=-8,160,176" → EPSG:4326.
        let inverse = Inverse::for_crs(&Crs::Projected { epsg: Some(26710) }).unwrap();
        let (lat, lon) = inverse.geodetic([562_000.0, 5_117_000.0]).unwrap();
        assert!(
            (lat - 46.205_523_367_098_46).abs() < 1e-8 && (lon + 122.197_532_744_084_78).abs() < 1e-8,
            "{lat} {lon}"
        );
        // On Clarke 1866 itself, before the shift.
        let (la, lo) = tm_inverse_on(CLARKE_1866, 62_000.0, 5_117_000.0, -123.0, UTM_K0);
        assert!((la - 46.205_714_778_209_156).abs() < 1e-10 && (lo + 122.196_340_383_205_54).abs() < 1e-10);
    }

    #[test]
    fn ecef_round_trips() {
        for (lat, lon) in [(46.2, -122.19), (-33.9, 151.2), (0.0, 0.0), (89.0, 10.0)] {
            let (la, lo) = geodetic_of_ecef(ecef(lat, lon, 0.0));
            assert!((la - lat).abs() < 1e-11 && (lo - lon).abs() < 1e-11);
        }
    }
}
