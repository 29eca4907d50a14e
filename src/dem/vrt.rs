//! GDAL virtual rasters (`.vrt`): a mosaic of GeoTIFF tiles as
//! `gdalbuildvrt` writes it, read as one grid.
//!
//! What is read: a `VRTDataset` without rotation, north-up, with one
//! `VRTRasterBand` (its `NoDataValue`, `Offset` and `Scale`) whose sources
//! are `SimpleSource` or `ComplexSource` elements naming a GeoTIFF
//! (`relativeToVRT` honoured), band 1, copied pixel for pixel: `SrcRect` and
//! `DstRect` of one size (no resampling), clipped to the raster. A
//! `ComplexSource` may carry `NODATA`, `ScaleOffset` and `ScaleRatio`.
//! Only the strips or tiles of a source under its `SrcRect` are decoded.
//! Later sources are drawn over earlier ones, as GDAL draws them, except
//! that a source's nodata never covers another's data. Ground no source
//! covers is nodata where the band has a `NoDataValue`, else 0, as in GDAL.
//!
//! Each source must agree with the VRT on where it lies: its own
//! georeference (GeoKeys) has the VRT's CRS and step, and its first sample
//! falls where `SrcRect`/`DstRect` put it, within a thousandth of a step; a
//! mosaic that does not line up is refused rather than shifted. The grid
//! is then placed as one GeoTIFF of the whole mosaic would be, so the same
//! ground gives the same tileset either way.

use std::path::{Path, PathBuf};

use super::geotiff::{self, RawGeoref};
use super::{DemError, corrupt, invalid, io_error, sample_count, unsupported};
use crate::heightfield::Heightfield;
use crate::store::{Big, Memory};

/// The largest VRT file read (its XML), bytes: a mosaic of a hundred
/// thousand tiles stays far below it.
const MAX_VRT_BYTES: u64 = 64 << 20;

/// Reads the mosaic a `.vrt` describes.
pub(super) fn load(path: &Path, memory: Option<&Memory>) -> Result<Heightfield, DemError> {
    assemble(path, &read(path)?, memory)
}

/// The files the mosaic reads, in its order.
pub(super) fn sources(path: &Path) -> Result<Vec<PathBuf>, DemError> {
    Ok(read(path)?.sources.into_iter().map(|s| s.file).collect())
}

fn read(path: &Path) -> Result<Vrt, DemError> {
    let len = std::fs::metadata(path).map_err(|e| io_error(path, e))?.len();
    if len > MAX_VRT_BYTES {
        return Err(unsupported(path, format!("{len} bytes of VRT XML; terrachunk reads up to {MAX_VRT_BYTES}")));
    }
    let text = std::fs::read_to_string(path).map_err(|e| io_error(path, e))?;
    parse(path, &text)
}

/// One source: the file and where its pixels go.
#[derive(Debug)]
struct Source {
    file: PathBuf,
    /// `SrcRect`: first column and row, columns and rows.
    src: [usize; 4],
    /// `DstRect`: first column and row in the mosaic (may be negative).
    dst: [i64; 2],
    /// `ComplexSource` `NODATA`: source values that are not drawn.
    nodata: Option<f64>,
    /// `ScaleRatio`, `ScaleOffset`: value = raw · ratio + offset.
    scale: (f64, f64),
}

/// What the VRT says.
#[derive(Debug)]
struct Vrt {
    width: usize,
    height: usize,
    /// The GDAL geotransform: corner x, dx, 0, corner y, 0, dy.
    transform: [f64; 6],
    nodata: Option<f64>,
    /// The band's `Offset` and `Scale`: metres = value · scale + offset.
    unit: (f64, f64),
    sources: Vec<Source>,
}

/// The first child element of `node` named `name`.
fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|c| c.has_tag_name(name))
}

fn parse(path: &Path, text: &str) -> Result<Vrt, DemError> {
    let doc = roxmltree::Document::parse(text).map_err(|e| corrupt(path, format!("not valid VRT XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "VRTDataset" {
        return Err(corrupt(path, format!("the root element is <{}>, not <VRTDataset>", root.tag_name().name())));
    }
    if let Some(sub) = root.attribute("subClass") {
        return Err(unsupported(path, format!("a {sub} (terrachunk reads mosaics: plain VRTDataset)")));
    }
    let size = |name: &str| -> Result<usize, DemError> {
        let v = root.attribute(name).ok_or_else(|| corrupt(path, format!("<VRTDataset> has no {name}")))?;
        v.trim().parse().map_err(|_| corrupt(path, format!("<VRTDataset> {name}=\"{v}\" is not a size")))
    };
    let (width, height) = (size("rasterXSize")?, size("rasterYSize")?);
    let number = |node: roxmltree::Node<'_, '_>, what: &str| -> Result<f64, DemError> {
        let t = node.text().unwrap_or("").trim();
        match t.parse::<f64>() {
            Ok(v) if v.is_finite() || what == "NoDataValue" || what == "NODATA" => Ok(v),
            _ => Err(corrupt(path, format!("<{what}> \"{t}\" is not a finite number"))),
        }
    };
    let gt = child(root, "GeoTransform")
        .ok_or_else(|| unsupported(path, "the VRT has no <GeoTransform>; a mosaic needs one to place its tiles"))?;
    let parts: Vec<&str> = gt.text().unwrap_or("").split(',').map(str::trim).collect();
    let transform: [f64; 6] = parts
        .iter()
        .map(|p| p.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<Vec<f64>>>()
        .and_then(|v| v.try_into().ok())
        .ok_or_else(|| corrupt(path, format!("<GeoTransform> \"{}\" is not six finite numbers", parts.join(", "))))?;
    if transform[2] != 0.0 || transform[4] != 0.0 {
        return Err(unsupported(path, "a rotated or sheared <GeoTransform>; terrachunk reads north-up grids"));
    }
    if !(transform[1] > 0.0 && transform[5] < 0.0) {
        return Err(unsupported(
            path,
            format!(
                "<GeoTransform> steps {} × {}: terrachunk reads north-up, west-to-east mosaics (x step > 0, y step < 0)",
                transform[1], transform[5]
            ),
        ));
    }
    let bands: Vec<_> = root.children().filter(|c| c.has_tag_name("VRTRasterBand")).collect();
    let [band] = bands.as_slice() else {
        return Err(unsupported(path, format!("{} bands; a DEM mosaic has one", bands.len())));
    };
    if let Some(sub) = band.attribute("subClass") {
        return Err(unsupported(path, format!("a {sub} band (terrachunk reads plain mosaics)")));
    }
    let nodata = child(*band, "NoDataValue").map(|n| number(n, "NoDataValue")).transpose()?;
    let offset = child(*band, "Offset").map(|n| number(n, "Offset")).transpose()?.unwrap_or(0.0);
    let scale = child(*band, "Scale").map(|n| number(n, "Scale")).transpose()?.unwrap_or(1.0);
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut sources = Vec::new();
    for s in band.children().filter(|c| c.is_element()) {
        let kind = s.tag_name().name();
        match kind {
            "SimpleSource" | "ComplexSource" => {}
            "AveragedSource" | "KernelFilteredSource" => {
                return Err(unsupported(path, format!("<{kind}> (terrachunk copies sources pixel for pixel)")));
            }
            _ => continue,
        }
        let name_node =
            child(s, "SourceFilename").ok_or_else(|| corrupt(path, format!("<{kind}> has no <SourceFilename>")))?;
        let name = name_node.text().unwrap_or("").trim();
        if name.is_empty() {
            return Err(corrupt(path, format!("<{kind}> has an empty <SourceFilename>")));
        }
        let file = if name_node.attribute("relativeToVRT") == Some("1") { dir.join(name) } else { PathBuf::from(name) };
        if let Some(b) = child(s, "SourceBand") {
            let b = b.text().unwrap_or("").trim();
            if b != "1" {
                return Err(unsupported(path, format!("{name}: source band {b}; terrachunk reads band 1")));
            }
        }
        for other in ["LUT", "ColorTableComponent", "Exponent", "DstMax", "DstMin", "UseMaskBand"] {
            if child(s, other).is_some() {
                return Err(unsupported(path, format!("{name}: <{other}> in a source")));
            }
        }
        let rect = |tag: &str| -> Result<Option<[f64; 4]>, DemError> {
            let Some(r) = child(s, tag) else { return Ok(None) };
            let mut v = [0.0; 4];
            for (k, a) in ["xOff", "yOff", "xSize", "ySize"].iter().enumerate() {
                let t = r.attribute(*a).ok_or_else(|| corrupt(path, format!("{name}: <{tag}> has no {a}")))?;
                v[k] = t
                    .trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| corrupt(path, format!("{name}: <{tag}> {a}=\"{t}\" is not a number")))?;
            }
            Ok(Some(v))
        };
        let (src, dst) = (rect("SrcRect")?, rect("DstRect")?);
        let whole = |v: f64| v.fract() == 0.0 && v.abs() < 1e15;
        let (src, dst) = match (src, dst) {
            (Some(s), Some(d)) => {
                if !s.iter().chain(&d).copied().all(whole) || s[0] < 0.0 || s[1] < 0.0 || s[2] < 1.0 || s[3] < 1.0 {
                    return Err(unsupported(
                        path,
                        format!("{name}: <SrcRect>/<DstRect> of fractional or empty pixels"),
                    ));
                }
                if s[2] != d[2] || s[3] != d[3] {
                    return Err(unsupported(
                        path,
                        format!(
                            "{name}: <SrcRect> {} × {} drawn into <DstRect> {} × {}; terrachunk copies sources \
                             pixel for pixel (resample with gdalwarp first)",
                            s[2], s[3], d[2], d[3]
                        ),
                    ));
                }
                ([s[0] as usize, s[1] as usize, s[2] as usize, s[3] as usize], [d[0] as i64, d[1] as i64])
            }
            _ => return Err(unsupported(path, format!("{name}: a source without both <SrcRect> and <DstRect>"))),
        };
        let nodata = child(s, "NODATA").map(|n| number(n, "NODATA")).transpose()?;
        let ratio = child(s, "ScaleRatio").map(|n| number(n, "ScaleRatio")).transpose()?.unwrap_or(1.0);
        let off = child(s, "ScaleOffset").map(|n| number(n, "ScaleOffset")).transpose()?.unwrap_or(0.0);
        sources.push(Source { file, src, dst, nodata, scale: (ratio, off) });
    }
    if sources.is_empty() {
        return Err(invalid(path, "the VRT names no source"));
    }
    Ok(Vrt { width, height, transform, nodata, unit: (offset, scale), sources })
}

/// Reads every source in turn and draws it into the mosaic.
fn assemble(path: &Path, vrt: &Vrt, memory: Option<&Memory>) -> Result<Heightfield, DemError> {
    let n = sample_count(path, vrt.width, vrt.height)?;
    if vrt.width < 2 || vrt.height < 2 {
        return Err(invalid(path, format!("grid is {} × {} samples; need at least 2 × 2", vrt.width, vrt.height)));
    }
    // The grid the sources promise against what their files hold, before
    // anything is allocated.
    let mut held = std::fs::metadata(path).map_err(|e| io_error(path, e))?.len();
    for s in &vrt.sources {
        let meta = std::fs::metadata(&s.file).map_err(|e| source_error(path, &s.file, e))?;
        if !meta.is_file() {
            return Err(unsupported(path, format!("source {}: not a regular file", s.file.display())));
        }
        if super::sniff_file(&s.file).map_err(|e| within(path, &s.file, e))? != Some(super::Format::Tiff) {
            return Err(unsupported(
                path,
                format!("source {} is not a GeoTIFF; terrachunk reads VRT mosaics of GeoTIFFs", s.file.display()),
            ));
        }
        held = held.saturating_add(meta.len());
    }
    super::check_expansion((vrt.width, vrt.height), 4, held).map_err(|e| unsupported(path, e))?;

    let [cx, dx, _, cy, _, dy] = vrt.transform;
    // Sample centres, as a GeoTIFF's georeference gives them.
    let origin = [cx + dx / 2.0, cy + dy / 2.0];
    let fill = if vrt.nodata.is_some() { f32::NAN } else { vrt.unit.0 as f32 };
    let mut heights = Big::filled(n, fill, memory).map_err(|e| super::io_error(path, e))?;
    let mut placed: Option<RawGeoref> = None;
    for s in &vrt.sources {
        let [sx, sy, w, h] = s.src;
        // Only the strips or tiles under SrcRect are decoded.
        let tile = geotiff::load_window(&s.file, s.src, memory).map_err(|e| within(path, &s.file, e))?;
        let raw = tile.georef;
        let name = s.file.display();
        let Some(raw) = raw else {
            return Err(invalid(path, format!("source {name} has no georeference; a mosaic tile needs one")));
        };
        if !(raw.step[0] > 0.0 && raw.step[1] < 0.0) {
            return Err(unsupported(path, format!("source {name} is not stored north-up, west to east")));
        }
        let close = |a: f64, b: f64, unit: f64| (a - b).abs() <= 1e-3 * unit.abs();
        if !close(raw.step[0], dx, dx) || !close(raw.step[1], dy, dy) {
            return Err(invalid(
                path,
                format!("source {name} has steps {} × {}, the VRT {dx} × {dy}", raw.step[0], raw.step[1]),
            ));
        }
        match &placed {
            None => placed = Some(raw.clone()),
            Some(p) if p.crs != raw.crs || p.unit_m != raw.unit_m => {
                return Err(invalid(
                    path,
                    format!(
                        "source {name} is in {:?} (unit {} m), the first source in {:?}",
                        raw.crs, raw.unit_m, p.crs
                    ),
                ));
            }
            Some(_) => {}
        }
        // Where the VRT puts this file's first sample, and where it says it is.
        let at = [s.dst[0] - s.src[0] as i64, s.dst[1] - s.src[1] as i64];
        let expected = [origin[0] + at[0] as f64 * dx, origin[1] + at[1] as f64 * dy];
        if !close(raw.origin[0], expected[0], dx) || !close(raw.origin[1], expected[1], dy) {
            return Err(invalid(
                path,
                format!(
                    "source {name} starts at ({}, {}) but the VRT draws it at ({}, {}): the mosaic does not line up",
                    raw.origin[0], raw.origin[1], expected[0], expected[1]
                ),
            ));
        }
        let (ratio, off) = s.scale;
        for r in 0..h {
            let row = s.dst[1] + r as i64;
            if row < 0 || row >= vrt.height as i64 {
                continue;
            }
            for c in 0..w {
                let col = s.dst[0] + c as i64;
                if col < 0 || col >= vrt.width as i64 {
                    continue;
                }
                let v = tile.heights[r * w + c];
                if v.is_nan() || s.nodata.is_some_and(|nd| f64::from(v) == nd) {
                    continue;
                }
                let v = f64::from(v) * ratio + off;
                let k = row as usize * vrt.width + col as usize;
                heights[k] = if vrt.nodata.is_some_and(|nd| v == nd) {
                    f32::NAN
                } else {
                    super::to_height(v * vrt.unit.1 + vrt.unit.0)
                        .map_err(|e| invalid(path, format!("source {name}, row {}, column {}: {e}", sy + r, sx + c)))?
                };
            }
        }
    }
    let raw = placed.expect("at least one source was read");
    let mut hf = Heightfield::ungeoreferenced(vrt.width, vrt.height, heights, super::file_name(path));
    geotiff::place_grid(&mut hf, RawGeoref { origin, step: [dx, dy], ..raw });
    Ok(hf)
}

fn source_error(vrt: &Path, file: &Path, e: std::io::Error) -> DemError {
    invalid(vrt, format!("source {}: {e}", file.display()))
}

/// A source's own error, told as the VRT's (the user gave the VRT),
/// naming the source.
fn within(vrt: &Path, file: &Path, e: DemError) -> DemError {
    let name = file.display();
    match e {
        DemError::Io { source, .. } => invalid(vrt, format!("source {name}: cannot read: {source}")),
        DemError::Unsupported { what, .. } => unsupported(vrt, format!("source {name}: {what}")),
        DemError::Corrupt { what, .. } => corrupt(vrt, format!("source {name}: {what}")),
        DemError::Invalid { what, .. } => invalid(vrt, format!("source {name}: {what}")),
    }
}
