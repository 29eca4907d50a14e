//! Other tools' meshes on the same grid: the grid exported for them, and
//! their meshes measured against it and added to the table.

use super::*;

/// Writes the grid a benchmark of `dem` with `cut` runs on as `.npy`
/// ([`grid::write_npy`]), for the Python peers. Returns its label and heights.
pub fn export_grid(
    dem: &Path,
    cut: Cut,
    config: Option<&Path>,
    npy: &Path,
) -> Result<(String, Heightfield), BenchError> {
    let (label, hf) = cut_grid(dem, cut, &load_options(config)?)?;
    grid::write_npy(&hf, npy)?;
    Ok((label, hf))
}

/// A mesh measured against a grid.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct MeshMeasure {
    /// Triangles in the file.
    pub triangles: usize,
    /// Vertices in the file.
    pub vertices: usize,
    /// Errors.
    #[serde(flatten)]
    pub errors: ErrorStats,
    /// Its triangles' shapes in plan (metres, by the grid's spacing).
    pub shape: ShapeSummary,
}

/// Measures an OBJ mesh (grid units, [`measure::read_obj`]) against `hf`.
pub fn measure_mesh(hf: &Heightfield, obj: &Path) -> Result<MeshMeasure, BenchError> {
    let (verts, tris) = measure::read_obj(obj)?;
    Ok(MeshMeasure {
        triangles: tris.len(),
        vertices: verts.len(),
        errors: measure::mesh_errors(hf, &verts, &tris),
        shape: measure::grid_shape(&verts, &tris, hf.spacing_m),
    })
}

/// Adds the rows of other tools to `out/bench.csv` and redraws the plot.
///
/// `manifest` is a CSV with the header `tool,max_error_m,seconds,runs,mesh`:
/// one line per mesh a peer made, its median seconds over `runs` timed runs
/// and the OBJ file (relative to the manifest) holding the mesh in grid
/// units. Each mesh is measured against the grid of `dem` cut by `cut`,
/// which must be the grid the peer was given.
pub fn import_peers(
    dem: &Path,
    cut: Cut,
    config: Option<&Path>,
    manifest: &Path,
    out: &Path,
) -> Result<Vec<Row>, BenchError> {
    let text = std::fs::read_to_string(manifest).map_err(|source| BenchError::Io { path: manifest.into(), source })?;
    let (label, hf) = cut_grid(dem, cut, &load_options(config)?)?;
    let bad =
        |n: usize, what: &str| BenchError::Input { path: manifest.into(), what: format!("line {}: {what}", n + 1) };
    let mut lines = text.lines().enumerate();
    if lines.next().map(|l| l.1.trim()) != Some("tool,max_error_m,seconds,runs,mesh") {
        return Err(bad(0, "header must be tool,max_error_m,seconds,runs,mesh"));
    }
    let dir = manifest.parent().unwrap_or(Path::new("."));
    let mut rows = Vec::new();
    for (n, line) in lines.filter(|l| !l.1.trim().is_empty()) {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 5 {
            return Err(bad(n, "expected 5 fields"));
        }
        let max_error_m: f64 = f[1].parse().map_err(|_| bad(n, "bad max_error_m"))?;
        let seconds: f64 = f[2].parse().map_err(|_| bad(n, "bad seconds"))?;
        let runs: usize = f[3].parse().map_err(|_| bad(n, "bad runs"))?;
        let m = measure_mesh(&hf, &dir.join(f[4]))?;
        eprintln!(
            "{} {} at {max_error_m} m: {} triangles, measured max error {:.4} m (RMS {:.4}), median {seconds:.3} s",
            f[0], label, m.triangles, m.errors.max_error_m, m.errors.rms_error_m
        );
        let mut secs = [None; 7];
        secs[2] = Some(seconds);
        secs[6] = Some(seconds);
        rows.push(
            Row {
                tool: table::clean(f[0]),
                dem: label.clone(),
                width: hf.width,
                height: hf.height,
                samples: hf.width * hf.height,
                max_error_m,
                levels: Some(1),
                chunks: Some(1),
                triangles: Some(m.triangles),
                leaf_triangles: Some(m.triangles),
                vertices: Some(m.vertices),
                measured_max_error_m: Some(m.errors.max_error_m),
                measured_rms_error_m: Some(m.errors.rms_error_m),
                uncovered_samples: Some(m.errors.uncovered_samples),
                seconds: secs,
                runs,
                threads: 1,
                ..Row::default()
            }
            .with_shape(&m.shape),
        );
    }
    std::fs::create_dir_all(out).map_err(|source| BenchError::Io { path: out.into(), source })?;
    table::write(&out.join("bench.csv"), &rows, true)?;
    #[cfg(feature = "plots")]
    replot(out)?;
    Ok(rows)
}
