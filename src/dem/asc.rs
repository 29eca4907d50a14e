//! ESRI ASCII grid (`.asc`): a keyword header, then rows north to south.
//!
//! Header keywords, in any case and order: `ncols`, `nrows`,
//! `xllcorner`|`xllcenter`, `yllcorner`|`yllcenter`, `cellsize` (or GDAL's
//! `dx`/`dy`), and optionally `NODATA_value`. The file does not name its
//! coordinate system; a `.prj` beside it may (`super::prj`: an EPSG code in
//! its WKT, or a PROJ.4 string). The grid is read as projected (spacing =
//! cellsize times the CRS's linear unit, metres unless the CRS says feet)
//! unless the `.prj` describes a geographic CRS, in which case the cell
//! size is degrees and the grid goes through the local tangent plane.
//!
//! A value equal to `NODATA_value` is nodata. `NaN` is nodata only when the
//! header says so (`NODATA_value nan`); anywhere else it is refused, as is a
//! value `f32` cannot hold within 1 mm (see [`super::MAX_ROUNDING_M`]).

use std::io::{BufRead, BufReader};
use std::path::Path;

use super::prj::crs_of_prj;
use super::{DemError, check_stored, corrupt, file_name, invalid, io_error, sample_count};
use crate::geodesy::SourceCrs;
use crate::heightfield::{Crs, Georef, Heightfield};

#[derive(Default)]
struct Header {
    ncols: Option<usize>,
    nrows: Option<usize>,
    /// x of the lower-left corner or centre, and whether it is the centre.
    xll: Option<(f64, bool)>,
    yll: Option<(f64, bool)>,
    cellsize: Option<f64>,
    dx: Option<f64>,
    dy: Option<f64>,
    nodata: Option<f32>,
}

/// The longest token (keyword or number) a grid may hold, bytes: a height
/// written with every digit an `f64` has is under 30.
const MAX_TOKEN: usize = 64;

/// Whitespace-separated tokens read in pieces from a file, with the line
/// each starts on: the file is never held whole, so a huge one costs only
/// its grid, and a file with no whitespace costs a token's worth.
struct Tokens<R> {
    r: R,
    /// The current token and its line (1-based).
    token: Vec<u8>,
    token_line: usize,
    line: usize,
    /// A token read ahead (the first of the body, found by the header loop).
    held: bool,
}

impl<R: BufRead> Tokens<R> {
    /// Reads the next token into `self.token`; false at the end of the file.
    fn next(&mut self, path: &Path) -> Result<bool, DemError> {
        if std::mem::take(&mut self.held) {
            return Ok(true);
        }
        self.token.clear();
        loop {
            let buf = self.r.fill_buf().map_err(|e| io_error(path, e))?;
            if buf.is_empty() {
                return Ok(!self.token.is_empty());
            }
            let mut used = 0;
            let mut ended = false;
            for &b in buf {
                used += 1;
                if b.is_ascii_whitespace() {
                    if b == b'\n' {
                        self.line += 1;
                    }
                    if !self.token.is_empty() {
                        ended = true;
                        break;
                    }
                } else {
                    if self.token.is_empty() {
                        self.token_line = self.line;
                    }
                    if self.token.len() == MAX_TOKEN {
                        return Err(corrupt(
                            path,
                            format!("line {}: a token longer than {MAX_TOKEN} bytes; not a grid", self.line),
                        ));
                    }
                    self.token.push(b);
                }
            }
            self.r.consume(used);
            if ended {
                return Ok(true);
            }
        }
    }

    fn text(&self, path: &Path) -> Result<&str, DemError> {
        std::str::from_utf8(&self.token)
            .map_err(|e| corrupt(path, format!("line {}: not a text file: {e}", self.token_line)))
    }
}

/// Read an ESRI ASCII grid: the header first, checked, then the values,
/// streamed from the file.
pub(super) fn load(path: &Path) -> Result<Heightfield, DemError> {
    let file = std::fs::File::open(path).map_err(|e| io_error(path, e))?;
    let file_len = file.metadata().map_err(|e| io_error(path, e))?.len();
    let mut tokens = Tokens { r: BufReader::new(file), token: Vec::new(), token_line: 1, line: 1, held: false };

    let mut header = Header::default();
    while tokens.next(path)? {
        let key = tokens.text(path)?.to_string();
        if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || is_number(&key) {
            tokens.held = true; // the first value
            break;
        }
        let line_no = tokens.token_line;
        if !tokens.next(path)? || tokens.token_line != line_no {
            return Err(corrupt(path, format!("line {line_no}: header keyword {key:?} has no value")));
        }
        let value = tokens.text(path)?;
        let num = || {
            value
                .parse::<f64>()
                .map_err(|_| corrupt(path, format!("line {line_no}: {key} value {value:?} is not a number")))
        };
        let count = || {
            value
                .parse::<usize>()
                .map_err(|_| corrupt(path, format!("line {line_no}: {key} value {value:?} is not a whole number")))
        };
        match key.to_ascii_lowercase().as_str() {
            "ncols" => header.ncols = Some(count()?),
            "nrows" => header.nrows = Some(count()?),
            "xllcorner" => header.xll = Some((num()?, false)),
            "xllcenter" => header.xll = Some((num()?, true)),
            "yllcorner" => header.yll = Some((num()?, false)),
            "yllcenter" => header.yll = Some((num()?, true)),
            "cellsize" => header.cellsize = Some(num()?),
            "dx" => header.dx = Some(num()?),
            "dy" => header.dy = Some(num()?),
            "nodata_value" | "nodata" => {
                header.nodata = Some(
                    value
                        .parse::<f32>()
                        .map_err(|_| corrupt(path, format!("line {line_no}: {key} value {value:?} is not a number")))?,
                )
            }
            _ => {
                return Err(corrupt(path, format!("line {line_no}: unknown header keyword {key:?}")));
            }
        }
    }

    let missing = |what: &str| corrupt(path, format!("the header has no {what}"));
    let ncols = header.ncols.ok_or_else(|| missing("ncols"))?;
    let nrows = header.nrows.ok_or_else(|| missing("nrows"))?;
    let (dx, dy) = match (header.cellsize, header.dx, header.dy) {
        (_, Some(dx), Some(dy)) => (dx, dy),
        (Some(c), _, _) => (c, c),
        _ => return Err(missing("cellsize")),
    };
    let expected = sample_count(path, ncols, nrows)?;

    // Each value takes at least two bytes (a digit and a separator), so a
    // header promising more than the file can hold is refused before the
    // body is read, and nothing is reserved beyond what it could hold.
    if (expected as u64).saturating_mul(2) > file_len.saturating_add(1) {
        return Err(corrupt(
            path,
            format!(
                "the header promises ncols × nrows = {ncols} × {nrows} = {expected} values but the file is only \
                 {file_len} bytes"
            ),
        ));
    }
    let mut heights = Vec::with_capacity(expected);
    let mut found = 0usize;
    while tokens.next(path)? {
        let line = tokens.token_line;
        let token = tokens.text(path)?;
        let v: f32 = token.parse().map_err(|_| corrupt(path, format!("line {line}: {token:?} is not a number")))?;
        found += 1;
        if found > expected {
            continue;
        }
        if Some(v) == header.nodata {
            heights.push(f32::NAN);
            continue;
        }
        if v.is_nan() && !header.nodata.is_some_and(f32::is_nan) {
            // Text declares its nodata; a NaN is a broken export, not a hole.
            let declared = header.nodata.map_or("not declared".to_string(), |n| n.to_string());
            return Err(invalid(path, format!("line {line}: {token:?} is not a height (NODATA_value is {declared})")));
        }
        if v.abs() >= 32_768.0 {
            // Far from 0 the nearest f32 may be more than 1 mm off (or
            // infinite where the text is merely large).
            let exact: f64 = token.parse().expect("a token that parses as f32 parses as f64");
            check_stored(exact, v).map_err(|e| invalid(path, format!("line {line}: {e}")))?;
        }
        heights.push(v);
    }
    if found != expected {
        return Err(corrupt(
            path,
            format!("found {found} values, expected ncols × nrows = {ncols} × {nrows} = {expected}"),
        ));
    }

    // Centre of the north-west sample.
    let (xll, x_centre) = header.xll.unwrap_or((0.0, false));
    let (yll, y_centre) = header.yll.unwrap_or((0.0, false));
    let x0 = if x_centre { xll } else { xll + dx / 2.0 };
    let y_south = if y_centre { yll } else { yll + dy / 2.0 };
    let y0 = y_south + dy * nrows.saturating_sub(1) as f64;

    let (crs, definition) = read_prj(path).map_or((Crs::Projected { epsg: None }, None), |t| crs_of_prj(&t));
    let geographic = matches!(crs, Crs::Geographic { .. });
    let mut spacing_m = [dx, dy];
    if !geographic && let Ok(source) = SourceCrs::of(&crs, definition.as_deref()) {
        // Feet grids become metres; Mercator's are scaled to the ground at
        // the centre, as for GeoTIFF (`geotiff::georeference`).
        let mid = [x0 + dx * ncols.saturating_sub(1) as f64 / 2.0, y0 - dy * nrows.saturating_sub(1) as f64 / 2.0];
        let k = source.metres_per_unit() * source.ground_per_grid_m(mid).unwrap_or(1.0);
        spacing_m = [dx * k, dy * k];
    }
    let mut hf = Heightfield {
        width: ncols,
        height: nrows,
        heights: heights.into(),
        spacing_m,
        georef: Georef { crs, origin: [x0, y0], step: [dx, -dy], local_tangent: None, definition },
        source: file_name(path),
    };
    if geographic && dx > 0.0 && dy > 0.0 {
        hf.apply_local_tangent();
    }
    Ok(hf)
}

fn is_number(token: &str) -> bool {
    token.parse::<f64>().is_ok()
}

/// The text of the `.prj` beside the grid, if there is one to read.
fn read_prj(path: &Path) -> Option<String> {
    let prj = path.with_extension("prj");
    // Only a regular file, and only its start: a FIFO or a huge file
    // named like the grid must not stall the load.
    let read = |p: &Path| -> std::io::Result<String> {
        use std::io::Read;
        if !std::fs::metadata(p)?.is_file() {
            return Err(std::io::ErrorKind::InvalidInput.into());
        }
        let mut text = String::new();
        std::fs::File::open(p)?.take(1 << 16).read_to_string(&mut text)?;
        Ok(text)
    };
    read(&prj).ok()
}
