//! The height grids a benchmark runs on: the whole DEM, a (2^k+1)² square
//! for pymartini, or a centred window for the scaling runs; and the files
//! that carry exactly those heights to the other tools (a float32 TIFF for
//! `terrachunk build`, a `.npy` array for the Python peers).

use std::io::Write;
use std::path::Path;

use crate::heightfield::Heightfield;

use super::BenchError;

/// How many rows and columns [`square`] cropped or padded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SquareChange {
    /// Columns removed (positive) or added by repeating the last one (negative).
    pub columns: i64,
    /// Rows removed (positive) or added by repeating the last one (negative).
    pub rows: i64,
}

/// The top-left `n × n` samples of `hf`; where the grid is narrower or
/// shorter than `n`, the last column or row is repeated to fill it (as
/// Martini's own demo does to turn a 512² tile into 513²). Spacing and
/// georeference are kept (the north-west corner does not move).
pub fn square(hf: &Heightfield, n: usize) -> (Heightfield, SquareChange) {
    let mut heights = Vec::with_capacity(n * n);
    for i in 0..n {
        let si = i.min(hf.height - 1);
        for j in 0..n {
            heights.push(hf.get(si, j.min(hf.width - 1)));
        }
    }
    let change = SquareChange { columns: hf.width as i64 - n as i64, rows: hf.height as i64 - n as i64 };
    (Heightfield { width: n, height: n, heights: heights.into(), ..hf.clone() }, change)
}

/// The centred window holding about `1/fraction` of the samples (each side
/// divided by √fraction, at least 2 samples).
pub fn centred_window(hf: &Heightfield, fraction: u32) -> Heightfield {
    let f = f64::from(fraction.max(1)).sqrt();
    let w = ((hf.width as f64 / f).round() as usize).clamp(2, hf.width);
    let h = ((hf.height as f64 / f).round() as usize).clamp(2, hf.height);
    let (x0, z0) = ((hf.width - w) / 2, (hf.height - h) / 2);
    let mut heights = Vec::with_capacity(w * h);
    for i in z0..z0 + h {
        heights.extend_from_slice(&hf.heights[i * hf.width + x0..i * hf.width + x0 + w]);
    }
    let mut georef = hf.georef.clone();
    georef.origin = [georef.origin[0] + georef.step[0] * x0 as f64, georef.origin[1] + georef.step[1] * z0 as f64];
    Heightfield { width: w, height: h, heights: heights.into(), georef, ..hf.clone() }
}

/// Writes the grid as an uncompressed float32 GeoTIFF without GeoKeys (NaN =
/// nodata), which `dem::load` reads back bit for bit. The spacing is not in
/// the file: pass it to `build` with `--spacing`.
pub fn write_f32_tiff(hf: &Heightfield, path: &Path) -> Result<(), BenchError> {
    let io = |source| BenchError::Io { path: path.into(), source };
    let file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    let mut enc = tiff::encoder::TiffEncoder::new(file).map_err(|e| BenchError::tiff(path, e))?;
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(hf.width as u32, hf.height as u32, &hf.heights)
        .map_err(|e| BenchError::tiff(path, e))
}

/// Writes the grid as a NumPy `.npy` file: little-endian float32, C order,
/// shape `(rows, columns)`, NaN = nodata (format version 1.0).
pub fn write_npy(hf: &Heightfield, path: &Path) -> Result<(), BenchError> {
    let io = |source| BenchError::Io { path: path.into(), source };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}", hf.height, hf.width);
    // Magic (6) + version (2) + length (2) + header + '\n', padded to 64 bytes.
    let total = 10 + header.len() + 1;
    header.extend(std::iter::repeat_n(' ', total.next_multiple_of(64) - total));
    header.push('\n');
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    out.write_all(b"\x93NUMPY\x01\x00").map_err(io)?;
    out.write_all(&(header.len() as u16).to_le_bytes()).map_err(io)?;
    out.write_all(header.as_bytes()).map_err(io)?;
    for h in &hf.heights {
        out.write_all(&h.to_le_bytes()).map_err(io)?;
    }
    out.flush().map_err(io)
}
