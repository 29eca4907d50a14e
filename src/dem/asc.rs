//! ESRI ASCII grid (`.asc`): a keyword header, then rows north to south.
//!
//! Header keywords, in any case and order: `ncols`, `nrows`,
//! `xllcorner`|`xllcenter`, `yllcorner`|`yllcenter`, `cellsize` (or GDAL's
//! `dx`/`dy`), and optionally `NODATA_value`. The file does not name its
//! coordinate system; it is read as projected metres (spacing = cellsize)
//! unless a `.prj` beside it describes a geographic one (`GEOGCS` without
//! `PROJCS`), in which case the cell size is degrees and the grid goes
//! through the local tangent plane.
//!
//! A value equal to `NODATA_value` is nodata. `NaN` is nodata only when the
//! header says so (`NODATA_value nan`); anywhere else it is refused, as is a
//! value `f32` cannot hold within 1 mm (see [`super::MAX_ROUNDING_M`]).

use std::path::Path;

use super::{DemError, check_stored, corrupt, file_name, invalid, io_error, sample_count};
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

/// Read an ESRI ASCII grid.
pub(super) fn load(path: &Path) -> Result<Heightfield, DemError> {
    let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
    let text = std::str::from_utf8(&bytes).map_err(|e| corrupt(path, format!("not a text file: {e}")))?;

    let mut header = Header::default();
    let mut lines = text.lines().enumerate().peekable();
    while let Some(&(i, line)) = lines.peek() {
        let mut tokens = line.split_ascii_whitespace();
        let Some(key) = tokens.next() else {
            lines.next();
            continue;
        };
        if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || is_number(key) {
            break;
        }
        lines.next();
        let line_no = i + 1;
        let value = tokens
            .next()
            .ok_or_else(|| corrupt(path, format!("line {line_no}: header keyword {key:?} has no value")))?;
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

    // Never reserve more than the text could hold (two bytes per value), so a
    // lying header cannot make us allocate gigabytes.
    let mut heights = Vec::with_capacity(expected.min(text.len() / 2 + 1));
    let mut found = 0usize;
    for (i, line) in lines {
        for token in line.split_ascii_whitespace() {
            let v: f32 =
                token.parse().map_err(|_| corrupt(path, format!("line {}: {token:?} is not a number", i + 1)))?;
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
                return Err(invalid(
                    path,
                    format!("line {}: {token:?} is not a height (NODATA_value is {declared})", i + 1),
                ));
            }
            if v.abs() >= 32_768.0 {
                // Far from 0 the nearest f32 may be more than 1 mm off (or
                // infinite where the text is merely large).
                let exact: f64 = token.parse().expect("a token that parses as f32 parses as f64");
                check_stored(exact, v).map_err(|e| invalid(path, format!("line {}: {e}", i + 1)))?;
            }
            heights.push(v);
        }
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

    let geographic = prj_is_geographic(path);
    let mut hf = Heightfield {
        width: ncols,
        height: nrows,
        heights,
        spacing_m: [dx, dy],
        georef: Georef {
            crs: if geographic { Crs::Geographic { epsg: None } } else { Crs::Projected { epsg: None } },
            origin: [x0, y0],
            step: [dx, -dy],
            local_tangent: None,
        },
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

/// A `.prj` beside the grid whose WKT is a geographic (not projected) CRS.
fn prj_is_geographic(path: &Path) -> bool {
    let prj = path.with_extension("prj");
    match std::fs::read_to_string(prj) {
        Ok(wkt) => {
            let upper = wkt.to_ascii_uppercase();
            let upper = upper.trim_start();
            (upper.starts_with("GEOGCS") || upper.starts_with("GEOGCRS")) && !upper.contains("PROJCS")
        }
        Err(_) => false,
    }
}
