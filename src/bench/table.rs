//! `bench.csv`: one row per (tool, DEM, max_error_m, threads); written,
//! appended to (the peers script adds its rows) and read back for the plot.
//!
//! Figures a tool does not have (bytes of a single TIN, stage times of a
//! Python peer) are left empty. Labels never contain commas, so the file is
//! plain comma-separated text without quoting.

use std::io::Write;
use std::path::Path;

use super::BenchError;

/// The header, in column order (README.md, "Benchmarks", says what each is).
pub const COLUMNS: [&str; 29] = [
    "tool",
    "dem",
    "width",
    "height",
    "samples",
    "max_error_m",
    "levels",
    "chunks",
    "triangles",
    "leaf_triangles",
    "vertices",
    "bytes",
    "bytes_per_sample",
    "measured_max_error_m",
    "measured_rms_error_m",
    "uncovered_samples",
    "s_load",
    "s_plan",
    "s_mesh",
    "s_skirt_morph",
    "s_write",
    "s_index",
    "s_total",
    "runs",
    "peak_rss_bytes",
    "threads",
    "sliver_share",
    "needles",
    "min_angle_deg",
];

/// One row of `bench.csv`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Row {
    /// `terrachunk` (whole pipeline), `terrachunk-single-tin`, `pymartini`, `pydelatin`, ...
    pub tool: String,
    /// DEM label: file name, plus the crop or window if any.
    pub dem: String,
    /// Grid columns.
    pub width: usize,
    /// Grid rows.
    pub height: usize,
    /// width × height.
    pub samples: usize,
    /// The error setting, metres.
    pub max_error_m: f64,
    /// Tree levels (1 for a single mesh).
    pub levels: Option<usize>,
    /// Chunks written (1 for a single mesh).
    pub chunks: Option<usize>,
    /// Surface triangles of all levels.
    pub triangles: Option<usize>,
    /// Surface triangles of the leaves (chunks without children): the
    /// finest surface, the one to compare with a single mesh.
    pub leaf_triangles: Option<usize>,
    /// Surface vertices of all levels.
    pub vertices: Option<usize>,
    /// Bytes written (.glb files and index files).
    pub bytes: Option<u64>,
    /// bytes / samples.
    pub bytes_per_sample: Option<f64>,
    /// Largest error of the finest surface, measured from the mesh, metres.
    pub measured_max_error_m: Option<f64>,
    /// RMS error of the finest surface, metres.
    pub measured_rms_error_m: Option<f64>,
    /// Valid samples no finest-surface triangle covers.
    pub uncovered_samples: Option<usize>,
    /// Median wall seconds: load, plan, mesh, skirt+morph, write, index, total.
    pub seconds: [Option<f64>; 7],
    /// Timed runs the medians are taken over.
    pub runs: usize,
    /// Largest peak resident memory of the timed runs, bytes.
    pub peak_rss_bytes: Option<u64>,
    /// Worker threads.
    pub threads: usize,
    /// Share of the finest surface's triangles with aspect over 100
    /// (longest edge ÷ its height, in plan: `mesh::quality`).
    pub sliver_share: Option<f64>,
    /// Finest-surface triangles with aspect over 1 000.
    pub needles: Option<usize>,
    /// Smallest angle of any finest-surface triangle, degrees.
    pub min_angle_deg: Option<f64>,
}

fn opt<T: ToString>(v: &Option<T>) -> String {
    v.as_ref().map(T::to_string).unwrap_or_default()
}

/// A label safe for the file (no commas or line breaks).
pub fn clean(s: &str) -> String {
    s.replace([',', '\n', '\r'], " ")
}

impl Row {
    fn fields(&self) -> Vec<String> {
        let mut f = vec![
            clean(&self.tool),
            clean(&self.dem),
            self.width.to_string(),
            self.height.to_string(),
            self.samples.to_string(),
            self.max_error_m.to_string(),
            opt(&self.levels),
            opt(&self.chunks),
            opt(&self.triangles),
            opt(&self.leaf_triangles),
            opt(&self.vertices),
            opt(&self.bytes),
            self.bytes_per_sample.map(|b| format!("{b:.3}")).unwrap_or_default(),
            self.measured_max_error_m.map(|e| format!("{e:.6}")).unwrap_or_default(),
            self.measured_rms_error_m.map(|e| format!("{e:.6}")).unwrap_or_default(),
            opt(&self.uncovered_samples),
        ];
        f.extend(self.seconds.iter().map(|s| s.map(|s| format!("{s:.6}")).unwrap_or_default()));
        f.extend([self.runs.to_string(), opt(&self.peak_rss_bytes), self.threads.to_string()]);
        f.extend([
            self.sliver_share.map(|s| format!("{s:.6}")).unwrap_or_default(),
            opt(&self.needles),
            self.min_angle_deg.map(|a| format!("{a:.6}")).unwrap_or_default(),
        ]);
        f
    }

    fn parse(line: &str) -> Option<Row> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != COLUMNS.len() {
            return None;
        }
        fn o<T: std::str::FromStr>(s: &str) -> Option<Option<T>> {
            if s.is_empty() { Some(None) } else { s.parse().ok().map(Some) }
        }
        let mut seconds = [None; 7];
        for (k, s) in seconds.iter_mut().enumerate() {
            *s = o(f[16 + k])?;
        }
        Some(Row {
            tool: f[0].into(),
            dem: f[1].into(),
            width: f[2].parse().ok()?,
            height: f[3].parse().ok()?,
            samples: f[4].parse().ok()?,
            max_error_m: f[5].parse().ok()?,
            levels: o(f[6])?,
            chunks: o(f[7])?,
            triangles: o(f[8])?,
            leaf_triangles: o(f[9])?,
            vertices: o(f[10])?,
            bytes: o(f[11])?,
            bytes_per_sample: o(f[12])?,
            measured_max_error_m: o(f[13])?,
            measured_rms_error_m: o(f[14])?,
            uncovered_samples: o(f[15])?,
            seconds,
            runs: f[23].parse().ok()?,
            peak_rss_bytes: o(f[24])?,
            threads: f[25].parse().ok()?,
            sliver_share: o(f[26])?,
            needles: o(f[27])?,
            min_angle_deg: o(f[28])?,
        })
    }

    /// The shape columns from a summary of the finest surface.
    pub fn with_shape(self, s: &crate::mesh::quality::ShapeSummary) -> Row {
        Row {
            sliver_share: Some(s.sliver_share()),
            needles: Some(s.needles),
            min_angle_deg: Some(s.min_angle_deg),
            ..self
        }
    }

    /// Median total seconds, the time the plot shows.
    pub fn total_seconds(&self) -> Option<f64> {
        self.seconds[6]
    }
}

/// Writes `rows` to `path`: a new file with the header, or (with `append`
/// and an existing file) added at its end.
pub fn write(path: &Path, rows: &[Row], append: bool) -> Result<(), BenchError> {
    let io = |source| BenchError::Io { path: path.into(), source };
    let fresh = !append || !path.exists();
    let file =
        std::fs::OpenOptions::new().create(true).write(true).append(!fresh).truncate(fresh).open(path).map_err(io)?;
    let mut out = std::io::BufWriter::new(file);
    if fresh {
        writeln!(out, "{}", COLUMNS.join(",")).map_err(io)?;
    }
    for r in rows {
        writeln!(out, "{}", r.fields().join(",")).map_err(io)?;
    }
    out.flush().map_err(io)
}

/// Reads a file [`write()`] wrote.
pub fn read(path: &Path) -> Result<Vec<Row>, BenchError> {
    let text = std::fs::read_to_string(path).map_err(|source| BenchError::Io { path: path.into(), source })?;
    let mut lines = text.lines();
    if lines.next() != Some(COLUMNS.join(",").as_str()) {
        return Err(BenchError::Input { path: path.into(), what: "not a bench.csv (header differs)".into() });
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, l)| {
            Row::parse(l)
                .ok_or_else(|| BenchError::Input { path: path.into(), what: format!("line {}: bad row", n + 2) })
        })
        .collect()
}
