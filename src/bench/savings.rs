//! What the error-bounded tree saves: each DEM is built
//! twice at the same `max_error_m`, once as shipped (a subtree ends where its
//! chunk already meets the leaf error) and once with `complete_tree` (every
//! chunk refined to the deepest level), and the two are compared in chunks,
//! triangles and bytes. Chunks over nodata alone are absent from both.

use std::fmt::Write as _;
use std::path::Path;

use super::{BenchError, ChildReport, Cut, Outputs, Runs, build_once, check_errors, load_options, prepare, scratch};

/// One DEM at one error, both trees.
#[derive(Clone, Debug, PartialEq)]
pub struct SavingsRow {
    /// DEM label.
    pub dem: String,
    /// Grid samples.
    pub samples: usize,
    /// Valid (not nodata) samples.
    pub valid: usize,
    /// max_error_m.
    pub max_error_m: f64,
    /// The error-bounded tree.
    pub bounded: TreeFigures,
    /// Every chunk to the deepest level.
    pub complete: TreeFigures,
}

/// One tree's size.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TreeFigures {
    /// Levels with at least one chunk.
    pub levels: usize,
    /// Chunks, all levels.
    pub chunks: usize,
    /// Surface triangles, all levels.
    pub triangles: usize,
    /// Bytes written.
    pub bytes: u64,
}

impl TreeFigures {
    fn from_report(r: &ChildReport) -> Self {
        TreeFigures {
            levels: r.levels.iter().filter(|l| l.chunks > 0).count(),
            chunks: r.levels.iter().map(|l| l.chunks).sum(),
            triangles: r.levels.iter().map(|l| l.triangles).sum(),
            bytes: r.bytes,
        }
    }
}

impl SavingsRow {
    /// Share of the complete tree's chunks the bounded tree does without.
    pub fn chunks_saved(&self) -> f64 {
        saved(self.bounded.chunks as f64, self.complete.chunks as f64)
    }

    /// Share of the complete tree's triangles the bounded tree does without.
    pub fn triangles_saved(&self) -> f64 {
        saved(self.bounded.triangles as f64, self.complete.triangles as f64)
    }

    /// Share of the complete tree's bytes the bounded tree does without.
    pub fn bytes_saved(&self) -> f64 {
        saved(self.bounded.bytes as f64, self.complete.bytes as f64)
    }
}

fn saved(ours: f64, complete: f64) -> f64 {
    if complete > 0.0 { 1.0 - ours / complete } else { 0.0 }
}

/// Builds every DEM both ways at every error; writes `out/savings.csv`.
/// One build of each tree per DEM and error, with the first thread count:
/// the counts compared do not depend on timing, so `runs` and `warmup` are
/// not used.
pub fn savings(o: &Runs) -> Result<Vec<SavingsRow>, BenchError> {
    check_errors(&o.errors)?;
    std::fs::create_dir_all(&o.out).map_err(|source| BenchError::Io { path: o.out.clone(), source })?;
    let work = scratch(&o.out)?;
    let mut outputs = Outputs::new(&work.0);
    let load = load_options(o.config.as_deref())?;
    let mut rows = Vec::new();
    for dem in &o.dems {
        let p = prepare(dem, Cut::Whole, &load, &work.0)?;
        let mut complete = prepare(dem, Cut::Whole, &load, &work.0)?;
        complete.build_args.push("--complete-tree".into());
        for &e in &o.errors {
            let threads = o.threads.first().copied().unwrap_or(0);
            let b = build_once(&o.exe, &p, o.config.as_deref(), e, threads, &mut outputs)?;
            let c = build_once(&o.exe, &complete, o.config.as_deref(), e, threads, &mut outputs)?;
            let row = SavingsRow {
                dem: p.label.clone(),
                samples: p.hf.width * p.hf.height,
                valid: p.hf.valid_count(),
                max_error_m: e,
                bounded: TreeFigures::from_report(&b),
                complete: TreeFigures::from_report(&c),
            };
            eprintln!(
                "{} at {e} m: {} of {} chunks, {} of {} triangles",
                row.dem, row.bounded.chunks, row.complete.chunks, row.bounded.triangles, row.complete.triangles
            );
            rows.push(row);
        }
    }
    write_csv(&o.out.join("savings.csv"), &rows)?;
    Ok(rows)
}

fn write_csv(path: &Path, rows: &[SavingsRow]) -> Result<(), BenchError> {
    let mut s = String::from(
        "dem,samples,valid_samples,max_error_m,levels,complete_levels,chunks,complete_chunks,\
         triangles,complete_triangles,bytes,complete_bytes,bytes_per_sample,complete_bytes_per_sample\n",
    );
    for r in rows {
        let n = r.samples as f64;
        let (b, c) = (&r.bounded, &r.complete);
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.3}",
            r.dem,
            r.samples,
            r.valid,
            r.max_error_m,
            b.levels,
            c.levels,
            b.chunks,
            c.chunks,
            b.triangles,
            c.triangles,
            b.bytes,
            c.bytes,
            b.bytes as f64 / n,
            c.bytes as f64 / n
        );
    }
    std::fs::write(path, s).map_err(|source| BenchError::Io { path: path.into(), source })
}

/// The rows as a Markdown table (what the README shows).
pub fn markdown(rows: &[SavingsRow]) -> String {
    let mut s = String::from(
        "| DEM | samples (nodata) | max error | levels (complete tree) | chunks (complete tree) | saved | \
         triangles (complete tree) | saved | bytes/sample (complete tree) |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let (b, c) = (&r.bounded, &r.complete);
        let n = r.samples as f64;
        let _ = writeln!(
            s,
            "| {} | {} ({}) | {} m | {} ({}) | {} ({}) | {:.0} % | {} ({}) | {:.0} % | {:.1} ({:.1}) |",
            r.dem,
            r.samples,
            r.samples - r.valid,
            r.max_error_m,
            b.levels,
            c.levels,
            b.chunks,
            c.chunks,
            100.0 * r.chunks_saved(),
            b.triangles,
            c.triangles,
            100.0 * r.triangles_saved(),
            b.bytes as f64 / n,
            c.bytes as f64 / n
        );
    }
    s
}
