//! The benchmark plot: triangles against max error and time against max
//! error, log–log, one line per (tool, DEM), drawn with `plotters` to PNG and
//! SVG from the rows of `bench.csv`.
//!
//! Text is set in a subset of DejaVu Sans that ships in `bench/` (licence
//! beside it) and is compiled in, so the plot needs no system fonts.

use std::collections::BTreeMap;
use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::BenchError;
use super::table::Row;

const FONT: &[u8] = include_bytes!("../../bench/DejaVuSans-subset.ttf");
const SIZE: (u32, u32) = (1400, 620);
const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and known to parse; a failure would show as a
        // "font unavailable" drawing error below.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Draws `rows` into `png` and `svg`.
pub fn plot(rows: &[Row], png: &Path, svg: &Path) -> Result<(), BenchError> {
    register_font();
    let series = series(rows);
    if series.is_empty() {
        return Err(BenchError::Plot("no rows with triangles and times to plot".into()));
    }
    let plot_err = |e: String| BenchError::Plot(e);
    {
        let root = SVGBackend::new(svg, SIZE).into_drawing_area();
        draw(&root, &series).map_err(plot_err)?;
        root.present().map_err(|e| BenchError::Plot(format!("{}: {e}", svg.display())))?;
    }
    let mut buf = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        draw(&root, &series).map_err(plot_err)?;
        root.present().map_err(|e| BenchError::Plot(e.to_string()))?;
    }
    image::save_buffer(png, &buf, SIZE.0, SIZE.1, image::ExtendedColorType::Rgb8)
        .map_err(|e| BenchError::Plot(format!("{}: {e}", png.display())))
}

/// One point: max_error_m, leaf triangles, total seconds.
type Point = (f64, Option<f64>, Option<f64>);
/// One line: its label and points.
type Series = (String, Vec<Point>);

fn series(rows: &[Row]) -> Vec<Series> {
    let mut by: BTreeMap<(String, String, usize), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        by.entry((r.tool.clone(), r.dem.clone(), r.threads)).or_default().push(r);
    }
    // Thread counts are named only when the pipeline ran with several.
    let several_threads = {
        let mut t: Vec<usize> = rows.iter().filter(|r| r.tool == "terrachunk").map(|r| r.threads).collect();
        t.sort_unstable();
        t.dedup();
        t.len() > 1
    };
    by.into_iter()
        .map(|((tool, dem, threads), mut rs)| {
            rs.sort_by(|a, b| a.max_error_m.total_cmp(&b.max_error_m));
            let label = if several_threads && tool == "terrachunk" {
                format!("{tool}, {dem}, {threads} threads")
            } else {
                format!("{tool}, {dem}")
            };
            let pts = rs
                .iter()
                .map(|r| {
                    let tri = r.leaf_triangles.or(r.triangles).map(|t| t as f64).filter(|t| *t > 0.0);
                    (r.max_error_m, tri, r.total_seconds().filter(|s| *s > 0.0))
                })
                .collect();
            (label, pts)
        })
        .filter(|(_, p): &Series| p.iter().any(|q| q.1.is_some() || q.2.is_some()))
        .collect()
}

/// A tick label without float noise: 0.25, 2, 1e5.
fn tick(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e4 || v.abs() < 1e-2 {
        format!("{v:.0e}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() { 0.1..10.0 } else { lo / 1.5..hi * 1.5 }
}

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, series: &[Series]) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let root = root.titled("terrachunk bench: speed against error", ("sans-serif", 26)).map_err(|e| e.to_string())?;
    let panels = root.split_evenly((1, 2));
    let x = log_range(series.iter().flat_map(|s| s.1.iter().map(|p| p.0)));
    // Tick the errors that were run (a log axis alone only ticks powers of ten).
    let mut x_ticks: Vec<f64> = series.iter().flat_map(|s| s.1.iter().map(|p| p.0)).collect();
    x_ticks.sort_by(f64::total_cmp);
    x_ticks.dedup();
    let panel = |area: &DrawingArea<DB, Shift>,
                 caption: &str,
                 y_desc: &str,
                 pick: &dyn Fn(&Point) -> Option<f64>,
                 legend: bool|
     -> Result<(), String> {
        let y = log_range(series.iter().flat_map(|s| s.1.iter().filter_map(pick)));
        let mut chart = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 18))
            .margin(14)
            .x_label_area_size(48)
            .y_label_area_size(78)
            .build_cartesian_2d(x.clone().log_scale().with_key_points(x_ticks.clone()), y.log_scale())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .y_labels(12)
            .x_desc("max_error_m (m)")
            .y_desc(y_desc)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .bold_line_style(RGBColor(200, 200, 200))
            .light_line_style(TRANSPARENT)
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(|e| e.to_string())?;
        for (k, (label, pts)) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let line: Vec<(f64, f64)> = pts.iter().filter_map(|p| pick(p).map(|v| (p.0, v))).collect();
            if line.is_empty() {
                continue;
            }
            let drawn =
                chart.draw_series(LineSeries::new(line.clone(), colour.stroke_width(2))).map_err(|e| e.to_string())?;
            if legend {
                drawn
                    .label(label.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(2)));
            }
            chart
                .draw_series(line.iter().map(|&(a, b)| Circle::new((a, b), 4, colour.filled())))
                .map_err(|e| e.to_string())?;
        }
        if legend {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerLeft)
                .label_font(("sans-serif", 14))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    };
    panel(&panels[0], "finest-level triangles (a single TIN: all of it)", "triangles", &|p| p.1, true)?;
    panel(
        &panels[1],
        "wall time (terrachunk: whole pipeline, files written; peers: meshing)",
        "seconds",
        &|p| p.2,
        false,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::tick;

    #[test]
    fn ticks_read_cleanly() {
        assert_eq!(tick(0.25), "0.25");
        assert_eq!(tick(2.0), "2");
        assert_eq!(tick(0.30000000000000004), "0.3");
        assert_eq!(tick(100000.0), "1e5");
    }
}
