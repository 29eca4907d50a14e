//! What `verify` and `inspect` print: [`VerifyReport`] as a table, one
//! chunk file as [`Inspection`]. The command only prints them.

use std::fmt;

use crate::verify::{ChunkFile, VerifyReport};

impl fmt::Display for VerifyReport {
    /// The per-level table, the texture table where there are textures, and
    /// `OK` or one `FAIL` line per failure.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = self;
        writeln!(f, "{:>5} {:>7} {:>10} {:>12} {:>12}", "level", "chunks", "δ (m)", "max err (m)", "morph gap (m)")?;
        for (l, c) in &r.levels {
            writeln!(
                f,
                "{l:>5} {:>7} {:>10.4} {:>12.4} {:>12.2e}",
                c.chunks, c.delta_m, c.max_error_m, c.max_morph_gap_m
            )?;
        }
        writeln!(f, "{} shared borders compared", r.borders_checked)?;
        if let Some(t) = &r.texture {
            writeln!(
                f,
                "{:>5} {:>7} {:>10} {:>10} {:>21} {:>18}",
                "level", "chunks", "T_g (m)", "δ/τ (m)", "over δ/τ: at source", "capped (stated)"
            )?;
            for (l, c) in &t.levels {
                writeln!(
                    f,
                    "{l:>5} {:>7} {:>10.4} {:>10.4} {:>21} {:>18}",
                    c.chunks, c.texel_m, c.bound_m, c.at_source, c.capped
                )?;
            }
            writeln!(
                f,
                "{} texture seams compared, border texels differ by up to {} (allowed {}), RMS {:.2} (allowed {:.2})",
                t.seams_checked, t.max_seam_diff, t.seam_tolerance, t.max_seam_rms, t.seam_rms_tolerance
            )?;
        }
        for s in &r.slivers {
            writeln!(f, "promise 8 not kept: {s}")?;
        }
        if r.failures.is_empty() {
            writeln!(f, "OK")?;
        }
        for failure in &r.failures {
            writeln!(f, "FAIL {failure}")?;
        }
        Ok(())
    }
}

/// One chunk file's level, δ, footprint, counts, bounds, morph range and
/// texture, as `terrachunk inspect` prints them.
pub struct Inspection<'a>(
    /// The chunk file, as `verify::read_chunk` reads it.
    pub &'a ChunkFile,
);

impl fmt::Display for Inspection<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = self.0;
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for p in c.surface.positions.iter().chain(c.skirt.iter().flat_map(|s| &s.positions)) {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let dys = c.surface.morph_dy.iter().chain(c.skirt.iter().flat_map(|s| &s.morph_dy));
        let (mlo, mhi) = dys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &d| (a.min(d), b.max(d)));
        writeln!(f, "chunk      {}/{}/{}", c.key.level, c.key.x, c.key.y)?;
        writeln!(f, "delta_m    {}", c.delta_m)?;
        writeln!(
            f,
            "footprint  columns {}..={}, rows {}..={}",
            c.footprint[0], c.footprint[1], c.footprint[2], c.footprint[3]
        )?;
        writeln!(f, "surface    {} vertices, {} triangles", c.surface.positions.len(), c.surface.triangles.len())?;
        if let Some(s) = &c.skirt {
            writeln!(f, "skirt      {} vertices, {} triangles", s.positions.len(), s.triangles.len())?;
        }
        writeln!(
            f,
            "bounds     x {:.3}..{:.3}  y {:.3}..{:.3}  z {:.3}..{:.3} (m)",
            lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
        )?;
        writeln!(f, "morph dy   {mlo:.4}..{mhi:.4} m")?;
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
