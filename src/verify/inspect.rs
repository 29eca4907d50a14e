//! `inspect`: one chunk file summarised for a person (level, δ, footprint,
//! counts, bounds, morph range, texture), from the same reader `verify`
//! uses. Values that are not finite are counted and named, never folded
//! into bounds that would then look finite.

use std::fmt;
use std::path::Path;

use super::VerifyError;
use super::read::{ChunkFile, read_chunk};

/// What `inspect` prints about one chunk.
#[derive(Clone, Debug)]
pub struct Inspection {
    /// The chunk as read.
    pub chunk: ChunkFile,
    /// Lowest and highest world position per axis over the finite
    /// positions (surface and skirt), metres; `None` when none is finite.
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Positions (surface and skirt) with a NaN or infinite coordinate.
    pub non_finite_positions: usize,
    /// Lowest and highest finite morph delta, metres.
    pub morph_dy: Option<(f64, f64)>,
    /// Morph deltas that are NaN or infinite.
    pub non_finite_morph: usize,
}

/// Reads the chunk file at `path` (see [`read_chunk`]) and summarises it.
pub fn inspect(path: &Path) -> Result<Inspection, VerifyError> {
    Ok(Inspection::of(read_chunk(path)?))
}

impl Inspection {
    /// The summary of a chunk already read.
    pub fn of(chunk: ChunkFile) -> Self {
        let prims = || std::iter::once(&chunk.surface).chain(chunk.skirt.as_ref());
        let mut bounds: Option<([f64; 3], [f64; 3])> = None;
        let mut non_finite_positions = 0;
        for p in prims().flat_map(|p| &p.positions) {
            if !p.iter().all(|v| v.is_finite()) {
                non_finite_positions += 1;
                continue;
            }
            let (lo, hi) = bounds.get_or_insert((*p, *p));
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let mut morph_dy: Option<(f64, f64)> = None;
        let mut non_finite_morph = 0;
        for &d in prims().flat_map(|p| &p.morph_dy) {
            if !d.is_finite() {
                non_finite_morph += 1;
                continue;
            }
            let (lo, hi) = morph_dy.get_or_insert((d, d));
            (*lo, *hi) = (lo.min(d), hi.max(d));
        }
        Inspection { chunk, bounds, non_finite_positions, morph_dy, non_finite_morph }
    }
}

impl fmt::Display for Inspection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.chunk;
        writeln!(f, "chunk      {}", super::name(c.key))?;
        writeln!(f, "delta_m    {}", c.delta_m)?;
        let [x0, x1, z0, z1] = c.footprint;
        writeln!(f, "footprint  columns {x0}..={x1}, rows {z0}..={z1}")?;
        writeln!(f, "surface    {} vertices, {} triangles", c.surface.positions.len(), c.surface.triangles.len())?;
        if let Some(s) = &c.skirt {
            writeln!(f, "skirt      {} vertices, {} triangles", s.positions.len(), s.triangles.len())?;
        }
        match self.bounds {
            Some((lo, hi)) => writeln!(
                f,
                "bounds     x {:.3}..{:.3}  y {:.3}..{:.3}  z {:.3}..{:.3} (m){}",
                lo[0],
                hi[0],
                lo[1],
                hi[1],
                lo[2],
                hi[2],
                if self.non_finite_positions > 0 { " of the finite positions" } else { "" }
            )?,
            None => writeln!(f, "bounds     none: no position is finite")?,
        }
        if self.non_finite_positions > 0 {
            writeln!(f, "NOT FINITE {} positions (NaN or infinite)", self.non_finite_positions)?;
        }
        match self.morph_dy {
            Some((lo, hi)) => writeln!(f, "morph dy   {lo:.4}..{hi:.4} m")?,
            None => writeln!(f, "morph dy   none finite")?,
        }
        if self.non_finite_morph > 0 {
            writeln!(f, "NOT FINITE {} morph deltas (NaN or infinite)", self.non_finite_morph)?;
        }
        if let Some(t) = &c.texture {
            let spacing = |a: usize| {
                let cells = f64::from(c.footprint[2 * a + 1] - c.footprint[2 * a]);
                cells * c.spacing_m[a] / f64::from([t.colour.width, t.colour.height][a] - 1)
            };
            writeln!(
                f,
                "texture    {} × {} texels ({}), T_g {:.4} × {:.4} m",
                t.colour.width,
                t.colour.height,
                t.colour.mime,
                spacing(0),
                spacing(1)
            )?;
            if let Some((n, set)) = &t.normal {
                writeln!(f, "normal map {} × {} texels (TEXCOORD_{set})", n.width, n.height)?;
            }
        }
        Ok(())
    }
}
