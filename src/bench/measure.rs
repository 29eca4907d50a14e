//! Measure: the true vertical error of a mesh against the DEM, taken from the
//! mesh alone, whoever made it.
//!
//! Every triangle is rasterised back onto the sample grid: each valid sample
//! it covers (within 1e-4 grid units, the f32 rounding of written
//! positions) gets |interpolated height − sample|, keeping, as `verify`
//! does, the smallest value among the triangles that cover it (on a shared
//! edge they agree; a zero-width sliver must not count a vertex it merely
//! touches). The same scan measures terrachunk's leaf chunks read back from
//! their `.glb` files ([`leaf_errors`]) and a peer's mesh given as an OBJ
//! file ([`read_obj`], [`mesh_errors`]), so every tool is judged by one
//! checker and not by its own claim.

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;
use serde_json::Value;

use crate::heightfield::Heightfield;
use crate::mesh::MeshVertex;
use crate::mesh::locate::barycentric;
use crate::mesh::quality::{self, ShapeSummary};
use crate::verify::read_chunk;

use super::BenchError;

/// Errors of a mesh against the DEM's valid samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Largest |surface − sample| over the covered valid samples, metres.
    pub max_error_m: f64,
    /// Root mean square of |surface − sample| over the covered valid samples, metres.
    pub rms_error_m: f64,
    /// Valid samples measured (each counted once).
    pub samples: usize,
    /// Valid samples no triangle covers (0 for a mesh of the whole grid).
    pub uncovered_samples: usize,
}

/// Partial sums that merge across chunks.
#[derive(Clone, Copy, Debug, Default)]
pub struct ErrorSum {
    max: f64,
    sum_sq: f64,
    count: usize,
    uncovered: usize,
}

impl ErrorSum {
    /// Both parts together.
    pub fn merge(self, o: ErrorSum) -> ErrorSum {
        ErrorSum {
            max: self.max.max(o.max),
            sum_sq: self.sum_sq + o.sum_sq,
            count: self.count + o.count,
            uncovered: self.uncovered + o.uncovered,
        }
    }

    /// The statistics.
    pub fn stats(&self) -> ErrorStats {
        ErrorStats {
            max_error_m: self.max,
            rms_error_m: if self.count == 0 { 0.0 } else { (self.sum_sq / self.count as f64).sqrt() },
            samples: self.count,
            uncovered_samples: self.uncovered,
        }
    }
}

/// A closed rectangle of samples: columns `x0..=x1`, rows `z0..=z1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// First column.
    pub x0: u32,
    /// Last column.
    pub x1: u32,
    /// First row.
    pub z0: u32,
    /// Last row.
    pub z1: u32,
}

impl Window {
    /// The whole grid.
    pub fn all(hf: &Heightfield) -> Self {
        Window { x0: 0, x1: hf.width as u32 - 1, z0: 0, z1: hf.height as u32 - 1 }
    }

    fn contains(&self, i: u32, j: u32) -> bool {
        (self.z0..=self.z1).contains(&i) && (self.x0..=self.x1).contains(&j)
    }
}

/// Rasterises `tris` (vertices in grid units: column `x`, row `z`, height
/// `h` in metres) over `window`. The maximum is taken over every covered
/// valid sample of `window`; the RMS and the uncovered count only over
/// those in `owned` (inside `window`), so that chunks sharing a border count
/// its samples once.
pub fn scan(hf: &Heightfield, verts: &[MeshVertex], tris: &[[u32; 3]], window: Window, owned: Window) -> ErrorSum {
    let Window { x0, x1, z0, z1 } = window;
    let w = (x1 - x0 + 1) as usize;
    let mut best = vec![f64::INFINITY; w * (z1 - z0 + 1) as usize];
    for t in tris {
        let [a, b, c] = t.map(|i| verts[i as usize]);
        let (zlo, zhi) = (a.z.min(b.z).min(c.z), a.z.max(b.z).max(c.z));
        let (xlo, xhi) = (a.x.min(b.x).min(c.x), a.x.max(b.x).max(c.x));
        let (ilo, ihi) = ((zlo - 1e-4).ceil().max(f64::from(z0)), (zhi + 1e-4).floor().min(f64::from(z1)));
        let (jlo, jhi) = ((xlo - 1e-4).ceil().max(f64::from(x0)), (xhi + 1e-4).floor().min(f64::from(x1)));
        if ilo > ihi || jlo > jhi {
            continue;
        }
        for i in ilo as u32..=ihi as u32 {
            for j in jlo as u32..=jhi as u32 {
                let s = hf.get(i as usize, j as usize);
                if s.is_nan() {
                    continue;
                }
                let (outside, h) = barycentric(&a, &b, &c, f64::from(j), f64::from(i));
                if outside > 1e-4 {
                    continue;
                }
                let e = &mut best[(i - z0) as usize * w + (j - x0) as usize];
                *e = e.min((h - f64::from(s)).abs());
            }
        }
    }
    sum_owned(hf, &best, window, owned)
}

/// [`ErrorSum`] of per-sample errors `best` over `window` (row-major,
/// INFINITY where no triangle holds a sample): the largest over the
/// window, the RMS and uncovered count over the samples it `owned`.
fn sum_owned(hf: &Heightfield, best: &[f64], window: Window, owned: Window) -> ErrorSum {
    let Window { x0, x1, z0, z1 } = window;
    let w = (x1 - x0 + 1) as usize;
    let mut sum = ErrorSum::default();
    for i in z0..=z1 {
        for j in x0..=x1 {
            if hf.get(i as usize, j as usize).is_nan() {
                continue;
            }
            let e = best[(i - z0) as usize * w + (j - x0) as usize];
            let mine = owned.contains(i, j);
            if e.is_finite() {
                sum.max = sum.max.max(e);
                if mine {
                    sum.sum_sq += e * e;
                    sum.count += 1;
                }
            } else if mine {
                sum.uncovered += 1;
            }
        }
    }
    sum
}

/// The shapes of a mesh in grid units (column, row) over cells of
/// `spacing_m`, in plan metres.
pub fn grid_shape(verts: &[MeshVertex], tris: &[[u32; 3]], spacing_m: [f64; 2]) -> ShapeSummary {
    let plan: Vec<[f64; 2]> = verts.iter().map(|v| [v.x * spacing_m[0], v.z * spacing_m[1]]).collect();
    quality::summarize(&plan, tris)
}

/// Errors of one mesh over the whole grid.
pub fn mesh_errors(hf: &Heightfield, verts: &[MeshVertex], tris: &[[u32; 3]]) -> ErrorStats {
    let all = Window::all(hf);
    scan(hf, verts, tris, all, all).stats()
}

/// What the leaves of a written tileset show.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LeafMeasure {
    /// Chunks without children.
    pub leaves: usize,
    /// Their surface triangles.
    pub leaf_triangles: usize,
    /// Their surface vertices.
    pub leaf_vertices: usize,
    /// Their errors against the DEM (each sample's RMS share counted once:
    /// a border sample belongs to the chunk east or south of it).
    pub errors: ErrorStats,
    /// Their triangles' shapes in plan, as written.
    pub shape: ShapeSummary,
}

/// Reads every leaf chunk (a tile without children in `tileset.json`) of the
/// tileset at `dir` and measures it against `hf`, which must be the grid the
/// tileset was built from.
pub fn leaf_errors(dir: &Path, hf: &Heightfield) -> Result<LeafMeasure, BenchError> {
    let ts_path = dir.join("tileset.json");
    let bad = |what: String| BenchError::Input { path: ts_path.clone(), what };
    // With its external tilesets in place.
    let ts: Value = crate::verify::read_tileset(dir).map_err(|e| bad(e.to_string()))?;
    let extras = &ts["extras"]["terrachunk"];
    let grid = [&extras["grid"]["width"], &extras["grid"]["height"]].map(|v| v.as_u64().unwrap_or(0) as usize);
    if grid != [hf.width, hf.height] {
        return Err(bad(format!("built from a {}×{} grid, not {}×{}", grid[0], grid[1], hf.width, hf.height)));
    }
    let spacing = [&extras["spacing_m"][0], &extras["spacing_m"][1]].map(|v| v.as_f64().unwrap_or(f64::NAN));
    if !spacing.iter().all(|s| s.is_finite() && *s > 0.0) {
        return Err(bad("extras.terrachunk.spacing_m is missing".into()));
    }
    let curved = crate::verify::Curved::of(&ts, hf).map_err(bad)?;
    let mut uris = Vec::new();
    collect_leaves(&ts["root"], &mut uris);
    let (last_x, last_z) = (hf.width as u32 - 1, hf.height as u32 - 1);
    let parts: Vec<Result<(ErrorSum, ShapeSummary, usize), BenchError>> = uris
        .par_iter()
        .map(|uri| {
            let c = read_chunk(&dir.join(uri))?;
            let [x0, x1, z0, z1] = c.footprint;
            if x1 > last_x || z1 > last_z || x0 >= x1 || z0 >= z1 {
                return Err(BenchError::Input {
                    path: dir.join(uri),
                    what: format!("footprint {:?} is outside the grid", c.footprint),
                });
            }
            let window = Window { x0, x1, z0, z1 };
            // A border sample is owned by the chunk east / south of it.
            let owned = Window {
                x1: if x1 == last_x { x1 } else { x1 - 1 },
                z1: if z1 == last_z { z1 } else { z1 - 1 },
                ..window
            };
            // A curved chunk is measured as `verify` measures it: along the
            // ellipsoid normal, from each sample's true place on the Earth.
            let (c, sum) = match &curved {
                None => {
                    let verts = c.surface.grid_vertices(spacing);
                    let sum = scan(hf, &verts, &c.surface.triangles, window, owned);
                    (c, sum)
                }
                Some(cv) => {
                    let input = |what: String| BenchError::Input { path: dir.join(uri), what };
                    let (flat, bent) = cv.unbend(&c).map_err(input)?;
                    let (best, _) = cv
                        .sample_errors(hf, &flat, &bent)
                        .ok_or_else(|| input("its footprint leaves the grid".into()))?;
                    let sum = sum_owned(hf, &best, window, owned);
                    (flat, sum)
                }
            };
            let plan: Vec<[f64; 2]> = c.surface.positions.iter().map(|p| [p[0], p[2]]).collect();
            Ok((sum, quality::summarize(&plan, &c.surface.triangles), c.surface.positions.len()))
        })
        .collect();
    let mut m = LeafMeasure { leaves: uris.len(), ..LeafMeasure::default() };
    let mut sum = ErrorSum::default();
    for p in parts {
        let (s, shape, v) = p?;
        sum = sum.merge(s);
        m.leaf_triangles += shape.triangles;
        m.leaf_vertices += v;
        m.shape = m.shape.merge(shape);
    }
    m.errors = sum.stats();
    Ok(m)
}

fn collect_leaves(tile: &Value, out: &mut Vec<String>) {
    let kids = tile["children"].as_array().filter(|k| !k.is_empty());
    match kids {
        Some(kids) => kids.iter().for_each(|k| collect_leaves(k, out)),
        None => {
            if let Some(uri) = tile["content"]["uri"].as_str() {
                out.push(uri.to_string());
            }
        }
    }
}

/// Reads a mesh from a Wavefront OBJ file in grid units: `v x y z` is column
/// `x`, height `y` in metres and row `z` (the glTF chunks' axes, y up);
/// `f a b c` are 1-based vertex indices (`a/..` forms and polygons, split
/// into fans, are accepted). Other lines are ignored.
pub fn read_obj(path: &Path) -> Result<(Vec<MeshVertex>, Vec<[u32; 3]>), BenchError> {
    let text = std::fs::read_to_string(path).map_err(|source| BenchError::Io { path: path.into(), source })?;
    let bad = |n: usize, what: &str| BenchError::Input { path: path.into(), what: format!("line {}: {what}", n + 1) };
    let (mut verts, mut faces) = (Vec::new(), Vec::new());
    for (n, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f64> =
                    it.take(3).map(str::parse).collect::<Result<_, _>>().map_err(|_| bad(n, "bad number"))?;
                if c.len() != 3 || !c.iter().all(|v| v.is_finite()) {
                    return Err(bad(n, "a vertex needs three finite coordinates"));
                }
                verts.push(MeshVertex { x: c[0], h: c[1], z: c[2], ph: c[1] });
            }
            Some("f") => {
                let idx: Vec<u32> = it
                    .map(|t| t.split('/').next().unwrap_or("").parse::<u32>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| bad(n, "face indices must be positive integers"))?;
                if idx.len() < 3 {
                    return Err(bad(n, "a face needs three vertices"));
                }
                for k in 1..idx.len() - 1 {
                    faces.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    let n = verts.len() as u32;
    let mut tris = Vec::with_capacity(faces.len());
    for f in faces {
        if f.iter().any(|&i| i == 0 || i > n) {
            return Err(BenchError::Input {
                path: path.into(),
                what: format!("face {f:?} refers to a vertex outside 1..={n}"),
            });
        }
        tris.push(f.map(|i| i - 1));
    }
    Ok((verts, tris))
}
