//! Load: every supported DEM format into one [`Heightfield`].
//!
//! Each format lives in its own file and returns a `Heightfield` with NaN for
//! nodata, spacing in metres (geographic grids go through
//! [`Heightfield::apply_local_tangent`]) and the georeference it found.
//! This module picks the reader (by magic bytes first, then by extension),
//! applies the user's overrides, and checks what every later stage relies on:
//! at least 2 × 2 samples, a finite positive spacing, no infinite height and
//! at least one sample with data. Errors name the file and what is wrong with
//! it; nothing here panics on user input.
//!
//! Formats read:
//!
//! | format | extension | samples | georeference |
//! |---|---|---|---|
//! | GeoTIFF | `.tif`, `.tiff` | one band of int 8/16/32/64, uint 8/16/32/64, float 16/32/64; strips or tiles; uncompressed, LZW, DEFLATE, PackBits, with or without predictor | GeoKeys, `GDAL_NODATA` |
//! | PNG | `.png` | 8- or 16-bit grayscale (value = metres), 8-bit RGB(A) Mapbox Terrain-RGB | none |
//! | SRTM | `.hgt` | big-endian int16, square; several tiles (or a folder) form a mosaic | from the file name |
//! | ESRI ASCII grid | `.asc` | text | header, and the CRS a `.prj` beside it names (an EPSG code in its WKT, or PROJ.4 text; else projected metres of no named CRS) |
//! | VTP BT 1.1–1.3 | `.bt` | int16, int32, float32 | header |
//! | OpenEXR | `.exr` | one float16/float32 channel | none |
//! | GDAL VRT | `.vrt` | a mosaic of GeoTIFFs as `gdalbuildvrt` writes it (`vrt.rs`) | the VRT's, checked against each tile's |
//!
//! A file without a georeference gets a spacing of 1 m on both axes unless
//! [`LoadOptions::spacing_m`] says otherwise.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::heightfield::Heightfield;

mod asc;
mod bt;
mod exr;
pub(crate) mod geotiff;
mod hgt;
mod prj;
mod vrt;

use crate::store::{Big, Memory};
pub(crate) use hgt::is_hgt;
mod png;

/// Options that override what a file says.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Multiply every height by this (e.g. 0.3048 for feet). Default 1.
    /// Must be finite and non-zero.
    pub vertical_scale: Option<f64>,
    /// Force the ground spacing in metres, `[s_x, s_z]`; both finite and > 0.
    /// Files without a georeference (PNG, EXR, a GeoTIFF without GeoKeys)
    /// otherwise get 1 m.
    pub spacing_m: Option<[f64; 2]>,
    /// A geoid model (`.gtx` or geographic GeoTIFF) whose undulation is
    /// added to every height, making them ellipsoidal (`crate::geoid`).
    pub geoid: Option<PathBuf>,
    /// A memory limit: GeoTIFF and VRT grids past its share are decoded
    /// straight into a mapped scratch file ([`crate::store`]), any other
    /// format is read whole and then moved into one.
    pub memory: Option<Memory>,
}

/// What can go wrong while loading a DEM. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DemError {
    /// The file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file's format is not one terrachunk reads.
    #[error("{path}: unsupported format: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What was found.
        what: String,
    },
    /// The file is truncated or its contents contradict its header.
    #[error("{path}: corrupt: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The data are readable but unusable (NaN heights, all nodata, 1 × N...).
    #[error("{path}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

impl DemError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            DemError::Io { path, .. }
            | DemError::Unsupported { path, .. }
            | DemError::Corrupt { path, .. }
            | DemError::Invalid { path, .. } => path,
        }
    }
}

/// The most samples one grid may hold (2^31, 8 GiB of `f32`): anything larger
/// is a corrupt header or a file this tool cannot hold in memory anyway.
pub(crate) const MAX_SAMPLES: usize = 1 << 31;

/// The most bytes a reader decodes per byte of compressed file: the
/// memory a grid (4 bytes per sample, as `f32` heights) or a texture (3
/// bytes per pixel) takes, against the file's length. Real DEMs and images
/// stay far below it (the DEFLATE mosaic of California, 8401 × 4801
/// samples: under 6 to 1; a mostly-sea SRTM tile: under 20), while a
/// header promising gigapixels from a few megabytes of near-constant data
/// passes it by orders of magnitude and is refused before anything is
/// allocated. Grids and images up to [`SMALL_DECODE_BYTES`] are always
/// read, so small synthetic files of one value still load.
pub(crate) const MAX_EXPANSION: u64 = 1024;

/// Decoded sizes that [`MAX_EXPANSION`] never refuses, bytes (64 MiB).
pub(crate) const SMALL_DECODE_BYTES: u64 = 64 << 20;

/// Refuses a file of `file_len` bytes whose header promises `width ×
/// height` pixels of `bytes_per_pixel` bytes once decoded, beyond
/// [`MAX_EXPANSION`]; the message says why.
pub(crate) fn check_expansion(
    (width, height): (usize, usize),
    bytes_per_pixel: u64,
    file_len: u64,
) -> Result<(), String> {
    let decoded = (width as u64).saturating_mul(height as u64).saturating_mul(bytes_per_pixel);
    if decoded > SMALL_DECODE_BYTES && decoded > file_len.saturating_mul(MAX_EXPANSION) {
        return Err(format!(
            "the header promises {width} × {height} pixels ({decoded} bytes in memory) from a file of \
             {file_len} bytes, more than {MAX_EXPANSION} to 1; refused before decoding"
        ));
    }
    Ok(())
}

pub(crate) fn io_error(path: &Path, source: std::io::Error) -> DemError {
    DemError::Io { path: path.to_path_buf(), source }
}

pub(crate) fn unsupported(path: &Path, what: impl Into<String>) -> DemError {
    DemError::Unsupported { path: path.to_path_buf(), what: what.into() }
}

pub(crate) fn corrupt(path: &Path, what: impl Into<String>) -> DemError {
    DemError::Corrupt { path: path.to_path_buf(), what: what.into() }
}

pub(crate) fn invalid(path: &Path, what: impl Into<String>) -> DemError {
    DemError::Invalid { path: path.to_path_buf(), what: what.into() }
}

/// The most a stored height may differ from the file's value, metres.
///
/// Heights are held as `f32`. Within ±32 768 m its rounding stays below
/// 1 mm, so no terrain on Earth (or Mars) comes near this; a file whose
/// values are far from 0 *and* finer than `f32` can hold there (1e6 m with
/// centimetre relief, where `f32` steps are 6.25 cm) would otherwise be
/// flattened without a word, so it is refused instead.
pub(crate) const MAX_ROUNDING_M: f64 = 1e-3;

/// A finite source value that no `f32` height holds within
/// [`MAX_ROUNDING_M`].
#[derive(Debug)]
pub(crate) struct Lossy {
    value: f64,
    stored: f32,
}

impl std::fmt::Display for Lossy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Plain digits where they are readable, scientific beyond.
        let show = |v: f64| if v.abs() < 1e15 { v.to_string() } else { format!("{v:e}") };
        if self.stored.is_infinite() {
            return write!(f, "{} is beyond the range of a 32-bit float height (±3.4e38)", show(self.value));
        }
        let next = f32::from_bits(self.stored.to_bits() + 1);
        let step = (f64::from(next) - f64::from(self.stored)).abs();
        write!(
            f,
            "{} would be stored as {}: heights are held as 32-bit floats, which near {:.0e} m have steps \
             of {step} m; subtract a constant from the heights so they lie nearer 0 (within ±32 768 m \
             they are held to 1 mm)",
            show(self.value),
            show(f64::from(self.stored)),
            self.value
        )
    }
}

/// `v` as the `f32` height the grid stores, unless that moves it by more
/// than [`MAX_ROUNDING_M`] or overflows. NaN and infinities pass through
/// (nodata, and [`validate`]'s refusal of infinite heights).
#[inline]
pub(crate) fn to_height(v: f64) -> Result<f32, Lossy> {
    let stored = v as f32;
    check_stored(v, stored).map(|()| stored)
}

/// Whether `stored` holds the source value `v` within [`MAX_ROUNDING_M`]
/// (NaN and infinite `v` always pass).
#[inline]
pub(crate) fn check_stored(v: f64, stored: f32) -> Result<(), Lossy> {
    // Below 2^15 in magnitude half an f32 step is under 1 mm: nothing to check.
    if stored.abs() < 32_768.0 || !v.is_finite() {
        return Ok(());
    }
    if stored.is_infinite() || (f64::from(stored) - v).abs() > MAX_ROUNDING_M {
        return Err(Lossy { value: v, stored });
    }
    Ok(())
}

/// `width × height`, refused when it overflows or exceeds [`MAX_SAMPLES`].
pub(crate) fn sample_count(path: &Path, width: usize, height: usize) -> Result<usize, DemError> {
    match width.checked_mul(height) {
        Some(n) if n <= MAX_SAMPLES => Ok(n),
        _ => Err(unsupported(
            path,
            format!(
                "grid of {width} × {height} samples is larger than the {MAX_SAMPLES} samples \
                 terrachunk can hold"
            ),
        )),
    }
}

/// The file name alone, for `Heightfield::source`.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| path.display().to_string())
}

/// Load one DEM, or several `.hgt` tiles (or a folder of them) as a mosaic.
///
/// The result has at least 2 × 2 samples, a finite spacing > 0, no infinite
/// height and at least one sample that is not nodata (NaN); heights are
/// multiplied by `opts.vertical_scale` and the spacing replaced by
/// `opts.spacing_m` when given.
pub fn load(paths: &[PathBuf], opts: &LoadOptions) -> Result<Heightfield, DemError> {
    let Some(first) = paths.first() else {
        return Err(invalid(Path::new(""), "no input file given"));
    };
    check_options(first, opts)?;
    let (hf, name_for_errors) = if paths.len() > 1 {
        let hf = hgt::load_mosaic(paths)?;
        let name = PathBuf::from(&hf.source);
        (hf, name)
    } else if first.is_dir() {
        (hgt::load_folder(first)?, first.clone())
    } else {
        (load_one(first, opts)?, first.clone())
    };
    let mut hf = finish(&name_for_errors, hf, opts)?;
    if let Some(model) = &opts.geoid {
        crate::geoid::Geoid::read(model)?.apply(&mut hf, &name_for_errors, model)?;
    }
    Ok(hf)
}

/// The files a `.vrt` mosaic reads, in its order (none for any other
/// input): what a sharded build's manifest hashes besides the VRT.
pub fn vrt_sources(path: &Path) -> Result<Vec<PathBuf>, DemError> {
    if !path.is_file() || !(by_extension(path) == Some(Format::Vrt) || sniff_file(path)? == Some(Format::Vrt)) {
        return Ok(Vec::new());
    }
    vrt::sources(path)
}

fn sniff_file(path: &Path) -> Result<Option<Format>, DemError> {
    let mut head = Vec::with_capacity(64);
    std::fs::File::open(path).and_then(|f| f.take(64).read_to_end(&mut head)).map_err(|e| io_error(path, e))?;
    Ok(sniff(&head))
}

/// Reject overrides no grid could use, before reading anything.
fn check_options(path: &Path, opts: &LoadOptions) -> Result<(), DemError> {
    if let Some(s) = opts.vertical_scale
        && !(s.is_finite() && s != 0.0)
    {
        return Err(invalid(path, format!("vertical scale override {s} must be finite and non-zero")));
    }
    if let Some([sx, sz]) = opts.spacing_m
        && !(sx.is_finite() && sz.is_finite() && sx > 0.0 && sz > 0.0)
    {
        return Err(invalid(path, format!("spacing override {sx} × {sz} m: both must be finite and greater than 0")));
    }
    Ok(())
}

/// The formats terrachunk reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Tiff,
    Png,
    Hgt,
    Asc,
    Bt,
    Exr,
    Vrt,
}

/// Recognise a format from the first bytes of the file.
fn sniff(head: &[u8]) -> Option<Format> {
    if head.starts_with(b"II*\0")
        || head.starts_with(b"MM\0*")
        || head.starts_with(b"II+\0")
        || head.starts_with(b"MM\0+")
    {
        return Some(Format::Tiff);
    }
    if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Some(Format::Png);
    }
    if head.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        return Some(Format::Exr);
    }
    if head.starts_with(b"binterr") {
        return Some(Format::Bt);
    }
    let text = head.trim_ascii_start();
    if text.starts_with(b"<VRTDataset") {
        return Some(Format::Vrt);
    }
    if text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"ncols")
        || text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"nrows")
    {
        return Some(Format::Asc);
    }
    None
}

fn by_extension(path: &Path) -> Option<Format> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    Some(match ext.as_str() {
        "tif" | "tiff" | "gtif" | "gtiff" => Format::Tiff,
        "png" => Format::Png,
        "hgt" => Format::Hgt,
        "asc" => Format::Asc,
        "bt" => Format::Bt,
        "exr" => Format::Exr,
        "vrt" => Format::Vrt,
        _ => return None,
    })
}

/// Read one file, choosing the reader by its magic bytes (so a misnamed file
/// still loads) and by its extension for formats without one (`.hgt`).
fn load_one(path: &Path, opts: &LoadOptions) -> Result<Heightfield, DemError> {
    // A FIFO or a device would block or never end.
    let meta = std::fs::metadata(path).map_err(|e| io_error(path, e))?;
    if !meta.is_file() {
        return Err(unsupported(path, "not a regular file"));
    }
    let mut head = Vec::with_capacity(64);
    std::fs::File::open(path).and_then(|f| f.take(64).read_to_end(&mut head)).map_err(|e| io_error(path, e))?;
    let format = match sniff(&head).or_else(|| by_extension(path)) {
        Some(f) => f,
        None => {
            let shown: String = head.iter().take(8).map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ");
            let ext =
                path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_else(|| "no extension".into());
            return Err(unsupported(
                path,
                format!(
                    "not a recognised DEM ({ext}, first bytes {shown}); terrachunk reads \
                     GeoTIFF, PNG, SRTM .hgt, ESRI .asc, VTP .bt, OpenEXR and GDAL .vrt mosaics of GeoTIFFs"
                ),
            ));
        }
    };
    match format {
        Format::Tiff => geotiff::load_in(path, opts.memory.as_ref()),
        Format::Png => png::load(path),
        Format::Hgt => hgt::load_single(path, opts.spacing_m.is_some()),
        Format::Asc => asc::load(path),
        Format::Bt => bt::load(path),
        Format::Exr => self::exr::load(path),
        Format::Vrt => vrt::load(path, opts.memory.as_ref()),
    }
}

/// Apply the overrides, then check what every later stage relies on.
fn finish(path: &Path, mut hf: Heightfield, opts: &LoadOptions) -> Result<Heightfield, DemError> {
    if let Some(scale) = opts.vertical_scale
        && scale != 1.0
    {
        for (k, h) in hf.heights.iter_mut().enumerate() {
            *h = to_height(f64::from(*h) * scale).map_err(|e| {
                let (row, col) = (k / hf.width.max(1), k % hf.width.max(1));
                invalid(path, format!("sample (row {row}, column {col}) × vertical scale {scale}: {e}"))
            })?;
        }
    }
    if let Some(spacing) = opts.spacing_m {
        hf.spacing_m = spacing;
    }
    validate(path, &hf)?;
    if !hf.heights.is_mapped() && opts.memory.is_some() {
        let heights = std::mem::take(&mut hf.heights);
        hf.heights = Big::from_vec_in(heights.into_vec(), opts.memory.as_ref()).map_err(|e| io_error(path, e))?;
    }
    Ok(hf)
}

fn validate(path: &Path, hf: &Heightfield) -> Result<(), DemError> {
    if hf.width < 2 || hf.height < 2 {
        return Err(invalid(path, format!("grid is {} × {} samples; need at least 2 × 2", hf.width, hf.height)));
    }
    if hf.width.checked_mul(hf.height) != Some(hf.heights.len()) {
        return Err(corrupt(
            path,
            format!("{} heights decoded for a {} × {} grid", hf.heights.len(), hf.width, hf.height),
        ));
    }
    // Rows beyond a pole: most often longitude and latitude swapped. Before
    // the spacing, which the local tangent plane makes negative there.
    if matches!(hf.georef.crs, crate::heightfield::Crs::Geographic { .. }) {
        let first = hf.georef.origin[1];
        let last = first + hf.georef.step[1] * (hf.height - 1) as f64;
        if first.abs().max(last.abs()) > 90.0 + 1e-9 {
            return Err(corrupt(
                path,
                format!(
                    "georeference puts the sample rows at latitudes {first}..{last}°, beyond ±90° \
                     (are longitude and latitude swapped?)"
                ),
            ));
        }
    }
    let [sx, sz] = hf.spacing_m;
    if !(sx.is_finite() && sz.is_finite() && sx > 0.0 && sz > 0.0) {
        return Err(invalid(
            path,
            format!(
                "sample spacing {sx} × {sz} m: both must be finite and greater than 0 \
                 (override it with a spacing option)"
            ),
        ));
    }
    // Written to the tileset (extras, and its placement on the globe): a
    // NaN there became `null` in tileset.json.
    if let Some(why) = crate::heightfield::unusable_placement(hf.georef.origin, hf.georef.step) {
        return Err(corrupt(path, why));
    }
    let infinite = hf.heights.iter().filter(|h| h.is_infinite()).count();
    if infinite > 0 {
        return Err(invalid(path, format!("{infinite} samples are infinite; heights must be finite (NaN = nodata)")));
    }
    if hf.heights.iter().all(|h| h.is_nan()) {
        return Err(invalid(path, format!("all {} samples are nodata", hf.heights.len())));
    }
    Ok(())
}
