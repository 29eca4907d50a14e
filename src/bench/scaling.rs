//! Scaling: centred windows of a DEM with a share of its samples each,
//! built at one error and thread counts (`OUT/scaling.csv`).

use super::*;

/// What [`scaling`] runs.
#[derive(Clone, Debug)]
pub struct ScaleOptions {
    /// DEMs, errors, runs, threads, output (`scaling.csv`).
    pub base: Runs,
    /// Each run keeps 1/f of the samples (a centred window); 1 = the whole file.
    pub fractions: Vec<u32>,
}

/// One configuration of a scaling run.
#[derive(Clone, Debug)]
pub struct ScaleRow {
    /// DEM label (with the window).
    pub dem: String,
    /// 1/f of the samples.
    pub fraction: u32,
    /// Grid columns.
    pub width: usize,
    /// Grid rows.
    pub height: usize,
    /// max_error_m.
    pub max_error_m: f64,
    /// Threads.
    pub threads: usize,
    /// Levels.
    pub levels: usize,
    /// Chunks.
    pub chunks: usize,
    /// Surface triangles, all levels.
    pub triangles: usize,
    /// Median seconds per stage (as in `bench.csv`).
    pub seconds: [f64; 7],
    /// Largest VmHWM of the timed runs.
    pub peak_rss_bytes: Option<u64>,
    /// Timed runs.
    pub runs: usize,
}

impl ScaleRow {
    /// Samples in the window.
    pub fn samples(&self) -> usize {
        self.width * self.height
    }
}

/// Runs the scaling configurations and writes `out/scaling.csv`.
pub fn scaling(o: &ScaleOptions) -> Result<Vec<ScaleRow>, BenchError> {
    check_errors(&o.base.errors)?;
    if o.fractions.is_empty() || o.fractions.contains(&0) {
        return Err(BenchError::Usage(format!("--scale {:?}: fractions are whole numbers ≥ 1", o.fractions)));
    }
    std::fs::create_dir_all(&o.base.out).map_err(|source| BenchError::Io { path: o.base.out.clone(), source })?;
    let work = scratch(&o.base.out)?;
    let mut outputs = Outputs::new(&work.0);
    let load = load_options(o.base.config.as_deref())?;
    let mut rows = Vec::new();
    for dem in &o.base.dems {
        for &f in &o.fractions {
            let cut = if f == 1 { Cut::Whole } else { Cut::Window(f) };
            let p = prepare(dem, cut, &load, &work.0)?;
            for &e in &o.base.errors {
                for &t in &o.base.threads {
                    let reports = timed_builds(&o.base, &p, e, t, &mut outputs)?;
                    let last = reports.last().expect("at least one run");
                    let row = ScaleRow {
                        dem: p.label.clone(),
                        fraction: f,
                        width: p.hf.width,
                        height: p.hf.height,
                        max_error_m: e,
                        threads: last.threads,
                        levels: last.levels.len(),
                        chunks: last.levels.iter().map(|l| l.chunks).sum(),
                        triangles: last.levels.iter().map(|l| l.triangles).sum(),
                        seconds: median_stages(&reports),
                        peak_rss_bytes: reports.iter().filter_map(|r| r.peak_rss_bytes).max(),
                        runs: reports.len(),
                    };
                    eprintln!(
                        "{} at {e} m on {} threads: median {:.3} s, peak {:.0} MB",
                        row.dem,
                        row.threads,
                        row.seconds[6],
                        row.peak_rss_bytes.unwrap_or(0) as f64 / 1e6
                    );
                    rows.push(row);
                }
            }
            if cut != Cut::Whole {
                let _ = std::fs::remove_file(&p.build_input);
            }
        }
    }
    write_scaling(&o.base.out.join("scaling.csv"), &rows)?;
    Ok(rows)
}

pub(super) fn write_scaling(path: &Path, rows: &[ScaleRow]) -> Result<(), BenchError> {
    let mut s = String::from(
        "dem,fraction,width,height,samples,max_error_m,threads,levels,chunks,triangles,\
         s_load,s_plan,s_mesh,s_skirt_morph,s_write,s_index,s_total,us_per_sample,runs,peak_rss_bytes,rss_bytes_per_sample\n",
    );
    for r in rows {
        let n = r.samples() as f64;
        let rss = r.peak_rss_bytes.map(|b| b.to_string()).unwrap_or_default();
        let rss_per = r.peak_rss_bytes.map(|b| format!("{:.2}", b as f64 / n)).unwrap_or_default();
        let secs: Vec<String> = r.seconds.iter().map(|s| format!("{s:.6}")).collect();
        s += &format!(
            "{},1/{},{},{},{},{},{},{},{},{},{},{:.4},{},{},{}\n",
            r.dem,
            r.fraction,
            r.width,
            r.height,
            r.samples(),
            r.max_error_m,
            r.threads,
            r.levels,
            r.chunks,
            r.triangles,
            secs.join(","),
            r.seconds[6] / n * 1e6,
            r.runs,
            rss,
            rss_per
        );
    }
    std::fs::write(path, s).map_err(|source| BenchError::Io { path: path.into(), source })
}

/// How cost grows, as text: for each (DEM, error, threads) the exponent
/// `b` in time ∝ samples^b (and memory ∝ samples^b) between successive
/// windows, and the speed-up of each thread count over the smallest.
pub fn scaling_summary(rows: &[ScaleRow]) -> String {
    let mut s = String::new();
    s += &format!(
        "{:<44} {:>10} {:>7} {:>9} {:>10} {:>9} {:>8} {:>8}\n",
        "dem", "samples", "threads", "seconds", "µs/sample", "peak MB", "b(time)", "b(mem)"
    );
    for (k, r) in rows.iter().enumerate() {
        // The previous window of the same DEM, error and threads.
        let prev = rows[..k].iter().rev().find(|q| {
            q.threads == r.threads
                && q.max_error_m == r.max_error_m
                && q.fraction != r.fraction
                && same_dem(&q.dem, &r.dem)
        });
        let exp = |a: f64, b: f64, na: f64, nb: f64| {
            if a > 0.0 && b > 0.0 && na != nb { format!("{:.2}", (b / a).ln() / (nb / na).ln()) } else { "-".into() }
        };
        let n = r.samples() as f64;
        let (bt, bm) = match prev {
            Some(q) => (
                exp(q.seconds[6], r.seconds[6], q.samples() as f64, n),
                exp(q.peak_rss_bytes.unwrap_or(0) as f64, r.peak_rss_bytes.unwrap_or(0) as f64, q.samples() as f64, n),
            ),
            None => ("-".into(), "-".into()),
        };
        s += &format!(
            "{:<44} {:>10} {:>7} {:>9.3} {:>10.3} {:>9.1} {:>8} {:>8}\n",
            format!("{} @ {} m", r.dem, r.max_error_m),
            r.samples(),
            r.threads,
            r.seconds[6],
            r.seconds[6] / n * 1e6,
            r.peak_rss_bytes.unwrap_or(0) as f64 / 1e6,
            bt,
            bm
        );
    }
    for r in rows {
        let base = rows.iter().filter(|q| q.dem == r.dem && q.max_error_m == r.max_error_m).min_by_key(|q| q.threads);
        if let Some(b) = base.filter(|b| b.threads != r.threads) {
            s += &format!(
                "{} @ {} m: {} threads run at {:.2}× the speed of {}\n",
                r.dem,
                r.max_error_m,
                r.threads,
                b.seconds[6] / r.seconds[6],
                b.threads
            );
        }
    }
    s
}
