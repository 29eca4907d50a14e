//! GeoTIFF: one band of integer or float samples, in strips or tiles,
//! uncompressed or compressed (LZW, DEFLATE, PackBits, with or without the
//! horizontal predictor), decoded by the `tiff` crate chunk by chunk straight
//! into the final `f32` grid, so a 40 M-sample DEM needs no second full copy.
//!
//! Georeference comes from the GeoTIFF tags (OGC GeoTIFF 1.1):
//! ModelPixelScale (33550) and ModelTiepoint (33922), or a ModelTransformation
//! (34264) in their place, and the GeoKeyDirectory (34735) for the model type
//! (1024), raster type (1025: PixelIsArea puts the tie point on a pixel's
//! corner, PixelIsPoint on its centre), the EPSG codes (2048, 3072) and the
//! projected linear unit (3076). Nodata is GDAL's ASCII tag GDAL_NODATA
//! (42113); a float NaN is nodata whether declared or not (GDAL's
//! convention). Samples wider than `f32` (32/64-bit integers, float64) must
//! fit it within 1 mm (see `super::MAX_ROUNDING_M`). A TIFF without GeoKeys
//! is a plain grid with 1 m spacing.
//!
//! The same tags place an 8-bit gray/RGB(A) TIFF used as a texture
//! ([`load_rgb8`]); the DEM reader itself refuses colour images.
//!
//! A projected grid's spacing is in metres: its steps times the linear
//! unit, from the ProjLinearUnits key or else the EPSG code's definition
//! (US State Plane grids are often in US survey feet and say so only by
//! their code). Mercator (Web Mercator, EPSG:3857 and its aliases, above
//! all) is not a metric grid on the ground: its "metres" are stretched by
//! 1/cos(latitude). Its spacing is therefore scaled by cos(latitude) at the
//! grid centre (`geodesy::SourceCrs::ground_per_grid_m`), so heights and
//! horizontal distances are both true metres.

use std::cell::Cell;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;
use std::rc::Rc;

use tiff::TiffError;
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

use super::{DemError, check_expansion, corrupt, file_name, invalid, io_error, sample_count, to_height, unsupported};
use crate::geodesy::SourceCrs;
use crate::heightfield::{Crs, Heightfield};
use crate::store::{Big, Memory};

/// GeoKey ids (GeoTIFF 1.1, section 7).
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GEOGRAPHIC_TYPE: u16 = 2048;
const PROJECTED_CS_TYPE: u16 = 3072;
const PROJ_LINEAR_UNITS: u16 = 3076;

/// The file under the decoder, readable only within one byte range while
/// a strip or tile is decoded: the `tiff` crate reads an uncompressed or
/// DEFLATE chunk for as long as its decoder asks, past the byte count the
/// file declares for it, into the next chunk, the tags or padding.
struct Fenced {
    file: File,
    pos: u64,
    /// `[start, end)` while a chunk is read, shared with [`read_chunks`].
    fence: Rc<Cell<Option<(u64, u64)>>>,
    /// Set when a read stopped at the fence's end.
    hit: Rc<Cell<bool>>,
}

impl Read for Fenced {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let room = match self.fence.get() {
            Some((start, end)) if self.pos < start || self.pos >= end => {
                self.hit.set(self.pos >= end);
                return Ok(0);
            }
            Some((_, end)) => usize::try_from(end - self.pos).unwrap_or(usize::MAX).min(buf.len()),
            None => buf.len(),
        };
        let n = self.file.read(&mut buf[..room])?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for Fenced {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.file.seek(to)?;
        Ok(self.pos)
    }
}

type TiffDecoder = Decoder<BufReader<Fenced>>;

/// The fence of a [`Fenced`] file, as [`read_chunks`] sets it.
struct Fences {
    fence: Rc<Cell<Option<(u64, u64)>>>,
    hit: Rc<Cell<bool>>,
}

/// A TIFF opened for reading, with its file size and dimensions.
struct Opened {
    dec: TiffDecoder,
    file_len: u64,
    width: usize,
    height: usize,
    fences: Fences,
}

/// Opens `path` with tag limits sized from the file and reads its dimensions.
fn open(path: &Path) -> Result<Opened, DemError> {
    let file = File::open(path).map_err(|e| io_error(path, e))?;
    let file_len = file.metadata().map_err(|e| io_error(path, e))?.len();
    let (fence, hit) = (Rc::new(Cell::new(None)), Rc::new(Cell::new(false)));
    let fenced = Fenced { file, pos: 0, fence: fence.clone(), hit: hit.clone() };
    let mut dec =
        Decoder::new(BufReader::new(fenced)).map_err(|e| tiff_error(path, e))?.with_limits(tag_limits(file_len));
    let (w, h) = dec.dimensions().map_err(|e| tiff_error(path, e))?;
    Ok(Opened { dec, file_len, width: w as usize, height: h as usize, fences: Fences { fence, hit } })
}

/// Read a GeoTIFF DEM.
pub(crate) fn load(path: &Path) -> Result<Heightfield, DemError> {
    load_in(path, None)
}

/// [`load`], the samples decoded straight into a scratch file where
/// `memory` says a grid this size goes to one.
pub(crate) fn load_in(path: &Path, memory: Option<&Memory>) -> Result<Heightfield, DemError> {
    let (mut hf, raw) = load_unplaced(path, memory)?;
    if let Some(raw) = raw {
        place_grid(&mut hf, raw);
    }
    Ok(hf)
}

/// The samples as the file stores them (rows and columns in file order, a
/// ungeoreferenced grid) and the georeference its tags give, not applied
/// yet ([`place_grid`]): what a mosaic of GeoTIFFs assembles from.
fn load_unplaced(path: &Path, memory: Option<&Memory>) -> Result<(Heightfield, Option<RawGeoref>), DemError> {
    let Window { heights, size: (width, height), georef, .. } = read_samples(path, None, memory)?;
    Ok((Heightfield::ungeoreferenced(width, height, heights, file_name(path)), georef))
}

/// The samples of `window` (`[column, row, width, height]`, inside the
/// image) as [`load_unplaced`] reads them, decoding only the strips or
/// tiles that meet it.
pub(crate) fn load_window(path: &Path, window: [usize; 4], memory: Option<&Memory>) -> Result<Window, DemError> {
    read_samples(path, Some(window), memory)
}

/// The samples of `window`, or of the whole image.
fn read_samples(path: &Path, window: Option<[usize; 4]>, memory: Option<&Memory>) -> Result<Window, DemError> {
    let Opened { mut dec, file_len, width, height, fences } = open(path)?;
    let err = |e: TiffError| tiff_error(path, e);
    let window = window.unwrap_or([0, 0, width, height]);
    let [wx, wy, ww, wh] = window;
    if ww == 0 || wh == 0 || wx.saturating_add(ww) > width || wy.saturating_add(wh) > height {
        return Err(invalid(
            path,
            format!("a window of {ww} × {wh} samples at column {wx}, row {wy} is not inside its {width} × {height}"),
        ));
    }
    let n = sample_count(path, ww, wh)?;
    check_layout(path, &mut dec)?;
    check_chunks_present(path, &mut dec, file_len, (width, height), 4)?;
    let nodata = match dec.find_tag(Tag::GdalNodata).map_err(err)? {
        Some(tiff::decoder::ifd::Value::Ascii(s)) => parse_nodata(path, &s)?,
        Some(other) => {
            return Err(corrupt(path, format!("GDAL_NODATA tag is {other:?}, not text")));
        }
        None => None,
    };
    let mut heights = Big::filled(n, f32::NAN, memory).map_err(|e| super::io_error(path, e))?;
    let whole = window == [0, 0, width, height];
    let mut scratch = Vec::new();
    let (dec, decoded) = read_chunks(
        path,
        (dec, &fences),
        file_len,
        (width, height),
        8,
        ("samples", window),
        |chunk, [x0, y0, dw, dh]| {
            if whole {
                return place(path, &mut heights, width, x0, y0, dw, dh, chunk, nodata);
            }
            scratch.clear();
            scratch.resize(dw * dh, f32::NAN);
            place(path, &mut scratch, dw, 0, 0, dw, dh, chunk, nodata).map_err(|e| match e {
                DemError::Invalid { path, what } => {
                    DemError::Invalid { path, what: format!("{what}, in the chunk at column {x0}, row {y0}") }
                }
                e => e,
            })?;
            // The part of the chunk inside the window.
            let (c0, c1) = (x0.max(wx), (x0 + dw).min(wx + ww));
            let (r0, r1) = (y0.max(wy), (y0 + dh).min(wy + wh));
            for r in r0..r1 {
                let src = &scratch[(r - y0) * dw + (c0 - x0)..(r - y0) * dw + (c1 - x0)];
                heights[(r - wy) * ww + (c0 - wx)..(r - wy) * ww + (c1 - wx)].copy_from_slice(src);
            }
            Ok(())
        },
    )?;
    let mut dec = dec.with_limits(tag_limits(file_len));
    Ok(Window { heights, size: (width, height), georef: raw_georef(path, &mut dec)?, decoded })
}

/// What [`load_window`] read.
pub(crate) struct Window {
    /// Row-major samples of the window, NaN = nodata.
    pub heights: Big<f32>,
    /// The whole image: columns, rows.
    pub size: (usize, usize),
    /// The file's georeference, as stored.
    pub georef: Option<RawGeoref>,
    /// Strips or tiles decoded (the tests check that a window decodes only
    /// those under it).
    #[cfg_attr(not(test), allow(dead_code))]
    pub decoded: usize,
}

/// Limits for reading tags: a tag cannot hold more values than the file has
/// bytes, so a corrupt count is refused instead of allocated. (The `tiff`
/// crate bounds tag arrays by `decoding_buffer_size`.)
fn tag_limits(file_len: u64) -> Limits {
    let mut limits = Limits::default();
    let values = usize::try_from(file_len).unwrap_or(usize::MAX).saturating_add(4096);
    limits.decoding_buffer_size = values.saturating_mul(std::mem::size_of::<tiff::decoder::ifd::Value>());
    limits.intermediate_buffer_size = usize::try_from(file_len).unwrap_or(usize::MAX);
    limits
}

/// Decodes every strip or tile that lies on the image and meets `window`
/// (`[x0, y0, width, height]`), in file order, and hands each to `take`
/// with its first pixel and its size cropped to the image (`[x0, y0,
/// width, height]`; the decoder crops edge tiles and the last strip
/// alike); returns the decoder and how many it decoded. Extra planes or stray chunks beyond the image are
/// skipped. While decoding, the buffer limit is one chunk of at most
/// `bytes_per_pixel`; `unit` names a pixel in the error for empty chunks.
/// Each chunk is read only within the bytes its StripByteCounts or
/// TileByteCounts entry declares: a chunk that needs more is an error.
fn read_chunks(
    path: &Path,
    (dec, fences): (TiffDecoder, &Fences),
    file_len: u64,
    (width, height): (usize, usize),
    bytes_per_pixel: usize,
    (unit, window): (&str, [usize; 4]),
    mut take: impl FnMut(DecodingResult, [usize; 4]) -> Result<(), DemError>,
) -> Result<(TiffDecoder, usize), DemError> {
    let err = |e: TiffError| tiff_error(path, e);
    let (cw, ch) = dec.chunk_dimensions();
    let (cw, ch) = (cw as usize, ch as usize);
    if cw == 0 || ch == 0 {
        return Err(corrupt(path, format!("chunks of {cw} × {ch} {unit}")));
    }
    let mut limits = tag_limits(file_len);
    limits.decoding_buffer_size =
        cw.min(width).saturating_mul(ch.min(height)).saturating_mul(bytes_per_pixel).saturating_add(1 << 16);
    let mut dec = dec.with_limits(limits);
    let chunk_type = dec.get_chunk_type();
    let (across, count) = match chunk_type {
        ChunkType::Strip => (1, dec.strip_count().map_err(err)?),
        ChunkType::Tile => (width.div_ceil(cw), dec.tile_count().map_err(err)?),
    };
    let (offsets_tag, counts_tag, what) = match chunk_type {
        ChunkType::Strip => (Tag::StripOffsets, Tag::StripByteCounts, "strip"),
        ChunkType::Tile => (Tag::TileOffsets, Tag::TileByteCounts, "tile"),
    };
    let offsets = dec.get_tag_u64_vec(offsets_tag).map_err(err)?;
    let counts = dec.get_tag_u64_vec(counts_tag).map_err(err)?;
    let [wx, wy, ww, wh] = window;
    let mut decoded = 0;
    for idx in 0..count {
        let (x0, y0) = match chunk_type {
            ChunkType::Strip => (0, idx as usize * ch),
            ChunkType::Tile => ((idx as usize % across) * cw, (idx as usize / across) * ch),
        };
        if x0 >= width || y0 >= height {
            continue;
        }
        if x0 >= wx + ww || x0 + cw <= wx || y0 >= wy + wh || y0 + ch <= wy {
            continue;
        }
        let (Some(&offset), Some(&bytes)) = (offsets.get(idx as usize), counts.get(idx as usize)) else {
            return Err(corrupt(path, format!("{what} {idx} has no offset or byte count")));
        };
        fences.fence.set(Some((offset, offset.saturating_add(bytes))));
        fences.hit.set(false);
        let chunk = dec.read_chunk(idx);
        fences.fence.set(None);
        let chunk = chunk.map_err(|e| match e {
            TiffError::IoError(_) if fences.hit.get() => corrupt(
                path,
                format!("{what} {idx} needs more than the {bytes} bytes its {counts_tag:?} entry declares"),
            ),
            e => err(e),
        })?;
        take(chunk, [x0, y0, cw.min(width - x0), ch.min(height - y0)])?;
        decoded += 1;
    }
    Ok((dec, decoded))
}

/// Refuse, with a message a user understands, every layout that is not one
/// band of numbers.
fn check_layout(path: &Path, dec: &mut TiffDecoder) -> Result<(), DemError> {
    let err = |e: TiffError| tiff_error(path, e);
    let samples: u16 = dec.find_tag_unsigned(Tag::SamplesPerPixel).map_err(err)?.unwrap_or(1);
    let photometric: u16 = dec.find_tag_unsigned(Tag::PhotometricInterpretation).map_err(err)?.unwrap_or(1);
    let bits: u16 = dec
        .find_tag_unsigned_vec::<u16>(Tag::BitsPerSample)
        .map_err(err)?
        .and_then(|v| v.first().copied())
        .unwrap_or(1);
    let format: u16 =
        dec.find_tag_unsigned_vec::<u16>(Tag::SampleFormat).map_err(err)?.and_then(|v| v.first().copied()).unwrap_or(1);
    let compression: u16 = dec.find_tag_unsigned(Tag::Compression).map_err(err)?.unwrap_or(1);

    if samples != 1 {
        let kind = match (photometric, samples) {
            (2, 3) => "RGB".to_string(),
            (2, 4) => "RGBA".to_string(),
            (5, _) => "CMYK".to_string(),
            (6, _) => "YCbCr".to_string(),
            _ => format!("{samples} bands"),
        };
        return Err(unsupported(path, format!("{samples} samples per pixel ({kind}); a DEM needs one band")));
    }
    if photometric == 3 {
        return Err(unsupported(
            path,
            format!("{bits}-bit palette (colour-mapped) image; a DEM needs one band of heights"),
        ));
    }
    let kind = match format {
        1 => "unsigned integer",
        2 => "signed integer",
        3 => "floating-point",
        _ => {
            return Err(unsupported(
                path,
                format!("sample format {format} (complex or undefined); a DEM needs numbers"),
            ));
        }
    };
    let ok_bits = match format {
        3 => matches!(bits, 16 | 32 | 64),
        _ => matches!(bits, 8 | 16 | 32 | 64),
    };
    if !ok_bits {
        return Err(unsupported(path, format!("{bits}-bit {kind} samples; terrachunk reads 8, 16, 32 and 64 bits")));
    }
    let compression_name = match compression {
        1 => None,
        5 | 8 | 32946 | 32773 => None,
        2 => Some("CCITT Huffman"),
        3 | 4 => Some("CCITT fax"),
        6 | 7 => Some("JPEG"),
        34887 => Some("LERC"),
        34925 => Some("LZMA"),
        50000 => Some("ZSTD"),
        50001 => Some("WebP"),
        _ => Some("unknown"),
    };
    if let Some(name) = compression_name {
        return Err(unsupported(
            path,
            format!(
                "compression {compression} ({name}); terrachunk reads uncompressed, LZW, \
                 DEFLATE and PackBits TIFFs"
            ),
        ));
    }
    Ok(())
}

/// Check that every strip or tile the image needs is listed and lies inside
/// the file, so a truncated download says so instead of a decoder error.
fn check_chunks_present(
    path: &Path,
    dec: &mut TiffDecoder,
    file_len: u64,
    (width, height): (usize, usize),
    decoded_bytes_per_pixel: u64,
) -> Result<(), DemError> {
    let err = |e: TiffError| tiff_error(path, e);
    let (offsets_tag, counts_tag, what) = match dec.get_chunk_type() {
        ChunkType::Strip => (Tag::StripOffsets, Tag::StripByteCounts, "strips"),
        ChunkType::Tile => (Tag::TileOffsets, Tag::TileByteCounts, "tiles"),
    };
    let offsets = dec.get_tag_u64_vec(offsets_tag).map_err(err)?;
    let counts = dec.get_tag_u64_vec(counts_tag).map_err(err)?;
    let (cw, ch) = dec.chunk_dimensions();
    let needed = if cw == 0 || ch == 0 { 0 } else { width.div_ceil(cw as usize) * height.div_ceil(ch as usize) };
    if offsets.len() < needed || counts.len() < offsets.len() {
        return Err(corrupt(
            path,
            format!(
                "the image needs {needed} {what} but the file lists {} offsets and {} sizes",
                offsets.len(),
                counts.len()
            ),
        ));
    }
    let mut expected: u64 = 0;
    let mut found: u64 = 0;
    for (&off, &len) in offsets.iter().zip(&counts).take(needed) {
        expected = expected.saturating_add(len);
        found = found.saturating_add(len.min(file_len.saturating_sub(off)));
    }
    if found < expected {
        return Err(corrupt(
            path,
            format!(
                "expected {expected} bytes of samples, found {found} (the file is {file_len} \
                 bytes long; truncated?)"
            ),
        ));
    }
    check_expansion((width, height), decoded_bytes_per_pixel, expected).map_err(|e| corrupt(path, e))
}

/// GDAL_NODATA: decimal text, or "nan". Returns the value to map to NaN
/// (None when nodata is NaN already or absent).
fn parse_nodata(path: &Path, text: &str) -> Result<Option<f64>, DemError> {
    let t = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    if t.is_empty() {
        return Ok(None);
    }
    match t.parse::<f64>() {
        Ok(v) if v.is_nan() => Ok(None),
        Ok(v) => Ok(Some(v)),
        Err(_) => Err(corrupt(path, format!("GDAL_NODATA tag {t:?} is not a number"))),
    }
}

/// Copy one decoded chunk (`dw × dh` samples, rows packed) into the grid at
/// `(x0, y0)`, turning the declared nodata value into NaN.
#[allow(clippy::too_many_arguments)]
fn place(
    path: &Path,
    dst: &mut [f32],
    width: usize,
    x0: usize,
    y0: usize,
    dw: usize,
    dh: usize,
    chunk: DecodingResult,
    nodata: Option<f64>,
) -> Result<(), DemError> {
    fn copy<T: Copy>(
        dst: &mut [f32],
        width: usize,
        x0: usize,
        y0: usize,
        dw: usize,
        dh: usize,
        src: &[T],
        conv: impl Fn(T) -> f32,
    ) -> bool {
        if src.len() < dw * dh {
            return false;
        }
        for r in 0..dh {
            let start = (y0 + r) * width + x0;
            let Some(out) = dst.get_mut(start..start + dw) else {
                return false;
            };
            for (o, &v) in out.iter_mut().zip(&src[r * dw..(r + 1) * dw]) {
                *o = conv(v);
            }
        }
        true
    }
    // Samples wider than f32 (32/64-bit integers, float64) must fit it within
    // 1 mm (see `super::MAX_ROUNDING_M`); nodata is exempt.
    fn check_wide<T: Copy + PartialEq>(
        path: &Path,
        src: &[T],
        dw: usize,
        dh: usize,
        (x0, y0): (usize, usize),
        nodata: Option<T>,
        wide: impl Fn(T) -> f64,
    ) -> Result<(), DemError> {
        for (k, &v) in src.iter().take(dw * dh).enumerate() {
            if Some(v) != nodata {
                to_height(wide(v))
                    .map_err(|e| invalid(path, format!("sample (row {}, column {}): {e}", y0 + k / dw, x0 + k % dw)))?;
            }
        }
        Ok(())
    }
    // Integer nodata is compared exactly in the sample's own type; a value
    // that the type cannot hold never matches.
    macro_rules! int {
        ($src:expr, $t:ty) => {{
            let nd: Option<$t> = nodata.and_then(|v| {
                if v.fract() == 0.0 && v >= <$t>::MIN as f64 && v <= <$t>::MAX as f64 { Some(v as $t) } else { None }
            });
            if std::mem::size_of::<$t>() >= 4 {
                check_wide(path, &$src, dw, dh, (x0, y0), nd, |v: $t| v as f64)?;
            }
            match nd {
                Some(nd) => copy(dst, width, x0, y0, dw, dh, &$src, |v: $t| if v == nd { f32::NAN } else { v as f32 }),
                None => copy(dst, width, x0, y0, dw, dh, &$src, |v: $t| v as f32),
            }
        }};
    }
    let nd32 = nodata.map(|v| v as f32);
    let float = |v: f32| if Some(v) == nd32 { f32::NAN } else { v };
    let ok = match chunk {
        DecodingResult::U8(s) => int!(s, u8),
        DecodingResult::I8(s) => int!(s, i8),
        DecodingResult::U16(s) => int!(s, u16),
        DecodingResult::I16(s) => int!(s, i16),
        DecodingResult::U32(s) => int!(s, u32),
        DecodingResult::I32(s) => int!(s, i32),
        DecodingResult::U64(s) => int!(s, u64),
        DecodingResult::I64(s) => int!(s, i64),
        DecodingResult::F16(s) => copy(dst, width, x0, y0, dw, dh, &s, |v| float(v.to_f32())),
        DecodingResult::F32(s) => copy(dst, width, x0, y0, dw, dh, &s, float),
        DecodingResult::F64(s) => {
            let nd = nodata;
            check_wide(path, &s, dw, dh, (x0, y0), nd, |v| v)?;
            copy(dst, width, x0, y0, dw, dh, &s, |v: f64| if Some(v) == nd { f32::NAN } else { v as f32 })
        }
    };
    if ok {
        Ok(())
    } else {
        Err(corrupt(path, format!("a chunk at sample ({x0}, {y0}) decoded to fewer samples than its size")))
    }
}

/// The georeference as the file stores it, before the grid is turned
/// north-up: model coordinates of the centre of pixel (0, 0), the step per
/// pixel (signs as stored), the CRS and the projected linear unit in metres.
#[derive(Clone, Debug)]
pub(crate) struct RawGeoref {
    /// Centre of pixel (0, 0) in model units.
    pub origin: [f64; 2],
    /// Model units per pixel along a row and down a column (`step[1] < 0` for north-up).
    pub step: [f64; 2],
    /// Model type and EPSG code.
    pub crs: Crs,
    /// Metres per projected unit (1 unless the file says feet or kilometres).
    pub unit_m: f64,
}

/// Reads the GeoTIFF tags (None: the file has no GeoKeys or no transform).
fn raw_georef<R: std::io::Read + std::io::Seek>(
    path: &Path,
    dec: &mut Decoder<R>,
) -> Result<Option<RawGeoref>, DemError> {
    let err = |e: TiffError| tiff_error(path, e);
    let keys = match dec.find_tag(Tag::GeoKeyDirectoryTag).map_err(err)? {
        Some(v) => geokeys(&v.into_u16_vec().map_err(err)?),
        None => return Ok(None),
    };
    let scale =
        dec.find_tag(Tag::ModelPixelScaleTag).map_err(err)?.map(|v| v.into_f64_vec()).transpose().map_err(err)?;
    let tie = dec.find_tag(Tag::ModelTiepointTag).map_err(err)?.map(|v| v.into_f64_vec()).transpose().map_err(err)?;
    let transform =
        dec.find_tag(Tag::ModelTransformationTag).map_err(err)?.map(|v| v.into_f64_vec()).transpose().map_err(err)?;

    // Raster (I, J) → model (X, Y) as X = tx + (I − ti)·sx, Y = ty − (J − tj)·sy.
    let (sx, sy, ti, tj, tx, ty) = match (scale, tie, transform) {
        (Some(s), Some(t), _) if s.len() >= 2 && t.len() >= 6 => (s[0], s[1], t[0], t[1], t[3], t[4]),
        (_, _, Some(m)) if m.len() >= 16 => {
            // A grid turned or sheared against its CRS would be placed
            // wrongly as a north-up one: refused where the turn moves its far
            // corner by half a cell or more, ignored below that (rounding
            // in the file's matrix).
            let (w, h) = dec.dimensions().map_err(err)?;
            let (cols, rows) = (f64::from(w.max(1) - 1), f64::from(h.max(1) - 1));
            if m[1].abs() * rows >= 0.5 * m[0].abs() || m[4].abs() * cols >= 0.5 * m[5].abs() {
                return Err(unsupported(
                    path,
                    format!(
                        "its ModelTransformation turns the grid against its coordinate system \
                         ([{}, {}; {}, {}]): terrachunk reads north-up grids; warp it north-up first \
                         (gdalwarp)",
                        m[0], m[1], m[4], m[5]
                    ),
                ));
            }
            let sx = m[0].hypot(m[4]) * if m[0] < 0.0 { -1.0 } else { 1.0 };
            let sy = m[1].hypot(m[5]) * if m[5] > 0.0 { -1.0 } else { 1.0 };
            (sx, sy, 0.0, 0.0, m[3], m[7])
        }
        _ => return Ok(None),
    };
    let point = keys.get(&GT_RASTER_TYPE) == Some(&2);
    let c = if point { 0.0 } else { 0.5 };
    let origin = [tx + (c - ti) * sx, ty - (c - tj) * sy];
    let step = [sx, -sy];
    // A texture is placed by it alone (a DEM's is checked again in `dem::load`).
    if let Some(why) = crate::heightfield::unusable_placement(origin, step) {
        return Err(corrupt(path, why));
    }
    let epsg = |key: u16| keys.get(&key).copied().filter(|&c| c != 0 && c != 32767).map(u32::from);
    let model = keys.get(&GT_MODEL_TYPE).copied().unwrap_or_else(|| {
        if keys.contains_key(&PROJECTED_CS_TYPE) {
            1
        } else if keys.contains_key(&GEOGRAPHIC_TYPE) {
            2
        } else {
            0
        }
    });
    let crs = match model {
        2 => Crs::Geographic { epsg: epsg(GEOGRAPHIC_TYPE) },
        1 => Crs::Projected { epsg: epsg(PROJECTED_CS_TYPE) },
        // Geocentric or user-defined model: the origin and step are still recorded.
        _ => Crs::Unknown,
    };
    let unit_m = match keys.get(&PROJ_LINEAR_UNITS) {
        Some(9001) => 1.0,
        Some(9002) => 0.3048,
        Some(9003) => 1200.0 / 3937.0,
        Some(9036) => 1000.0,
        // No key (or one not listed here): the unit the EPSG code defines.
        _ => match crs {
            Crs::Projected { epsg: Some(code) } => {
                SourceCrs::from_epsg(code).map_or(1.0, |source| source.metres_per_unit())
            }
            _ => 1.0,
        },
    };
    Ok(Some(RawGeoref { origin, step, crs, unit_m }))
}

/// Fill `hf.georef` and `hf.spacing_m` from a GeoTIFF georeference.
pub(crate) fn place_grid(hf: &mut Heightfield, raw: RawGeoref) {
    let RawGeoref { mut origin, mut step, crs, unit_m } = raw;
    // A grid stored south-up or east-to-west is turned north-up, west-east.
    if step[1] > 0.0 {
        flip_rows(hf);
        origin[1] += step[1] * (hf.height - 1) as f64;
        step[1] = -step[1];
    }
    if step[0] < 0.0 {
        flip_columns(hf);
        origin[0] += step[0] * (hf.width - 1) as f64;
        step[0] = -step[0];
    }
    hf.georef.origin = origin;
    hf.georef.step = step;
    match crs {
        Crs::Geographic { .. } => {
            hf.georef.crs = crs;
            hf.apply_local_tangent();
        }
        Crs::Projected { .. } => {
            let mut spacing = [step[0].abs() * unit_m, step[1].abs() * unit_m];
            if let Ok(source) = SourceCrs::of(&crs, None) {
                let mid = [
                    origin[0] + step[0] * (hf.width - 1) as f64 / 2.0,
                    origin[1] + step[1] * (hf.height - 1) as f64 / 2.0,
                ];
                // A centre off the Earth keeps the grid's own metres; it
                // gets no placement either.
                let k = source.ground_per_grid_m(mid).unwrap_or(1.0);
                spacing = [spacing[0] * k, spacing[1] * k];
            }
            hf.georef.crs = crs;
            hf.spacing_m = spacing;
        }
        Crs::Unknown => {
            // Geocentric or user-defined model: the grid keeps 1 m spacing
            // unless overridden; the origin and step are still recorded.
        }
    }
}

/// An 8-bit colour image read from a TIFF (for textures, not DEMs).
pub(crate) struct Rgb8Tiff {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major RGB, 3 bytes per pixel (gray is repeated, alpha dropped).
    pub rgb: Vec<u8>,
    /// The GeoTIFF georeference, if the file has one.
    pub georef: Option<RawGeoref>,
}

/// The most pixels a colour TIFF may hold (2^30: 3 GiB of RGB).
const MAX_COLOUR_PIXELS: usize = 1 << 30;

/// Reads an 8-bit gray, RGB or RGBA TIFF (chunky, in strips or tiles, any
/// compression the DEM reader takes) with its georeference.
pub(crate) fn load_rgb8(path: &Path) -> Result<Rgb8Tiff, DemError> {
    let Opened { mut dec, file_len, width, height, fences } = open(path)?;
    let err = |e: TiffError| tiff_error(path, e);
    if width.checked_mul(height).is_none_or(|n| n > MAX_COLOUR_PIXELS) {
        return Err(unsupported(path, format!("{width} × {height} pixels is larger than terrachunk reads")));
    }
    let samples: u16 = dec.find_tag_unsigned(Tag::SamplesPerPixel).map_err(err)?.unwrap_or(1);
    let photometric: u16 = dec.find_tag_unsigned(Tag::PhotometricInterpretation).map_err(err)?.unwrap_or(1);
    let planar: u16 = dec.find_tag_unsigned(Tag::PlanarConfiguration).map_err(err)?.unwrap_or(1);
    let bits: Vec<u16> = dec.find_tag_unsigned_vec::<u16>(Tag::BitsPerSample).map_err(err)?.unwrap_or(vec![1]);
    let compression: u16 = dec.find_tag_unsigned(Tag::Compression).map_err(err)?.unwrap_or(1);
    let what = match (photometric, samples) {
        (0 | 1, 1) => "gray",
        (2, 3) => "RGB",
        (2, 4) => "RGBA",
        (3, _) => return Err(unsupported(path, "palette (colour-mapped) TIFF; a texture needs gray, RGB or RGBA")),
        (6, _) => return Err(unsupported(path, "YCbCr TIFF; a texture needs gray, RGB or RGBA")),
        (p, s) => {
            return Err(unsupported(
                path,
                format!("TIFF with {s} samples per pixel (photometric {p}); a texture needs gray, RGB or RGBA"),
            ));
        }
    };
    if bits.iter().any(|&b| b != 8) {
        return Err(unsupported(path, format!("{what} TIFF with {bits:?} bits per sample; textures need 8 bits")));
    }
    if planar != 1 {
        return Err(unsupported(path, "planar (band-separate) TIFF; textures need interleaved samples"));
    }
    if !matches!(compression, 1 | 5 | 8 | 32946 | 32773) {
        return Err(unsupported(
            path,
            format!("compression {compression}; terrachunk reads uncompressed, LZW, DEFLATE and PackBits TIFFs"),
        ));
    }
    check_chunks_present(path, &mut dec, file_len, (width, height), 3)?;
    let s = samples as usize;
    let mut rgb = vec![0u8; width * height * 3];
    let whole = [0, 0, width, height];
    let (dec, _) = read_chunks(
        path,
        (dec, &fences),
        file_len,
        (width, height),
        s,
        ("pixels", whole),
        |chunk, [x0, y0, dw, dh]| {
            let DecodingResult::U8(data) = chunk else {
                return Err(corrupt(path, "8-bit samples decoded to another type"));
            };
            if data.len() < dh * dw * s {
                return Err(corrupt(
                    path,
                    format!("a chunk at pixel ({x0}, {y0}) decoded to fewer pixels than its size"),
                ));
            }
            for r in 0..dh {
                for c in 0..dw {
                    let src = &data[(r * dw + c) * s..];
                    let dst = &mut rgb[((y0 + r) * width + x0 + c) * 3..][..3];
                    if s == 1 {
                        dst.fill(src[0]);
                    } else {
                        dst.copy_from_slice(&src[..3]);
                    }
                }
            }
            Ok(())
        },
    )?;
    let mut dec = dec.with_limits(tag_limits(file_len));
    let georef = raw_georef(path, &mut dec)?;
    Ok(Rgb8Tiff { width, height, rgb, georef })
}

/// GeoKeyDirectory → the keys whose value is stored inline (all we need).
fn geokeys(dir: &[u16]) -> std::collections::BTreeMap<u16, u16> {
    let mut keys = std::collections::BTreeMap::new();
    let count = dir.get(3).copied().unwrap_or(0) as usize;
    for k in 0..count {
        let Some(entry) = dir.get(4 + 4 * k..8 + 4 * k) else {
            break;
        };
        if entry[1] == 0 {
            keys.insert(entry[0], entry[3]);
        }
    }
    keys
}

fn flip_rows(hf: &mut Heightfield) {
    let w = hf.width;
    let h = hf.height;
    for i in 0..h / 2 {
        let (top, bottom) = hf.heights.split_at_mut((h - 1 - i) * w);
        top[i * w..(i + 1) * w].swap_with_slice(&mut bottom[..w]);
    }
}

fn flip_columns(hf: &mut Heightfield) {
    for row in hf.heights.chunks_mut(hf.width) {
        row.reverse();
    }
}

/// The `tiff` crate's errors as ours: bad structure is corruption, a missing
/// feature is unsupported.
fn tiff_error(path: &Path, e: TiffError) -> DemError {
    match e {
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            corrupt(path, format!("the TIFF ends early (truncated?): {io}"))
        }
        TiffError::IoError(io) => io_error(path, io),
        TiffError::UnsupportedError(u) => unsupported(path, format!("TIFF: {u}")),
        TiffError::LimitsExceeded => unsupported(path, "TIFF exceeds the decoder's limits"),
        other => corrupt(path, format!("not a valid TIFF: {other}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
    }

    /// A window reads the samples the whole file has there, from the strips
    /// or tiles under it alone.
    #[test]
    fn a_window_is_the_whole_files_samples_there_from_its_chunks_alone() {
        for name in ["dfw_texas_srtm3.tif", "california_crop_deflate.tif", "mount_st_helens_30m.tif"] {
            let path = fixture(name);
            let all = read_samples(&path, None, None).unwrap();
            let (w, h) = all.size;
            for window in [[0, 0, w, h], [1, 2, 3, 4], [w / 3, h / 2, w / 2, h / 3], [w - 1, h - 1, 1, 1]] {
                let part = load_window(&path, window, None).unwrap();
                let [x0, y0, ww, wh] = window;
                for r in 0..wh {
                    for c in 0..ww {
                        let (a, b) = (all.heights[(y0 + r) * w + x0 + c], part.heights[r * ww + c]);
                        assert!(a.to_bits() == b.to_bits() || a.is_nan() && b.is_nan(), "{name} {window:?} ({r}, {c})");
                    }
                }
                assert!(part.decoded <= all.decoded, "{name}");
            }
            let small = load_window(&path, [w / 2, h / 2, 2, 2], None).unwrap();
            assert!(small.decoded < all.decoded || all.decoded == 1, "{name}: {} of {}", small.decoded, all.decoded);
            assert!(load_window(&path, [w - 1, 0, 2, 1], None).is_err(), "{name}: a window past the image");
        }
    }
}
