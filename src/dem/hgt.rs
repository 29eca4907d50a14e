//! SRTM `.hgt` tiles, alone or as a mosaic.
//!
//! A tile has no header: big-endian int16 heights, n × n samples with n from
//! the file length (1201 for 3″ SRTM3, 3601 for 1″ SRTM1), row 0 north.
//! The name gives the south-west corner (`N43E006` → 43…44°N, 6…7°E) and the
//! samples lie *on* the grid lines, so row r, column c is at
//! lat = φ₀ + 1 − r/(n−1), lon = λ₀ + c/(n−1), and neighbouring tiles share
//! their edge row or column. A mosaic therefore takes each shared edge once:
//! k tiles of n across give k·(n−1)+1 samples. Where two tiles disagree on a
//! shared sample (void-filled tiles often do, by a few metres), the one that
//! has data wins, and between two with data the tile further north wins a
//! shared row and the tile further west a shared column, whatever order the
//! files were given in. That is what `gdalbuildvrt` does with western-
//! hemisphere tiles listed by name, so a mosaic built here matches one built
//! there (the California GeoTIFF of shared/dem, for one). Void (−32768) is
//! NaN.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{DemError, corrupt, file_name, invalid, io_error, sample_count, unsupported};
use crate::heightfield::{Crs, Georef, Heightfield};

/// SRTM void marker.
const VOID: i16 = i16::MIN;

/// One tile of a mosaic: where it is and how big.
struct Tile {
    path: PathBuf,
    name: String,
    /// South-west corner, whole degrees.
    lat: i32,
    lon: i32,
    /// Samples per side.
    n: usize,
}

/// One `.hgt` file. Its name must give its position unless the caller
/// overrides the spacing (`spacing_given`), in which case an unnamed tile
/// loads as a plain grid.
pub(super) fn load_single(path: &Path, spacing_given: bool) -> Result<Heightfield, DemError> {
    let n = side(path)?;
    match parse_name(path) {
        Some((lat, lon)) => {
            let tile = Tile { path: path.to_path_buf(), name: file_name(path), lat, lon, n };
            mosaic(vec![tile], file_name(path))
        }
        None if spacing_given => {
            let total = sample_count(path, n, n)?;
            let mut heights = vec![f32::NAN; total];
            fill(path, n, &mut heights, n, 0, 0)?;
            Ok(Heightfield::ungeoreferenced(n, n, heights, file_name(path)))
        }
        None => Err(invalid(
            path,
            "the file name does not say where the tile is (SRTM tiles are named after their \
             south-west corner, like N43E006.hgt); rename it or give the spacing",
        )),
    }
}

/// Every `.hgt` file in a folder, as one mosaic named after the folder.
pub(super) fn load_folder(dir: &Path) -> Result<Heightfield, DemError> {
    let mut paths = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| io_error(dir, e))? {
        let entry = entry.map_err(|e| io_error(dir, e))?;
        let p = entry.path();
        if is_hgt(&p) && p.is_file() {
            paths.push(p);
        }
    }
    if paths.is_empty() {
        return Err(invalid(dir, "the folder holds no .hgt tiles"));
    }
    paths.sort();
    let tiles = tiles(&paths)?;
    mosaic(tiles, file_name(dir))
}

/// Several `.hgt` files as one mosaic.
pub(super) fn load_mosaic(paths: &[PathBuf]) -> Result<Heightfield, DemError> {
    for p in paths {
        if !is_hgt(p) || p.is_dir() {
            return Err(unsupported(
                p,
                "only SRTM .hgt tiles can be combined into a mosaic; give other formats one at \
                 a time",
            ));
        }
    }
    let tiles = tiles(paths)?;
    let mut names: Vec<&str> = tiles.iter().map(|t| t.name.as_str()).collect();
    names.sort_unstable();
    let source = names.join("+");
    mosaic(tiles, source)
}

pub(crate) fn is_hgt(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("hgt"))
}

fn tiles(paths: &[PathBuf]) -> Result<Vec<Tile>, DemError> {
    paths
        .iter()
        .map(|p| {
            let n = side(p)?;
            let (lat, lon) = parse_name(p).ok_or_else(|| {
                invalid(
                    p,
                    "mismatched mosaic tiles: this name does not give the tile's position \
                     (expected the south-west corner, like N43E006.hgt)",
                )
            })?;
            Ok(Tile { path: p.clone(), name: file_name(p), lat, lon, n })
        })
        .collect()
}

/// Samples per side, from the file length: `len = 2·n²`.
fn side(path: &Path) -> Result<usize, DemError> {
    let len = std::fs::metadata(path).map_err(|e| io_error(path, e))?.len();
    let not_square =
        || corrupt(path, format!("{len} bytes is not a square grid of int16 (an SRTM tile is 2·n² bytes)"));
    if len % 2 != 0 {
        return Err(not_square());
    }
    let count = len / 2;
    let n = (count as f64).sqrt().round() as u64;
    if n < 2 || n.checked_mul(n) != Some(count) {
        return Err(not_square());
    }
    usize::try_from(n).map_err(|_| not_square())
}

/// `N43E006` (any case, anything after the first 7 characters) → (43, 6).
fn parse_name(path: &Path) -> Option<(i32, i32)> {
    let stem = path.file_name()?.to_str()?.as_bytes();
    let b = stem.get(..7)?;
    let digits = |s: &[u8]| -> Option<i32> {
        s.iter().try_fold(0i32, |acc, &c| c.is_ascii_digit().then(|| acc * 10 + i32::from(c - b'0')))
    };
    let lat = digits(&b[1..3])?;
    let lon = digits(&b[4..7])?;
    let lat = match b[0].to_ascii_uppercase() {
        b'N' => lat,
        b'S' => -lat,
        _ => return None,
    };
    let lon = match b[3].to_ascii_uppercase() {
        b'E' => lon,
        b'W' => -lon,
        _ => return None,
    };
    ((-90..90).contains(&lat) && (-180..180).contains(&lon)).then_some((lat, lon))
}

fn tile_name(lat: i32, lon: i32) -> String {
    format!(
        "{}{:02}{}{:03}",
        if lat < 0 { 'S' } else { 'N' },
        lat.unsigned_abs(),
        if lon < 0 { 'W' } else { 'E' },
        lon.unsigned_abs()
    )
}

/// Check the tiles form one full rectangle of equal tiles and stitch them.
fn mosaic(tiles: Vec<Tile>, source: String) -> Result<Heightfield, DemError> {
    let Some(first) = tiles.first() else {
        return Err(invalid(Path::new(&source), "no .hgt tiles given"));
    };
    let label = PathBuf::from(&source);
    let n = first.n;
    if let Some(other) = tiles.iter().find(|t| t.n != n) {
        return Err(invalid(
            &label,
            format!(
                "mismatched mosaic tiles: {} is {n} × {n} samples but {} is {} × {}",
                first.name, other.name, other.n, other.n
            ),
        ));
    }
    let mut seen: BTreeMap<(i32, i32), &str> = BTreeMap::new();
    for t in &tiles {
        if let Some(prev) = seen.insert((t.lat, t.lon), &t.name) {
            return Err(invalid(
                &label,
                format!(
                    "mismatched mosaic tiles: {prev} and {} are the same tile ({})",
                    t.name,
                    tile_name(t.lat, t.lon)
                ),
            ));
        }
    }
    let lat_min = tiles.iter().map(|t| t.lat).min().unwrap_or(0);
    let lat_max = tiles.iter().map(|t| t.lat).max().unwrap_or(0);
    let lon_min = tiles.iter().map(|t| t.lon).min().unwrap_or(0);
    let lon_max = tiles.iter().map(|t| t.lon).max().unwrap_or(0);
    let rows = (lat_max - lat_min + 1) as usize;
    let cols = (lon_max - lon_min + 1) as usize;
    if rows * cols != tiles.len() {
        let missing: Vec<String> = (lat_min..=lat_max)
            .rev()
            .flat_map(|lat| (lon_min..=lon_max).map(move |lon| (lat, lon)))
            .filter(|k| !seen.contains_key(k))
            .map(|(lat, lon)| tile_name(lat, lon))
            .collect();
        let shown = missing.iter().take(6).cloned().collect::<Vec<_>>().join(", ");
        let more = if missing.len() > 6 { ", …" } else { "" };
        return Err(invalid(
            &label,
            format!(
                "mismatched mosaic tiles: {} tiles do not form a full rectangle of {rows} × \
                 {cols}; missing {shown}{more}",
                tiles.len()
            ),
        ));
    }

    let too_big = || invalid(&label, format!("mosaic of {rows} × {cols} tiles of {n} samples is too large"));
    let width = cols.checked_mul(n - 1).and_then(|v| v.checked_add(1)).ok_or_else(too_big)?;
    let height = rows.checked_mul(n - 1).and_then(|v| v.checked_add(1)).ok_or_else(too_big)?;
    let total = sample_count(&label, width, height)?;
    let mut heights = vec![f32::NAN; total];

    // Later tiles overwrite earlier ones on shared edges: south-east first,
    // north-west last.
    let mut order: Vec<&Tile> = tiles.iter().collect();
    order.sort_by_key(|t| (t.lat, -t.lon));
    for t in order {
        let row0 = (lat_max - t.lat) as usize * (n - 1);
        let col0 = (t.lon - lon_min) as usize * (n - 1);
        fill(&t.path, n, &mut heights, width, row0, col0)?;
    }

    let step = 1.0 / (n - 1) as f64;
    let mut hf = Heightfield {
        width,
        height,
        heights: heights.into(),
        spacing_m: [1.0, 1.0],
        georef: Georef {
            crs: Crs::Geographic { epsg: Some(4326) },
            origin: [f64::from(lon_min), f64::from(lat_max + 1)],
            step: [step, -step],
            local_tangent: None,
            definition: None,
        },
        source,
    };
    hf.apply_local_tangent();
    Ok(hf)
}

/// Read one tile and write its non-void samples into the grid at
/// (`row0`, `col0`).
fn fill(path: &Path, n: usize, dst: &mut [f32], width: usize, row0: usize, col0: usize) -> Result<(), DemError> {
    let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
    let expected = n * n * 2;
    if bytes.len() != expected {
        return Err(corrupt(
            path,
            format!("expected {expected} bytes of samples, found {} (the file changed while reading)", bytes.len()),
        ));
    }
    for (r, row) in bytes.chunks_exact(2 * n).enumerate() {
        let start = (row0 + r) * width + col0;
        let Some(out) = dst.get_mut(start..start + n) else {
            return Err(corrupt(path, "tile does not fit the mosaic grid"));
        };
        for (o, b) in out.iter_mut().zip(row.chunks_exact(2)) {
            let v = i16::from_be_bytes([b[0], b[1]]);
            if v != VOID {
                *o = f32::from(v);
            }
        }
    }
    Ok(())
}
