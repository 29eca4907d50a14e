//! PNG heightmaps, decoded by the `image` crate.
//!
//! - 8- or 16-bit grayscale: the pixel value is the height in metres.
//! - 8-bit RGB or RGBA: Mapbox Terrain-RGB,
//!   h = −10000 + (R·65536 + G·256 + B)·0.1 m.
//!
//! An alpha of 0 (an alpha channel, or a grayscale `tRNS` colour) marks
//! nodata. A PNG carries no georeference: the grid is placed at the origin
//! with 1 m spacing unless the caller overrides it. Palette images and
//! grayscale below 8 bits are refused rather than guessed at: the decoder
//! would expand them to colours or rescaled levels, not heights.

use std::io::{Read, Seek};
use std::path::Path;

use image::{DynamicImage, ImageError, ImageFormat, ImageReader};

use super::{DemError, check_expansion, corrupt, file_name, io_error, sample_count, unsupported};
use crate::heightfield::Heightfield;

/// Read a PNG heightmap.
pub(super) fn load(path: &Path) -> Result<Heightfield, DemError> {
    let file = std::fs::File::open(path).map_err(|e| io_error(path, e))?;
    let file_len = file.metadata().map_err(|e| io_error(path, e))?.len();
    let mut bytes = Vec::with_capacity(33);
    (&file).take(33).read_to_end(&mut bytes).map_err(|e| io_error(path, e))?;
    // IHDR is always the first chunk: width, height, bit depth, colour type.
    if bytes.len() < 33 || &bytes[12..16] != b"IHDR" {
        return Err(corrupt(path, "the PNG header (IHDR) is missing or cut short"));
    }
    let be32 = |o: usize| u32::from_be_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let (w, h) = (be32(16) as usize, be32(20) as usize);
    let depth = bytes[24];
    let colour = bytes[25];
    match (colour, depth) {
        (3, d) => {
            return Err(unsupported(
                path,
                format!(
                    "{d}-bit palette (colour-mapped) PNG; a DEM needs grayscale heights or \
                     Terrain-RGB"
                ),
            ));
        }
        (0 | 4, d) if d < 8 => {
            return Err(unsupported(path, format!("{d}-bit grayscale PNG; heights need 8 or 16 bits")));
        }
        (2 | 6, 16) => {
            return Err(unsupported(path, "16-bit RGB PNG; Terrain-RGB is 8-bit RGB or RGBA"));
        }
        _ => {}
    }
    let n = sample_count(path, w, h)?;
    // The grid this becomes (f32 heights), against the file: a header
    // promising far more than any DEM compresses to is refused before the
    // decoder allocates for it.
    check_expansion((w, h), 4, file_len).map_err(|e| corrupt(path, e))?;

    let mut file = std::io::BufReader::new(file);
    file.seek(std::io::SeekFrom::Start(0)).map_err(|e| io_error(path, e))?;
    let mut reader = ImageReader::with_format(file, ImageFormat::Png);
    reader.no_limits();
    let image = reader.decode().map_err(|e| image_error(path, e))?;

    let mut heights = Vec::with_capacity(n);
    match image {
        DynamicImage::ImageLuma8(img) => heights.extend(img.pixels().map(|p| f32::from(p.0[0]))),
        DynamicImage::ImageLuma16(img) => heights.extend(img.pixels().map(|p| f32::from(p.0[0]))),
        DynamicImage::ImageLumaA8(img) => {
            heights.extend(img.pixels().map(|p| if p.0[1] == 0 { f32::NAN } else { f32::from(p.0[0]) }))
        }
        DynamicImage::ImageLumaA16(img) => {
            heights.extend(img.pixels().map(|p| if p.0[1] == 0 { f32::NAN } else { f32::from(p.0[0]) }))
        }
        DynamicImage::ImageRgb8(img) => heights.extend(img.pixels().map(|p| terrain_rgb(p.0[0], p.0[1], p.0[2]))),
        DynamicImage::ImageRgba8(img) => heights
            .extend(img.pixels().map(|p| if p.0[3] == 0 { f32::NAN } else { terrain_rgb(p.0[0], p.0[1], p.0[2]) })),
        other => {
            return Err(unsupported(
                path,
                format!("PNG colour layout {:?}; a DEM needs 8/16-bit grayscale or 8-bit Terrain-RGB", other.color()),
            ));
        }
    }
    if heights.len() != n {
        return Err(corrupt(path, format!("expected {n} samples, decoded {}", heights.len())));
    }
    Ok(Heightfield::ungeoreferenced(w, h, heights, file_name(path)))
}

/// Mapbox Terrain-RGB: 0.1 m steps from −10 000 m.
fn terrain_rgb(r: u8, g: u8, b: u8) -> f32 {
    let code = u32::from(r) * 65536 + u32::from(g) * 256 + u32::from(b);
    (-10_000.0 + f64::from(code) * 0.1) as f32
}

fn image_error(path: &Path, e: ImageError) -> DemError {
    match e {
        ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            corrupt(path, format!("the PNG ends early (truncated?): {io}"))
        }
        ImageError::IoError(io) => io_error(path, io),
        ImageError::Unsupported(u) => unsupported(path, format!("PNG: {u}")),
        ImageError::Limits(l) => unsupported(path, format!("PNG: {l}")),
        other => corrupt(path, format!("PNG: {other}")),
    }
}
