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
//! the centre, taken by central differences of the CRS's inverse projection
//! to WGS 84 longitude/latitude. The inverse is the `proj4rs` crate's (a
//! Rust port of PROJ's projections, checked against PROJ to 1e-6 m), built
//! from the PROJ.4 definition that `crs-definitions` holds for the grid's
//! EPSG code (about 6 000 projected and geographic CRSs), or from a
//! definition the file gave itself. The datum shift is the definition's
//! `+towgs84` Helmert transform; the map then holds the grid's convergence
//! (grid north against true north) and its point scale (grid metres per
//! ground metre), so both are undone. Geographic grids need no inverse on
//! WGS 84 and its equivalents: the local tangent plane of
//! `heightfield::LocalTangent` already is the ENU plane at the centre, and
//! the map is the identity.
//!
//! Not placed (no transform; the tileset stays in its local frame, and the
//! build warns with [`NotPlaced`]'s reason): files that name no CRS, EPSG
//! codes `crs-definitions` does not hold, and definitions `proj4rs` cannot
//! build, such as datums defined only by grid-shift files, which do not
//! ship. NAD27 is the one exception: its grids (NADCON) stand in for a
//! mean Helmert shift, as before this module used the library.
//!
//! What a planar tileset cannot be: the terrain stays flat on the centre's
//! tangent plane, so ground d metres from the centre floats d²/(2R) above
//! the ellipsoid (2 m at 5 km); heights are the DEM's (orthometric, above the
//! geoid) used as ellipsoidal heights unless a geoid model is given; and a
//! datum's Helmert shift is as good as its published parameters (ETRS89 and
//! NAD83 are taken as WGS 84, 1–2 m apart).

mod globe;

pub use globe::{Globe, MIN_RADIUS_M, geodetic, up};
use proj4rs::Proj;
use serde::{Deserialize, Serialize};

use crate::heightfield::{Crs, Georef};

/// WGS 84 semi-major axis, metres.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS 84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS 84 first eccentricity squared, f·(2 − f).
const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);

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
    /// identity for geographic grids; for a conformal projection (UTM,
    /// Lambert conformal conic, stereographic) a rotation by the
    /// convergence times 1/scale.
    pub enu_per_tileset_m: [[f64; 2]; 2],
    /// Grid convergence at the centre, degrees: the angle from true north to
    /// grid north (the tileset's y axis), positive clockwise, as the x axis
    /// gives it (exact for a conformal projection; 0 for geographic grids).
    pub convergence_deg: f64,
    /// Point scale at the centre: grid metres per ground metre along the
    /// tileset's x axis (1 for geographic grids; a conformal projection
    /// scales equally in every direction, an equal-area one does not).
    pub scale: f64,
    /// How the transform was made, and what it leaves out.
    pub method: String,
    /// How far the planar tileset, as the transform places it, lies from
    /// where its samples are on the ellipsoid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flat_frame_error: Option<FlatFrameError>,
    /// How the chunks are written: planar in grid metres (absent), or
    /// curved, every vertex at its WGS 84 position ([`Globe`]).
    #[serde(default, skip_serializing_if = "FrameKind::is_flat")]
    pub frame: FrameKind,
}

/// The frame a placed tileset's chunks are written in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum FrameKind {
    /// Grid metres on the tangent plane at the grid centre (world x =
    /// column · s_x, z = row · s_z, y = height); the root transform holds
    /// the projection's derivative there.
    #[default]
    Flat,
    /// Every vertex at the WGS 84 position of its grid point and height,
    /// in the east-north-up frame at the grid centre (shifted so that the
    /// centre keeps its flat place); the root transform is that frame's.
    /// Morph deltas are then 3-vectors.
    Curved,
}

impl FrameKind {
    fn is_flat(&self) -> bool {
        *self == FrameKind::Flat
    }
}

/// The largest distance between a sample as a client draws it (its
/// tileset position through the root transform) and its true position on
/// the WGS 84 ellipsoid, both at height 0, over the grid's corners, its
/// border and a lattice inside; the planar frame's price, which grows as
/// the square of the grid's size (d²/2R upwards at d from the centre).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FlatFrameError {
    /// Along the ellipsoid normal at the true position, metres (positive:
    /// drawn above it).
    pub vertical_m: f64,
    /// Across the normal, metres.
    pub horizontal_m: f64,
    /// The sample `[row, column]` drawn farthest from its place.
    pub at: [usize; 2],
}

impl FlatFrameError {
    /// Measures the placement of the `width` × `height` grid of `georef`,
    /// `spacing_m` apart in the tileset, by the column-major root
    /// `transform`; `None` when its CRS cannot be taken to WGS 84.
    pub fn measure(
        georef: &Georef,
        width: usize,
        height: usize,
        spacing_m: [f64; 2],
        transform: &[f64; 16],
    ) -> Option<FlatFrameError> {
        let source = SourceCrs::of(&georef.crs, georef.definition.as_deref()).ok()?;
        let mut worst = FlatFrameError { vertical_m: 0.0, horizontal_m: 0.0, at: [0, 0] };
        let mut farthest = -1.0;
        for (i, j) in probe_samples(width, height) {
            let src = [georef.origin[0] + georef.step[0] * j as f64, georef.origin[1] + georef.step[1] * i as f64];
            let (lat, lon) = source.to_wgs84(src)?;
            let truth = ecef(lat, lon, 0.0);
            let p = [j as f64 * spacing_m[0], -(i as f64) * spacing_m[1], 0.0];
            let t = transform;
            let drawn = [0, 1, 2].map(|r| t[r] * p[0] + t[4 + r] * p[1] + t[8 + r] * p[2] + t[12 + r]);
            let d = [0, 1, 2].map(|r| drawn[r] - truth[r]);
            let up = EnuFrame::new(lat, lon).axes[2];
            let vertical = d[0] * up[0] + d[1] * up[1] + d[2] * up[2];
            let across = [0, 1, 2].map(|r| d[r] - vertical * up[r]);
            let horizontal = across.iter().map(|a| a * a).sum::<f64>().sqrt();
            if vertical.abs() > worst.vertical_m.abs() {
                worst.vertical_m = vertical;
            }
            worst.horizontal_m = worst.horizontal_m.max(horizontal);
            let total = distance(drawn, truth);
            if total > farthest {
                (farthest, worst.at) = (total, [i, j]);
            }
        }
        Some(worst)
    }

    /// The larger of the two distances, metres.
    pub fn worst_m(&self) -> f64 {
        self.vertical_m.abs().max(self.horizontal_m)
    }
}

/// The samples a flat frame is measured at: every corner, up to 257 along
/// each border, and a 17 × 17 lattice inside (the error is smooth and
/// largest at the border; the lattice catches a projection's own bends).
fn probe_samples(width: usize, height: usize) -> Vec<(usize, usize)> {
    let along = |n: usize, k: usize| -> Vec<usize> {
        let mut v: Vec<usize> = (0..=k).map(|t| t * (n - 1) / k).collect();
        v.dedup();
        v
    };
    let (rows, cols) = (along(height, 256.min(height - 1)), along(width, 256.min(width - 1)));
    let mut out: Vec<(usize, usize)> = Vec::new();
    for &j in &cols {
        out.push((0, j));
        out.push((height - 1, j));
    }
    for &i in &rows {
        out.push((i, 0));
        out.push((i, width - 1));
    }
    for i in along(height, 16.min(height - 1)) {
        for j in along(width, 16.min(width - 1)) {
            out.push((i, j));
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Why a georeferenced grid gets no root transform.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum NotPlaced {
    /// The file says where the grid is in some CRS but not which.
    #[error("the file names no coordinate system")]
    NoCrs,
    /// An EPSG code with no definition in `crs-definitions`.
    #[error("EPSG:{0} is not a coordinate system terrachunk knows")]
    UnknownCode(u32),
    /// A definition `proj4rs` cannot build or invert.
    #[error("{name} ({definition}) cannot be inverted: {why}")]
    Unsupported {
        /// `EPSG:code`, or where the definition came from.
        name: String,
        /// The PROJ.4 definition.
        definition: String,
        /// What the library said.
        why: String,
    },
    /// A grid of degrees that reaches a pole, whose columns meet there in
    /// one point: written curved, its pole row's vertices could not be
    /// told apart again.
    #[error("{name}: the grid reaches a pole, where its columns meet in one point")]
    AtPole {
        /// `EPSG:code`, or where the definition came from.
        name: String,
    },
    /// A grid of degrees whose columns go once round the Earth: its first
    /// and last columns are one meridian, whose vertices, written curved,
    /// could not be told apart again.
    #[error("{name}: the grid's columns go once round the Earth, its first and last on one meridian")]
    WholeTurn {
        /// `EPSG:code`, or where the definition came from.
        name: String,
    },
    /// The grid centre does not come back as a point on the Earth.
    #[error("{name} puts the grid centre ({x}, {y}) nowhere on the Earth")]
    OffTheEarth {
        /// `EPSG:code`, or where the definition came from.
        name: String,
        /// Source x of the centre.
        x: f64,
        /// Source y of the centre.
        y: f64,
    },
}

impl Placement {
    /// Where the grid described by `georef` (`width` × `height` samples,
    /// `spacing_m` between them on the ground as the tileset has it) sits on
    /// the Earth, or why it cannot be placed.
    pub fn of_grid(georef: &Georef, width: usize, height: usize, spacing_m: [f64; 2]) -> Result<Placement, NotPlaced> {
        let source = SourceCrs::of(&georef.crs, georef.definition.as_deref())?;
        let [dx, dy] = georef.step;
        // Grid centre in source units, and in tileset metres (x east, y north).
        let (ci, cj) = ((height - 1) as f64 / 2.0, (width - 1) as f64 / 2.0);
        let src = [georef.origin[0] + dx * cj, georef.origin[1] + dy * ci];
        let centre = [cj * spacing_m[0], -ci * spacing_m[1], 0.0];
        let off = || NotPlaced::OffTheEarth { name: source.name.clone(), x: src[0], y: src[1] };
        if !(dx.is_finite() && dy.is_finite() && dx != 0.0 && dy != 0.0) {
            return Err(off());
        }
        let (mut lat, mut lon) = source.to_wgs84(src).ok_or_else(off)?;
        if !(lat.abs() < 90.0 && lon.is_finite()) {
            return Err(off());
        }
        // A geographic grid whose datum moves it by less than a millimetre
        // keeps its own degrees and the identity: its local tangent plane
        // is the ENU plane at the centre (`heightfield::LocalTangent`).
        let tangent = keeps_its_degrees(&source, src, (lat, lon));
        if tangent {
            (lat, lon) = (src[1], src[0]);
        }
        let frame = EnuFrame::new(lat, lon);
        let mut jac = [[1.0, 0.0], [0.0, 1.0]];
        if !tangent {
            // Source units per tileset metre along east and north.
            let per_m = [dx.abs() / spacing_m[0], dy.abs() / spacing_m[1]];
            // Derivative of ENU(at centre) with respect to tileset metres by
            // central differences over ±h metres: h small against the
            // Earth, large against f64 rounding of ECEF (1e-9 m in 6.4e6 m).
            let h = 1.0;
            for axis in 0..2 {
                let mut plus = src;
                let mut minus = src;
                let sign = if axis == 0 { dx.signum() } else { -dy.signum() };
                plus[axis] += sign * h * per_m[axis];
                minus[axis] -= sign * h * per_m[axis];
                let (lp, gp) = source.to_wgs84(plus).ok_or_else(off)?;
                let (lm, gm) = source.to_wgs84(minus).ok_or_else(off)?;
                let a = frame.enu(ecef(lp, gp, 0.0));
                let b = frame.enu(ecef(lm, gm, 0.0));
                for row in 0..2 {
                    jac[row][axis] = (a[row] - b[row]) / (2.0 * h);
                }
            }
        }
        // For a conformal map the derivative is a rotation times a scale:
        // grid east lies γ clockwise of true east, (cos γ, −sin γ)/k.
        let scale = 1.0 / jac[0][0].hypot(jac[1][0]);
        let convergence_deg = -jac[1][0].atan2(jac[0][0]).to_degrees();
        let how = if tangent {
            format!("geographic degrees ({}) on the local tangent plane", source.name)
        } else {
            format!(
                "{} = \"{}\", inverted to WGS 84 by proj4rs {}; root transform = ENU frame at (lon, lat, \
                 height) x the derivative of that inverse at the grid centre (undoes convergence and \
                 scale) x translation by -centre",
                source.name, source.definition, PROJ4RS_VERSION
            )
        };
        let mut placement = Placement {
            lon_deg: lon,
            lat_deg: lat,
            height_m: 0.0,
            centre,
            enu_per_tileset_m: jac,
            convergence_deg,
            scale,
            method: format!(
                "{how}; the tileset stays planar (ground d m from the centre floats d^2/2R above the \
                 ellipsoid), {NO_GEOID}"
            ),
            flat_frame_error: None,
            frame: FrameKind::Flat,
        };
        placement.flat_frame_error = FlatFrameError::measure(georef, width, height, spacing_m, &placement.transform());
        Ok(placement)
    }

    /// The placement of the same grid written in the curved frame
    /// ([`Globe`]): the transform is the ENU frame at the centre alone.
    pub fn curved(mut self) -> Placement {
        self.enu_per_tileset_m = [[1.0, 0.0], [0.0, 1.0]];
        self.frame = FrameKind::Curved;
        let planar = self.method.find("; the tileset stays planar").unwrap_or(self.method.len());
        let rest = self.method[planar..].split_once("), ").map_or("", |(_, r)| r).to_string();
        let how = &self.method[..planar];
        let how = how.split_once("; root transform").map_or(how, |(h, _)| h);
        self.method = format!(
            "{how}; curved: every vertex at the WGS 84 position of its grid point and height, in the ENU frame \
             at the grid centre (root transform = that frame x translation by -centre), {rest}"
        );
        self
    }

    /// The placement of a grid whose heights had the undulation of the
    /// geoid model `name` added (`crate::geoid`): its method says so.
    pub fn with_geoid(mut self, name: &str) -> Placement {
        let heights = format!("DEM heights plus the undulation of geoid model {name} (bilinear) are ellipsoidal");
        self.method = self.method.replace(NO_GEOID, &heights);
        self
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

/// What the placement's method says of heights without a geoid model.
const NO_GEOID: &str = "DEM heights are used as ellipsoidal (no geoid)";

/// The `proj4rs` release the placement's `method` names (Cargo.toml's).
const PROJ4RS_VERSION: &str = "0.3";

/// The definition of WGS 84 longitude/latitude, every inverse's target.
const WGS84_LONLAT: &str = "+proj=longlat +datum=WGS84 +no_defs";

/// NAD27's definitions name NADCON's grids, which do not ship; the mean
/// shift for the conterminous US (NIMA TR8350.2, table B.1, "NAS-C":
/// ±5 m, ±5 m, ±6 m) stands in for them, so NAD27 grids (legacy USGS DEMs)
/// are placed to ±5–10 m rather than not at all.
const NAD27_MEAN_SHIFT: &str = "+ellps=clrk66 +towgs84=-8,160,176";

/// A grid's CRS as the library inverts it: source coordinates (the CRS's
/// own units: metres, feet or degrees) to WGS 84 latitude and longitude.
pub struct SourceCrs {
    /// `EPSG:code`, or what the definition is.
    pub name: String,
    /// The PROJ.4 definition the inverse is built from.
    pub definition: String,
    /// Longitude/latitude degrees, not a projection.
    pub geographic: bool,
    proj: Proj,
    wgs84: Proj,
}

impl SourceCrs {
    /// The CRS a grid's georeference names: its EPSG code, or else the
    /// PROJ.4 `definition` the file gave.
    pub fn of(crs: &Crs, definition: Option<&str>) -> Result<SourceCrs, NotPlaced> {
        match (crs, definition) {
            (Crs::Geographic { epsg: None } | Crs::Projected { epsg: None }, Some(def)) => {
                SourceCrs::from_definition("the file's PROJ.4 definition", def)
            }
            (crs, _) => SourceCrs::of_crs(crs),
        }
    }

    fn of_crs(crs: &Crs) -> Result<SourceCrs, NotPlaced> {
        match *crs {
            Crs::Unknown | Crs::Projected { epsg: None } => Err(NotPlaced::NoCrs),
            // Unnamed geographic grids (SRTM .hgt, degree .asc) are WGS 84.
            Crs::Geographic { epsg: None } => SourceCrs::from_definition("unnamed geographic (WGS 84)", WGS84_LONLAT),
            Crs::Geographic { epsg: Some(code) } | Crs::Projected { epsg: Some(code) } => SourceCrs::from_epsg(code),
        }
    }

    /// The CRS of an EPSG code (or one of the unofficial codes for Web
    /// Mercator, 900913 and Esri's 102100 and 102113).
    pub fn from_epsg(code: u32) -> Result<SourceCrs, NotPlaced> {
        let lookup = match code {
            900_913 | 102_100 | 102_113 => 3857,
            _ => code,
        };
        let def =
            u16::try_from(lookup).ok().and_then(crs_definitions::from_code).ok_or(NotPlaced::UnknownCode(code))?;
        let definition = def.proj4.replace("+datum=NAD27", NAD27_MEAN_SHIFT);
        SourceCrs::from_definition(&format!("EPSG:{code}"), &definition)
    }

    /// The CRS of a PROJ.4 definition, named `name` in messages.
    pub fn from_definition(name: &str, definition: &str) -> Result<SourceCrs, NotPlaced> {
        let unsupported =
            |why: String| NotPlaced::Unsupported { name: name.to_string(), definition: definition.to_string(), why };
        let proj = Proj::from_proj_string(definition).map_err(|e| unsupported(e.to_string()))?;
        if !proj.has_inverse() {
            return Err(unsupported("the projection has no inverse".into()));
        }
        let wgs84 = Proj::from_proj_string(WGS84_LONLAT).expect("WGS 84 is a definition proj4rs builds");
        Ok(SourceCrs {
            name: name.to_string(),
            definition: definition.to_string(),
            geographic: proj.is_latlong(),
            proj,
            wgs84,
        })
    }

    /// Metres per unit of the projected coordinates (0.3048006… for US
    /// survey feet); 1 for geographic CRSs, whose unit is the degree.
    pub fn metres_per_unit(&self) -> f64 {
        if self.geographic { 1.0 } else { self.proj.to_meter() }
    }

    /// WGS 84 `(latitude, longitude)` in degrees of the source point
    /// `[x, y]` (easting, northing; or longitude, latitude in degrees);
    /// `None` where the inverse has no answer.
    pub fn to_wgs84(&self, p: [f64; 2]) -> Option<(f64, f64)> {
        let (lat, lon) = self.to_wgs84_radians(p)?;
        Some((lat.to_degrees(), lon.to_degrees()))
    }

    /// The source point `[x, y]` of a WGS 84 latitude and longitude,
    /// degrees: the inverse of [`SourceCrs::to_wgs84`].
    pub fn from_wgs84(&self, lat_deg: f64, lon_deg: f64) -> Option<[f64; 2]> {
        let mut q = (lon_deg.to_radians(), lat_deg.to_radians(), 0.0);
        proj4rs::transform::transform(&self.wgs84, &self.proj, &mut q).ok()?;
        let p = if self.geographic { [q.0.to_degrees(), q.1.to_degrees()] } else { [q.0, q.1] };
        p.iter().all(|v| v.is_finite()).then_some(p)
    }

    fn to_wgs84_radians(&self, p: [f64; 2]) -> Option<(f64, f64)> {
        let mut q = if self.geographic { (p[0].to_radians(), p[1].to_radians(), 0.0) } else { (p[0], p[1], 0.0) };
        proj4rs::transform::transform(&self.proj, &self.wgs84, &mut q).ok()?;
        (q.0.is_finite() && q.1.is_finite()).then_some((q.1, q.0))
    }

    /// Ground metres per grid metre, as a loader applies it to a projected
    /// grid's spacing at the grid's centre `p`: cos φ for Mercator (Web
    /// Mercator above all), whose grid stretches by 1/cos φ on its sphere
    /// (4/3 at 41°); 1 for every other projection, whose grid metres lie
    /// within a fraction of a percent of ground metres where it is meant
    /// to be used (the placement undoes what is left).
    pub fn ground_per_grid_m(&self, p: [f64; 2]) -> Option<f64> {
        if self.proj.projname() != "merc" {
            return Some(1.0);
        }
        self.to_wgs84_radians(p).map(|(lat, _)| lat.cos())
    }
}

/// Whether a grid in `source` keeps its own degrees as WGS 84's: geographic,
/// and its point `src` (longitude, latitude), which WGS 84 has at
/// `(lat, lon)`, moved by less than a millimetre by its datum.
fn keeps_its_degrees(source: &SourceCrs, src: [f64; 2], (lat, lon): (f64, f64)) -> bool {
    source.geographic && distance(ecef(lat, lon, 0.0), ecef(src[1], src[0], 0.0)) < 1e-3
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// ECEF metres of a WGS 84 latitude/longitude (degrees) and ellipsoidal height.
pub fn ecef(lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    let e2 = WGS84_E2;
    let (sp, cp) = lat_deg.to_radians().sin_cos();
    let (sl, cl) = lon_deg.to_radians().sin_cos();
    let n = WGS84_A / (1.0 - e2 * sp * sp).sqrt();
    [(n + h) * cp * cl, (n + h) * cp * sl, (n * (1.0 - e2) + h) * sp]
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
    // [+south] +datum=WGS84" and its get_factors), which implements
    // Krüger's series ("etmerc"); PROJ's own tests hold it to a few nm.
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

    fn utm_epsg(zone: u32, north: bool) -> u32 {
        if north { 32600 + zone } else { 32700 + zone }
    }

    #[test]
    fn utm_inverse_matches_proj_to_a_micrometre() {
        for (lat, lon, zone, north, e, n, _, _) in UTM_POINTS {
            let source = SourceCrs::from_epsg(utm_epsg(zone, north)).unwrap();
            let (la, lo) = source.to_wgs84([e, n]).unwrap();
            // 1e-11 degree is about 1 µm.
            assert!((la - lat).abs() < 1e-11 && (lo - lon).abs() < 1e-11, "({lat}, {lon}) came back ({la}, {lo})");
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
        let origin = [centre[0] - 200.0 * 30.0, centre[1] + 150.0 * 30.0];
        let crs = Crs::Projected { epsg: Some(utm_epsg(zone, north)) };
        (Georef { crs, origin, step: [30.0, -30.0], local_tangent: None, definition: None }, w, h)
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
        let cases: [(u32, [f64; 2], [f64; 2], f64); 4] = [
            (32610, [562_493.7, 5_116_588.1], [30.0, -30.0], 62_494.0 / r2),
            (32756, [334_368.6, 6_250_948.3], [30.0, -30.0], 165_631.0 / r2),
            (32631, [500_000.0, 5_000_000.0], [30.0, -30.0], 0.0),
            (3857, [-13_803_616.9, 6_274_861.4], [45.0, -45.0], 1.15 / WGS84_A),
        ];
        for (code, centre, step, grad_ln_k) in cases {
            let (w, h) = (471, 471);
            let origin = [centre[0] - 235.0 * step[0], centre[1] - 235.0 * step[1]];
            let crs = Crs::Projected { epsg: Some(code) };
            let g = Georef { crs: crs.clone(), origin, step, local_tangent: None, definition: None };
            let source = SourceCrs::of(&crs, None).unwrap();
            // The grid's own ground spacing, as a loader would measure it.
            let (lat0, _) = source.to_wgs84(centre).unwrap();
            let k = if code == 3857 { lat0.to_radians().cos() } else { 1.0 };
            let p = Placement::of_grid(&g, w, h, [step[0].abs() * k, step[1].abs() * k]).unwrap();
            let t = p.transform();
            let (lat, lon) = source.to_wgs84(origin).unwrap();
            // Sample (0, 0) sits at tileset (0, 0, 0).
            let got = [t[12], t[13], t[14]];
            let frame = EnuFrame::new(p.lat_deg, p.lon_deg);
            let (a, b) = (frame.enu(got), frame.enu(ecef(lat, lon, 0.0)));
            let horizontal = (a[0] - b[0]).hypot(a[1] - b[1]);
            let d = b[0].hypot(b[1]);
            let predicted = d * d * grad_ln_k / 2.0;
            assert!(
                horizontal < 0.01 + 1.5 * predicted,
                "EPSG:{code}: corner {horizontal} m off, predicted {predicted}"
            );
            // d²/2R with R between the meridian and prime-vertical radii.
            assert!((a[2] - b[2] - d * d / (2.0 * WGS84_A)).abs() < 0.25, "EPSG:{code}: height {} {}", a[2], b[2]);
        }
    }

    #[test]
    fn geographic_grids_sit_on_their_own_tangent_plane() {
        // 1201 × 1201 samples of 3″ from (−97°, 33°): centre (−96.5°, 32.5°).
        let step = 1.0 / 1200.0;
        let (mx, mz) = crate::heightfield::metres_per_degree(32.5);
        for epsg in [Some(4326), Some(4269), Some(4258), None] {
            let g = Georef {
                crs: Crs::Geographic { epsg },
                origin: [-97.0, 33.0],
                step: [step, -step],
                local_tangent: None,
                definition: None,
            };
            let p = Placement::of_grid(&g, 1201, 1201, [step * mx, step * mz]).unwrap();
            assert!((p.lon_deg + 96.5).abs() < 1e-12 && (p.lat_deg - 32.5).abs() < 1e-12, "{epsg:?}");
            assert_eq!((p.convergence_deg, p.scale, p.enu_per_tileset_m), (0.0, 1.0, [[1.0, 0.0], [0.0, 1.0]]));
            assert!((p.centre[0] - 600.0 * step * mx).abs() < 1e-9 && (p.centre[1] + 600.0 * step * mz).abs() < 1e-9);
        }
    }

    #[test]
    fn grids_without_a_known_crs_are_not_placed_and_say_why() {
        let mut g = Georef::default();
        assert_eq!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]), Err(NotPlaced::NoCrs));
        g.crs = Crs::Projected { epsg: None };
        assert_eq!(Placement::of_grid(&g, 3, 3, [1.0, 1.0]), Err(NotPlaced::NoCrs));
        // No EPSG CRS has code 9999.
        g.crs = Crs::Projected { epsg: Some(9999) };
        let why = Placement::of_grid(&g, 3, 3, [1.0, 1.0]).unwrap_err();
        assert_eq!(why.to_string(), "EPSG:9999 is not a coordinate system terrachunk knows");
        // A definition whose datum is only a grid-shift file, which does not ship.
        let e = SourceCrs::from_definition("test", "+proj=longlat +ellps=clrk66 +nadgrids=ntv1_can.dat").err();
        assert!(matches!(e, Some(NotPlaced::Unsupported { .. })), "{e:?}");
    }

    #[test]
    fn nad27_is_shifted_onto_wgs84_as_proj_does_with_the_same_parameters() {
        // PROJ: "+proj=utm +zone=10 +ellps=clrk66 +towgs84=-8,160,176" → EPSG:4326.
        let source = SourceCrs::from_epsg(26710).unwrap();
        let (lat, lon) = source.to_wgs84([562_000.0, 5_117_000.0]).unwrap();
        assert!(
            (lat - 46.205_523_367_098_46).abs() < 1e-8 && (lon + 122.197_532_744_084_78).abs() < 1e-8,
            "{lat} {lon}"
        );
        // NAD27 degrees are placed the same way, no longer refused.
        let g = Georef {
            crs: Crs::Geographic { epsg: Some(4267) },
            origin: [-122.2, 46.2],
            step: [1e-3, -1e-3],
            local_tangent: None,
            definition: None,
        };
        assert!(Placement::of_grid(&g, 3, 3, [77.0, 111.0]).is_ok());
    }

    #[test]
    fn feet_and_metres_per_unit() {
        assert_eq!(SourceCrs::from_epsg(32610).unwrap().metres_per_unit(), 1.0);
        assert_eq!(SourceCrs::from_epsg(4326).unwrap().metres_per_unit(), 1.0);
        // NAD83 / California zone 3 (ftUS): 1200/3937 m.
        assert!((SourceCrs::from_epsg(2227).unwrap().metres_per_unit() - 1200.0 / 3937.0).abs() < 1e-15);
        // NAD83 / Arizona East (ft): the international foot, 0.3048 m.
        assert_eq!(SourceCrs::from_epsg(2222).unwrap().metres_per_unit(), 0.3048);
    }
}
