//! VTP Binary Terrain (`.bt`), versions 1.1 to 1.3.
//!
//! A 256-byte little-endian header (vterrain.org/Implementation/Formats/BT):
//! `binterr1.x`; columns i32 @10; rows i32 @14; bytes per sample i16 @18;
//! float flag i16 @20; horizontal units i16 @22 (0 degrees, 1 metres,
//! 2 international feet, 3 US survey feet); UTM zone i16 @24 (negative =
//! south); datum i16 @26 (EPSG datum code); left/right/bottom/top f64
//! @28/36/44/52, the grid's outer edges; external projection flag i16 @60;
//! vertical scale f32 @62 (1.3 only; 0 means 1). Samples follow at byte 256
//! **column by column, west to east, each column from south to north**.
//! Nodata is −32768 (integer samples, and a float sample of exactly −32768
//! as GDAL and the VTP library write it); a float NaN stays NaN.

use std::path::Path;

use super::{DemError, corrupt, file_name, invalid, io_error, sample_count, to_height, unsupported};
use crate::heightfield::{Crs, Georef, Heightfield};

const HEADER: usize = 256;
const NODATA: i32 = -32768;

/// Sample encodings BT allows.
#[derive(Clone, Copy)]
enum Sample {
    I16,
    I32,
    F32,
}

/// Read a BT file.
pub(super) fn load(path: &Path) -> Result<Heightfield, DemError> {
    let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
    if bytes.len() < HEADER {
        return Err(corrupt(path, format!("the file is {} bytes, shorter than the 256-byte BT header", bytes.len())));
    }
    let h = &bytes[..HEADER];
    let version = &h[..10];
    let minor = match version {
        b"binterr1.3" => 3,
        b"binterr1.2" => 2,
        b"binterr1.1" => 1,
        _ => {
            return Err(unsupported(
                path,
                format!("BT header {:?}; terrachunk reads versions 1.1 to 1.3", String::from_utf8_lossy(version)),
            ));
        }
    };
    let i16_at = |o: usize| i16::from_le_bytes([h[o], h[o + 1]]);
    let i32_at = |o: usize| i32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
    let f64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&h[o..o + 8]);
        f64::from_le_bytes(b)
    };

    let cols = i32_at(10);
    let rows = i32_at(14);
    if cols <= 0 || rows <= 0 {
        return Err(corrupt(path, format!("the header says {cols} columns × {rows} rows")));
    }
    let (width, height) = (cols as usize, rows as usize);
    let n = sample_count(path, width, height)?;
    let bytes_per_sample = i16_at(18);
    let float = i16_at(20) != 0;
    let sample = match (bytes_per_sample, float) {
        (2, false) => Sample::I16,
        (4, false) => Sample::I32,
        (4, true) => Sample::F32,
        _ => {
            return Err(unsupported(
                path,
                format!(
                    "{bytes_per_sample}-byte {} samples; BT holds int16, int32 or float32",
                    if float { "float" } else { "integer" }
                ),
            ));
        }
    };
    let units = i16_at(22);
    let unit_m = match units {
        0 | 1 => 1.0,
        2 => 0.3048,
        3 => 1200.0 / 3937.0,
        _ => {
            return Err(corrupt(path, format!("horizontal units code {units} (0–3 are defined)")));
        }
    };
    let zone = i16_at(24);
    let datum = i16_at(26);
    let (left, right, bottom, top) = (f64_at(28), f64_at(36), f64_at(44), f64_at(52));
    let vertical = if minor >= 3 {
        let b = [h[62], h[63], h[64], h[65]];
        match f32::from_le_bytes(b) {
            0.0 => 1.0,
            s if s.is_finite() => s,
            s => return Err(corrupt(path, format!("vertical scale {s} in the header"))),
        }
    } else {
        1.0
    };

    let size = bytes_per_sample as usize;
    let expected = n * size;
    let data = &bytes[HEADER..];
    if data.len() < expected {
        return Err(corrupt(path, format!("expected {expected} bytes of samples, found {}", data.len())));
    }

    // Column-major from the south-west corner → row-major from the north-west.
    let mut heights = vec![f32::NAN; n];
    for (k, b) in data[..expected].chunks_exact(size).enumerate() {
        let col = k / height;
        let row = height - 1 - k % height;
        let v = match sample {
            Sample::I16 => {
                let v = i16::from_le_bytes([b[0], b[1]]);
                if i32::from(v) == NODATA { f32::NAN } else { f32::from(v) * vertical }
            }
            Sample::I32 => {
                let v = i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                if v == NODATA {
                    f32::NAN
                } else {
                    to_height(f64::from(v) * f64::from(vertical))
                        .map_err(|e| invalid(path, format!("sample (row {row}, column {col}): {e}")))?
                }
            }
            Sample::F32 => {
                let v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                if v == NODATA as f32 { f32::NAN } else { v * vertical }
            }
        };
        heights[row * width + col] = v;
    }

    // The extents are the outer edges; sample centres sit half a cell in.
    let dx = (right - left) / width as f64;
    let dy = (top - bottom) / height as f64;
    let origin = [left + dx / 2.0, top - dy / 2.0];
    let mut hf = Heightfield {
        width,
        height,
        heights: heights.into(),
        spacing_m: [dx * unit_m, dy * unit_m],
        georef: Georef { crs: Crs::Unknown, origin, step: [dx, -dy], local_tangent: None, definition: None },
        source: file_name(path),
    };
    if units == 0 {
        hf.georef.crs = Crs::Geographic { epsg: geographic_epsg(datum) };
        if dx.is_finite() && dy.is_finite() && dx > 0.0 && dy > 0.0 {
            hf.apply_local_tangent();
        }
    } else {
        hf.georef.crs = Crs::Projected { epsg: utm_epsg(datum, zone) };
    }
    Ok(hf)
}

/// EPSG geographic CRS for the datums BT files commonly carry.
fn geographic_epsg(datum: i16) -> Option<u32> {
    match datum {
        6326 => Some(4326),
        6269 => Some(4269),
        6267 => Some(4267),
        6258 => Some(4258),
        _ => None,
    }
}

/// EPSG code of a UTM zone (negative = south) on a known datum.
fn utm_epsg(datum: i16, zone: i16) -> Option<u32> {
    if zone == 0 || zone.unsigned_abs() > 60 {
        return None;
    }
    let z = u32::from(zone.unsigned_abs());
    match (datum, zone > 0) {
        (6326, true) => Some(32600 + z),
        (6326, false) => Some(32700 + z),
        (6269, true) if z <= 23 => Some(26900 + z),
        (6267, true) if z <= 22 => Some(26700 + z),
        _ => None,
    }
}
