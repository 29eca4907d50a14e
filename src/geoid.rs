//! Vertical datum: DEM heights above a geoid to heights above the WGS 84
//! ellipsoid, `h = H + N(lat, lon)`.
//!
//! Most DEMs (SRTM, national lidar grids) give orthometric heights, above
//! a geoid ("mean sea level"), while 3D Tiles clients place content by
//! ellipsoidal height; the two differ by the geoid undulation N, −107 m
//! to +86 m on Earth. With `--geoid GRID` every sample gets the model's N
//! at its WGS 84 position, bilinear between the model's nodes, as PROJ
//! does; without it heights are used as given (the tileset's placement
//! says so).
//!
//! Models are read in the two formats PROJ distributes them in: a
//! GeoTIFF of one float band on a geographic grid (PROJ-data's current
//! format, e.g. `us_nga_egm96_15.tif`), and the older NOAA/NGS `.gtx`
//! (a 40-byte big-endian header: south latitude, west longitude,
//! latitude step, longitude step as f64; rows, columns as i32; then
//! rows × columns big-endian f32 from the south-west corner eastwards,
//! −88.8888 for no data).

use std::path::Path;

use rayon::prelude::*;

use crate::dem::DemError;
use crate::geodesy::SourceCrs;
use crate::heightfield::{Crs, Heightfield};

/// A geoid model: undulations on a regular latitude/longitude grid.
#[derive(Clone, Debug)]
pub struct Geoid {
    /// Latitude and longitude of node (0, 0), degrees.
    lat0: f64,
    lon0: f64,
    /// Signed latitude step between rows, positive eastward longitude step.
    dlat: f64,
    dlon: f64,
    rows: usize,
    cols: usize,
    /// Row-major undulations, metres; NaN where the model has none.
    values: Vec<f32>,
    /// The columns go once around the Earth, the last one next to the first.
    wraps: bool,
}

/// The value `.gtx` files mark missing nodes with.
const GTX_NODATA: f32 = -88.8888;

impl Geoid {
    /// Reads a model from a `.gtx` file or a geographic GeoTIFF. Errors
    /// name the file and what is wrong with it.
    pub fn read(path: &Path) -> Result<Geoid, DemError> {
        let bad = |what: String| DemError::Invalid { path: path.to_path_buf(), what: format!("geoid model: {what}") };
        let is_gtx = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gtx"));
        let geoid = if is_gtx {
            let bytes = std::fs::read(path).map_err(|source| DemError::Io { path: path.to_path_buf(), source })?;
            Geoid::from_gtx(&bytes).map_err(bad)?
        } else {
            let hf = crate::dem::geotiff::load(path)?;
            if !matches!(hf.georef.crs, Crs::Geographic { .. }) {
                return Err(bad("not a grid in longitude and latitude (a geoid model is one)".into()));
            }
            let [dlon, dlat] = hf.georef.step;
            let [lon0, lat0] = hf.georef.origin;
            let (rows, cols, values) = (hf.height, hf.width, hf.heights);
            Geoid::checked(Geoid { lat0, lon0, dlat, dlon, rows, cols, values: values.into_vec(), wraps: false })
                .map_err(bad)?
        };
        Ok(geoid)
    }

    /// A model from a `.gtx` file's bytes.
    pub fn from_gtx(bytes: &[u8]) -> Result<Geoid, String> {
        if bytes.len() < 40 {
            return Err(format!("{} bytes, shorter than a .gtx header (40)", bytes.len()));
        }
        let f = |k: usize| f64::from_be_bytes(bytes[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        let i = |at: usize| i32::from_be_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let (south, west, dlat, dlon) = (f(0), f(1), f(2), f(3));
        let (rows, cols) = (i(32), i(36));
        if rows < 2 || cols < 2 {
            return Err(format!("header says {rows} rows × {cols} columns; need at least 2 × 2"));
        }
        let (rows, cols) = (rows as usize, cols as usize);
        let want = rows.checked_mul(cols).and_then(|n| n.checked_mul(4)).and_then(|n| n.checked_add(40));
        if want != Some(bytes.len()) {
            return Err(format!("{} bytes for a header of {rows} × {cols} nodes ({want:?} expected)", bytes.len()));
        }
        let values = bytes[40..]
            .chunks_exact(4)
            .map(|b| f32::from_be_bytes(b.try_into().expect("4 bytes")))
            .map(|v| if v == GTX_NODATA { f32::NAN } else { v })
            .collect();
        Geoid::checked(Geoid { lat0: south, lon0: west, dlat, dlon, rows, cols, values, wraps: false })
    }

    /// Checks a model read from a file (its `wraps` is worked out here).
    fn checked(g: Geoid) -> Result<Geoid, String> {
        let Geoid { lat0, lon0, dlat, dlon, rows, cols, ref values, .. } = g;
        let finite = [lat0, lon0, dlat, dlon].iter().all(|v| v.is_finite());
        if !finite || dlat == 0.0 || dlon <= 0.0 {
            return Err(format!(
                "origin ({lat0}°, {lon0}°) and steps ({dlat}°, {dlon}°) are not a grid running east with a \
                 latitude step"
            ));
        }
        let last = lat0 + dlat * (rows - 1) as f64;
        if lat0.abs().max(last.abs()) > 90.0 + 1e-9 {
            return Err(format!("rows at latitudes {lat0}..{last}°, beyond ±90°"));
        }
        if values.iter().any(|v| v.is_infinite()) {
            return Err("infinite undulations".into());
        }
        // Around the Earth with no repeated column (PROJ's grids repeat it,
        // and reach the first column's longitude again without wrapping).
        let wraps = ((cols as f64) * dlon - 360.0).abs() < dlon * 1e-6;
        Ok(Geoid { wraps, ..g })
    }

    /// The undulation N at WGS 84 `(lat, lon)` degrees, metres, bilinear
    /// between the four nodes around it; `None` outside the model or where
    /// one of those nodes has no value.
    pub fn undulation(&self, lat: f64, lon: f64) -> Option<f64> {
        const EDGE: f64 = 1e-9;
        let fi = (lat - self.lat0) / self.dlat;
        if !(fi >= -EDGE && fi <= (self.rows - 1) as f64 + EDGE) {
            return None;
        }
        let fj = (lon - self.lon0).rem_euclid(360.0) / self.dlon;
        let last = (self.cols - 1) as f64;
        // A point just west of the first column comes back as ~360°.
        let fj = if fj > last + EDGE && (360.0 / self.dlon - fj) < EDGE { 0.0 } else { fj };
        let (j0, j1, v) = if fj <= last + EDGE {
            let fj = fj.min(last);
            let j0 = (fj.floor() as usize).min(self.cols - 2);
            (j0, j0 + 1, fj - j0 as f64)
        } else if self.wraps {
            (self.cols - 1, 0, fj - last)
        } else {
            return None;
        };
        let fi = fi.clamp(0.0, (self.rows - 1) as f64);
        let i0 = (fi.floor() as usize).min(self.rows - 2);
        let u = fi - i0 as f64;
        let at = |i: usize, j: usize| f64::from(self.values[i * self.cols + j]);
        let n = (1.0 - u) * ((1.0 - v) * at(i0, j0) + v * at(i0, j1))
            + u * ((1.0 - v) * at(i0 + 1, j0) + v * at(i0 + 1, j1));
        n.is_finite().then_some(n)
    }

    /// Adds the undulation to every sample of `hf` that has data, so its
    /// heights become ellipsoidal. `dem` and `model` name the files in
    /// errors: a grid whose CRS cannot be taken to WGS 84, or a sample the
    /// model does not cover.
    pub fn apply(&self, hf: &mut Heightfield, dem: &Path, model: &Path) -> Result<(), DemError> {
        let source =
            SourceCrs::of(&hf.georef.crs, hf.georef.definition.as_deref()).map_err(|why| DemError::Invalid {
                path: dem.to_path_buf(),
                what: format!("a geoid model needs to know where each sample is on the Earth, and {why}"),
            })?;
        let [x0, y0] = hf.georef.origin;
        let [dx, dy] = hf.georef.step;
        let width = hf.width;
        // Row by row in parallel; the first failing row (by index) is the
        // one reported, whatever the thread count.
        let failed: Vec<Option<String>> = hf
            .heights
            .par_chunks_mut(width)
            .enumerate()
            .map(|(i, row)| {
                let y = y0 + dy * i as f64;
                for (j, h) in row.iter_mut().enumerate() {
                    if h.is_nan() {
                        continue;
                    }
                    let x = x0 + dx * j as f64;
                    let Some((lat, lon)) = source.to_wgs84([x, y]) else {
                        return Some(format!("sample (row {i}, column {j}) at ({x}, {y}) is nowhere on the Earth"));
                    };
                    let Some(n) = self.undulation(lat, lon) else {
                        return Some(format!(
                            "does not cover sample (row {i}, column {j}) at {lat:.6}° N, {lon:.6}° E (the model spans \
                             {})",
                            self.extent()
                        ));
                    };
                    match crate::dem::to_height(f64::from(*h) + n) {
                        Ok(v) => *h = v,
                        Err(e) => return Some(format!("sample (row {i}, column {j}) + N {n} m: {e}")),
                    }
                }
                None
            })
            .collect();
        match failed.into_iter().flatten().next() {
            Some(what) => Err(DemError::Invalid { path: model.to_path_buf(), what: format!("geoid model: {what}") }),
            None => Ok(()),
        }
    }

    fn extent(&self) -> String {
        let lat1 = self.lat0 + self.dlat * (self.rows - 1) as f64;
        let lon1 = self.lon0 + self.dlon * (self.cols - 1) as f64;
        format!(
            "latitudes {}..{}°, longitudes {}..{}°{}",
            self.lat0.min(lat1),
            self.lat0.max(lat1),
            self.lon0,
            lon1,
            if self.wraps { " and round the Earth" } else { "" }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `.gtx` over `rows` × `cols` nodes from the south-west corner.
    fn gtx(south: f64, west: f64, step: f64, rows: i32, cols: i32, n: impl Fn(f64, f64) -> f32) -> Vec<u8> {
        let mut b = Vec::new();
        for v in [south, west, step, step] {
            b.extend(v.to_be_bytes());
        }
        b.extend(rows.to_be_bytes());
        b.extend(cols.to_be_bytes());
        for i in 0..rows {
            for j in 0..cols {
                b.extend(n(south + step * f64::from(i), west + step * f64::from(j)).to_be_bytes());
            }
        }
        b
    }

    #[test]
    fn bilinear_between_nodes_is_exact_on_a_plane() {
        let plane = |lat: f64, lon: f64| (10.0 + 2.0 * lat - 0.5 * lon) as f32;
        let g = Geoid::from_gtx(&gtx(40.0, -10.0, 0.25, 9, 9, plane)).unwrap();
        for (lat, lon) in [(40.0, -10.0), (41.3, -9.1), (42.0, -8.0), (40.125, -8.875)] {
            let n = g.undulation(lat, lon).unwrap();
            assert!((n - f64::from(plane(lat, lon))).abs() < 1e-4, "{lat} {lon}: {n}");
        }
        // The same longitude written the other way round the Earth.
        assert_eq!(g.undulation(41.0, 351.0), g.undulation(41.0, -9.0));
        assert_eq!(g.undulation(39.99, -9.0), None, "south of the model");
        assert_eq!(g.undulation(41.0, -7.9), None, "east of the model");
    }

    #[test]
    fn a_model_round_the_earth_wraps_between_its_last_and_first_columns() {
        // 1° nodes from 0° E, 360 columns: 359° E neighbours 0° E.
        let g = Geoid::from_gtx(&gtx(-2.0, 0.0, 1.0, 5, 360, |_, lon| if lon == 0.0 { 4.0 } else { 2.0 })).unwrap();
        assert!((g.undulation(0.0, 359.5).unwrap() - 3.0).abs() < 1e-12);
        assert!((g.undulation(0.0, -0.5).unwrap() - 3.0).abs() < 1e-12);
        assert!((g.undulation(0.0, 0.0).unwrap() - 4.0).abs() < 1e-12);
    }

    #[test]
    fn nodes_without_data_give_no_undulation() {
        let g = Geoid::from_gtx(&gtx(
            0.0,
            0.0,
            1.0,
            3,
            3,
            |lat, lon| if lat == 2.0 && lon == 2.0 { GTX_NODATA } else { 1.0 },
        ))
        .unwrap();
        assert_eq!(g.undulation(0.5, 0.5), Some(1.0));
        assert_eq!(g.undulation(1.5, 1.5), None);
    }

    #[test]
    fn a_truncated_or_inconsistent_gtx_is_refused() {
        let good = gtx(0.0, 0.0, 1.0, 3, 3, |_, _| 1.0);
        assert!(Geoid::from_gtx(&good[..30]).unwrap_err().contains("shorter than a .gtx header"));
        assert!(Geoid::from_gtx(&good[..good.len() - 4]).unwrap_err().contains("3 × 3 nodes"));
        let beyond_pole = gtx(89.0, 0.0, 1.0, 3, 3, |_, _| 1.0);
        assert!(Geoid::from_gtx(&beyond_pole).unwrap_err().contains("beyond ±90°"));
    }
}
