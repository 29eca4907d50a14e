//! The one in-memory form every loader produces and every later stage reads.
//!
//! Heights are stored as `f32` (an int16 or float32 DEM fits exactly, and
//! 40 M samples stay at 160 MB); every decision made from them is taken in
//! `f64`. Nodata is `NaN`. Row `i` runs southward, column `j` eastward, and
//! the world position of sample `(i, j)` is `(j·s_x, h, i·s_z)` (DESIGN.md).

use serde::{Deserialize, Serialize};

use crate::store::{Big, Memory};

/// How the grid is placed on the Earth, as far as the source file says.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Georef {
    /// Coordinate system of the source grid.
    pub crs: Crs,
    /// Source coordinates (x/longitude, y/latitude) of the *centre* of
    /// sample (0, 0), the north-west corner sample.
    pub origin: [f64; 2],
    /// Step between sample centres in source units: `[dx, dy]`, with `dy`
    /// negative for a north-up grid.
    pub step: [f64; 2],
    /// For geographic grids: where and how degrees became metres.
    pub local_tangent: Option<LocalTangent>,
    /// The CRS as a PROJ.4 definition, where the file gives one instead
    /// of an EPSG code (a `.prj` of PROJ.4 text beside an ASCII grid);
    /// `crs` still says whether it is geographic or projected.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub definition: Option<String>,
}

/// Coordinate system of a source grid.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Crs {
    /// The file carries no georeference; positions are grid indices × spacing.
    #[default]
    Unknown,
    /// Longitude/latitude in degrees (EPSG code when the file names one).
    Geographic {
        /// EPSG code, e.g. 4326.
        epsg: Option<u32>,
    },
    /// Projected metres (UTM, Web Mercator, ...).
    Projected {
        /// EPSG code, e.g. 32611.
        epsg: Option<u32>,
    },
}

/// The local tangent plane used to turn a geographic grid into metres.
///
/// Formula (equirectangular about the grid centre on the WGS 84 ellipsoid):
/// `s_x = N(φ0)·cos φ0·Δλ`, `s_z = M(φ0)·Δφ` with `N`, `M` the prime-vertical
/// and meridional radii of curvature at the centre latitude φ0 and the steps
/// in radians; world x = (λ − λ_w)·N·cos φ0, world z = (φ_n − φ)·M.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LocalTangent {
    /// Longitude of the grid centre, degrees.
    pub lon0_deg: f64,
    /// Latitude of the grid centre, degrees.
    pub lat0_deg: f64,
    /// Human-readable formula (kept in the tileset extras).
    pub formula: String,
}

/// Why a grid placement (first sample centre `origin`, `step` between
/// samples, in source units) cannot place anything: a value that is not
/// finite, or a zero step. `None` if it is usable.
pub fn unusable_placement(origin: [f64; 2], step: [f64; 2]) -> Option<String> {
    let usable = origin.iter().chain(&step).all(|v| v.is_finite()) && step.iter().all(|&s| s != 0.0);
    (!usable).then(|| {
        format!(
            "georeference places the first sample at ({}, {}) with steps {} × {}; \
             each must be finite and the steps non-zero",
            origin[0], origin[1], step[0], step[1]
        )
    })
}

/// A regular grid of heights in metres.
#[derive(Clone, Debug)]
pub struct Heightfield {
    /// Samples per row (west → east), at least 2.
    pub width: usize,
    /// Rows (north → south), at least 2.
    pub height: usize,
    /// Row-major heights in metres; `NaN` is nodata (in memory, or past a
    /// build's memory limit in a mapped scratch file, [`crate::store`]).
    pub heights: Big<f32>,
    /// Ground distance between sample centres, metres: `[s_x, s_z]`.
    pub spacing_m: [f64; 2],
    /// Where the grid sits, as the file said.
    pub georef: Georef,
    /// File name(s) it came from, for messages and the tileset extras.
    pub source: String,
}

/// WGS 84 semi-major axis (m) and first eccentricity squared.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 6.694_379_990_141_317e-3;

/// Metres per degree of longitude and of latitude at latitude `lat_deg`
/// on the WGS 84 ellipsoid: `(N·cos φ, M)·π/180`.
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    let phi = lat_deg.to_radians();
    let w = (1.0 - WGS84_E2 * phi.sin().powi(2)).sqrt();
    let n = WGS84_A / w;
    let m = WGS84_A * (1.0 - WGS84_E2) / (w * w * w);
    (n * phi.cos() * std::f64::consts::PI / 180.0, m * std::f64::consts::PI / 180.0)
}

impl Heightfield {
    /// A grid whose file says nothing about where it is: 1 m spacing,
    /// unknown CRS, north-up (overridable with `--spacing`).
    pub fn ungeoreferenced(width: usize, height: usize, heights: impl Into<Big<f32>>, source: String) -> Self {
        Heightfield {
            width,
            height,
            heights: heights.into(),
            spacing_m: [1.0, 1.0],
            georef: Georef {
                crs: Crs::Unknown,
                origin: [0.0, 0.0],
                step: [1.0, -1.0],
                local_tangent: None,
                definition: None,
            },
            source,
        }
    }

    /// Height of sample (row `i`, column `j`); `NaN` for nodata.
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> f32 {
        self.heights[i * self.width + j]
    }

    /// Number of samples that hold data.
    pub fn valid_count(&self) -> usize {
        // In parts, giving pages back between them: a scan maps a scratch
        // file's pages faster than the memory governor wakes.
        self.heights
            .chunks(1 << 21)
            .map(|part| {
                self.heights.relieve();
                part.iter().filter(|h| !h.is_nan()).count()
            })
            .sum()
    }

    /// For a geographic grid, replace `spacing_m` with metres on the local
    /// tangent plane at the grid centre and record how (DESIGN.md).
    pub fn apply_local_tangent(&mut self) {
        if !matches!(self.georef.crs, Crs::Geographic { .. }) {
            return;
        }
        let [lon, lat] = self.georef.origin;
        let [dlon, dlat] = self.georef.step;
        let lon0 = lon + dlon * (self.width - 1) as f64 / 2.0;
        let lat0 = lat + dlat * (self.height - 1) as f64 / 2.0;
        let (mx, mz) = metres_per_degree(lat0);
        self.spacing_m = [dlon.abs() * mx, dlat.abs() * mz];
        self.georef.local_tangent = Some(LocalTangent {
            lon0_deg: lon0,
            lat0_deg: lat0,
            formula: "x = (lon - lon_w) * N(lat0) * cos(lat0) * pi/180; \
                      z = (lat_n - lat) * M(lat0) * pi/180; WGS 84 radii"
                .to_string(),
        });
    }
}

/// A smooth stand-in for nodata: push-pull over an image pyramid (average of
/// the valid samples below each coarser cell, pulled back down). Only
/// vertices forced onto nodata samples (chunk corners, line midpoints) take
/// these heights; no error is ever measured against them. `None` when the
/// grid has no voids.
pub fn void_fill(hf: &Heightfield) -> Option<Big<f32>> {
    void_fill_in(hf, None).expect("in memory")
}

/// [`void_fill`], its arrays in scratch files where `memory` says so (which
/// can fail, naming the file).
pub fn void_fill_in(hf: &Heightfield, memory: Option<&Memory>) -> std::io::Result<Option<Big<f32>>> {
    if !hf.heights.iter().any(|h| h.is_nan()) {
        return Ok(None);
    }
    // levels[0] = the grid; each next one halves both sizes (rounding up).
    let grid = Big::copied_from(&hf.heights, memory)?;
    let mut levels: Vec<(usize, usize, Big<f32>)> = vec![(hf.width, hf.height, grid)];
    while {
        let (w, h, _) = &levels[levels.len() - 1];
        *w > 1 || *h > 1
    } {
        let (w, h, src) = &levels[levels.len() - 1];
        let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
        let mut dst = Big::filled(nw * nh, f32::NAN, memory)?;
        for i in 0..nh {
            for j in 0..nw {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for (di, dj) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let (si, sj) = (2 * i + di, 2 * j + dj);
                    if si < *h && sj < *w {
                        let v = src[si * w + sj];
                        if !v.is_nan() {
                            sum += f64::from(v);
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    dst[i * nw + j] = (sum / f64::from(n)) as f32;
                }
            }
        }
        levels.push((nw, nh, dst));
    }
    for l in (0..levels.len() - 1).rev() {
        let (upper, lower) = levels.split_at_mut(l + 1);
        let (w, h, fine) = &mut upper[l];
        let (cw, _, coarse) = &lower[0];
        for i in 0..*h {
            for j in 0..*w {
                if fine[i * *w + j].is_nan() {
                    fine[i * *w + j] = coarse[(i / 2) * cw + j / 2];
                }
            }
        }
    }
    let (_, _, mut filled) = levels.swap_remove(0);
    for v in filled.iter_mut().filter(|v| v.is_nan()) {
        *v = 0.0;
    }
    Ok(Some(filled))
}
