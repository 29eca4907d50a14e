//! Promise 9 for tilesets written in the curved frame: every DEM sample's
//! true WGS 84 position within δ of its chunk's surface as a 3D Tiles
//! client places it, measured along the ellipsoid normal at the sample.
//!
//! Nothing here reads how the build bent the chunks. Each vertex as
//! written (node translation + POSITION) goes through the file's own root
//! transform to ECEF, back to latitude, longitude and height, and through
//! the DEM's CRS to grid coordinates: the chunk in grid space, on which
//! the planar checks (coverage, borders, textures, shapes) run as for a
//! flat tileset. The error is then taken in ECEF, sample by sample, from
//! the sample's true position (the DEM's georeference and height) to the
//! plane of the written triangle that holds it in grid space; a morph
//! target must lie on the parent's written triangle at the grid point of
//! its vertex.

use serde_json::Value;

use super::read::{ChunkFile, Prim};
use crate::geodesy::{SourceCrs, ecef, geodetic, up};
use crate::heightfield::Heightfield;
use crate::mesh::locate::points_near_triangle;

/// The map from written positions to ECEF and grid, from the tileset's
/// root transform and the DEM's georeference.
pub(crate) struct Curved {
    transform: [f64; 16],
    source: SourceCrs,
    origin: [f64; 2],
    step: [f64; 2],
    pub(super) spacing: [f64; 2],
    /// The DEM's degrees are WGS 84's (no datum shift at its centre).
    degrees: bool,
}

/// A chunk's written surface in ECEF: its vertices, their morph targets,
/// and how far f32 rounding may have moved either.
pub(crate) struct CurvedChunk {
    pub(super) surface: Vec<[f64; 3]>,
    pub(super) targets: Vec<[f64; 3]>,
    /// The ellipsoid's up at each written vertex, in the chunk's axes: the
    /// surface's, then the skirt's.
    pub(super) ups: [Vec<[f64; 3]>; 2],
    pub(super) rounding_m: f64,
}

impl Curved {
    /// The map of a tileset whose extras say it is curved; `Ok(None)` for a
    /// flat one, `Err` where the curved tileset cannot be checked.
    pub(crate) fn of(ts: &Value, hf: &Heightfield) -> Result<Option<Curved>, String> {
        if ts["extras"]["terrachunk"]["placement"]["frame"] != "curved" {
            return Ok(None);
        }
        let t: Vec<f64> = ts["root"]["transform"]
            .as_array()
            .map_or(Vec::new(), |a| a.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect());
        let transform: [f64; 16] =
            t.try_into().map_err(|_| "a curved tileset's root tile has no transform of 16 numbers".to_string())?;
        let source = SourceCrs::of(&hf.georef.crs, hf.georef.definition.as_deref())
            .map_err(|e| format!("a curved tileset, but the DEM cannot be placed: {e}"))?;
        let (origin, step) = (hf.georef.origin, hf.georef.step);
        let centre = [0, 1].map(|a| origin[a] + step[a] * ([hf.width, hf.height][a] - 1) as f64 / 2.0);
        let degrees = source.geographic
            && source
                .to_wgs84(centre)
                .is_some_and(|(lat, lon)| (lat - centre[1]).abs() < 1e-9 && (lon - centre[0]).abs() < 1e-9);
        Ok(Some(Curved { transform, source, origin, step, spacing: hf.spacing_m, degrees }))
    }

    /// ECEF of a world (glTF y-up) position, through the root transform.
    fn ecef(&self, w: [f64; 3]) -> [f64; 3] {
        let p = [w[0], -w[2], w[1]];
        let t = &self.transform;
        [0, 1, 2].map(|r| t[r] * p[0] + t[4 + r] * p[1] + t[8 + r] * p[2] + t[12 + r])
    }

    /// The ellipsoid's up at a latitude and longitude, in the chunks' (glTF
    /// y-up) axes: the root transform's rotation taken back (its columns
    /// are orthonormal, east-north-up at the grid's centre).
    fn up_in_chunk(&self, lat: f64, lon: f64) -> [f64; 3] {
        let u = up(lat, lon);
        let t = &self.transform;
        let col = |c: usize| t[4 * c] * u[0] + t[4 * c + 1] * u[1] + t[4 * c + 2] * u[2];
        let (x, y, z) = (col(0), col(1), col(2));
        let len = (x * x + y * y + z * z).sqrt();
        [x / len, z / len, -y / len]
    }

    /// Grid column and row of a latitude and longitude in the chunk whose
    /// middle column is `middle`.
    fn grid_of(&self, lat: f64, lon: f64, middle: f64) -> Option<[f64; 2]> {
        let mut src = self.source.from_wgs84(lat, lon)?;
        if self.source.geographic {
            // The longitude within half a turn of the chunk's middle, across
            // the antimeridian too: a grid of degrees may be wider than half
            // a turn, a chunk no wider than a turn.
            let mid = self.origin[0] + self.step[0] * middle;
            src[0] = mid + (src[0] - mid + 180.0).rem_euclid(360.0) - 180.0;
        }
        Some([(src[0] - self.origin[0]) / self.step[0], (src[1] - self.origin[1]) / self.step[1]])
    }

    /// The true ECEF position and ellipsoid normal of sample (`i`, `j`) at
    /// height `h`.
    fn sample(&self, i: usize, j: usize, h: f64) -> Option<([f64; 3], [f64; 3])> {
        let src = [self.origin[0] + self.step[0] * j as f64, self.origin[1] + self.step[1] * i as f64];
        let (lat, lon) = if self.degrees { (src[1], src[0]) } else { self.source.to_wgs84(src)? };
        Some((ecef(lat, lon, h), up(lat, lon)))
    }

    /// The chunk in grid space (positions column · s_x, height, row · s_z,
    /// whole indices where the rounding allows; no morph deltas, which
    /// [`super::morph::check_curved_morph`] checks instead) and its surface in ECEF.
    pub(crate) fn unbend(&self, c: &ChunkFile) -> Result<(ChunkFile, CurvedChunk), String> {
        let rounding = |p: &Prim| 4.0 * f64::from(f32::EPSILON) * p.local_extent.iter().fold(1.0f64, |m, v| m.max(*v));
        let mut flat = c.clone();
        let mut surface = Vec::new();
        let mut targets = Vec::new();
        let rounding_m = std::iter::once(&c.surface).chain(&c.skirt).map(rounding).fold(0.0, f64::max);
        let snap = 1e-6 + 4.0 * rounding_m / self.spacing[0].min(self.spacing[1]);
        let middle = f64::from(c.footprint[0] + c.footprint[1]) / 2.0;
        let mut ups = [Vec::new(), Vec::new()];
        for ((written, prim, is_surface), ups) in std::iter::once((&c.surface, &mut flat.surface, true))
            .chain(c.skirt.iter().zip(flat.skirt.as_mut()).map(|(w, f)| (w, f, false)))
            .zip(&mut ups)
        {
            for (k, p) in written.positions.iter().enumerate() {
                let e = self.ecef(*p);
                let (lat, lon, h) = geodetic(e);
                ups.push(self.up_in_chunk(lat, lon));
                let [j, i] = self
                    .grid_of(lat, lon, middle)
                    .ok_or_else(|| format!("a vertex at {p:?} is nowhere on the grid"))?;
                let whole = |v: f64| if (v - v.round()).abs() <= snap { v.round() } else { v };
                prim.positions[k] = [whole(j) * self.spacing[0], h, whole(i) * self.spacing[1]];
                if is_surface {
                    let d = [written.morph_dxz_at(k)[0], written.morph_dy[k], written.morph_dxz_at(k)[1]];
                    surface.push(e);
                    targets.push(self.ecef([0, 1, 2].map(|a| p[a] + d[a])));
                }
            }
            prim.morph_dy = vec![0.0; prim.positions.len()];
            prim.morph_xz.clear();
        }
        // The planar checks must not hold the grid-space heights, read back
        // through the Earth's curvature, to δ: the error is taken in ECEF.
        flat.delta_m = f64::INFINITY;
        Ok((flat, CurvedChunk { surface, targets, ups, rounding_m }))
    }

    /// Per sample of the footprint (row-major, INFINITY where no triangle
    /// holds it or it is nodata), the distance along the ellipsoid normal
    /// from its true position to the plane of the written triangle holding
    /// it in grid space (the nearest, where it lies on an edge); and how
    /// many samples are nowhere on the Earth. `None` where the footprint
    /// leaves the grid.
    pub(crate) fn sample_errors(
        &self,
        hf: &Heightfield,
        flat: &ChunkFile,
        bent: &CurvedChunk,
    ) -> Option<(Vec<f64>, usize)> {
        let [x0, x1, z0, z1] = flat.footprint;
        if x1 as usize >= hf.width || z1 as usize >= hf.height {
            return None;
        }
        let w = (x1 - x0 + 1) as usize;
        // Each sample's true place is worked out again for each triangle
        // near it (a sample on an edge twice): held for a whole top chunk
        // it would take 56 bytes a sample.
        let mut best = vec![f64::INFINITY; w * (z1 - z0 + 1) as usize];
        let verts = flat.surface.grid_vertices(self.spacing);
        let mut lost = 0usize;
        for t in &flat.surface.triangles {
            let tri = t.map(|i| verts[i as usize]);
            let [a, b, c] = t.map(|i| bent.surface[i as usize]);
            let n = cross(sub(b, a), sub(c, a));
            let (zlo, zhi) = (tri[0].z.min(tri[1].z).min(tri[2].z), tri[0].z.max(tri[1].z).max(tri[2].z));
            let (xlo, xhi) = (tri[0].x.min(tri[1].x).min(tri[2].x), tri[0].x.max(tri[1].x).max(tri[2].x));
            let rows = ((zlo - 1e-4).ceil().max(f64::from(z0)), (zhi + 1e-4).floor().min(f64::from(z1)));
            let cols = ((xlo - 1e-4).ceil().max(f64::from(x0)), (xhi + 1e-4).floor().min(f64::from(x1)));
            points_near_triangle(&tri, rows, cols, 1e-4, |i, j, _| {
                let s = hf.get(i, j);
                if s.is_nan() {
                    return;
                }
                let at = (i - z0 as usize) * w + (j - x0 as usize);
                let Some((p, u)) = self.sample(i, j, f64::from(s)) else {
                    lost += 1;
                    return;
                };
                let along = dot(n, u);
                if along.abs() <= 1e-12 * dot(n, n).sqrt() {
                    return; // a wall seen edge-on: its neighbours hold the sample
                }
                let e = (dot(n, sub(a, p)) / along).abs();
                best[at] = best[at].min(e);
            });
        }
        Some((best, lost))
    }

    /// The largest of [`Curved::sample_errors`] over the footprint's valid
    /// samples; records it against `delta_m`.
    pub(super) fn check_error(
        &self,
        hf: &Heightfield,
        flat: &ChunkFile,
        bent: &CurvedChunk,
        delta_m: f64,
        problems: &mut Vec<String>,
    ) -> f64 {
        let Some((best, lost)) = self.sample_errors(hf, flat, bent) else { return f64::INFINITY };
        if lost > 0 {
            problems.push(format!("{lost} samples are nowhere on the Earth in the DEM's CRS"));
        }
        let worst = best.iter().copied().filter(|e| e.is_finite()).fold(0.0, f64::max);
        if worst > delta_m + bent.rounding_m {
            problems.push(format!(
                "error {worst:.4} m along the ellipsoid normal (the surface as a client places it) exceeds δ {delta_m} m"
            ));
        }
        worst
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
