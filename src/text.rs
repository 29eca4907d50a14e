//! What `verify` prints: [`VerifyReport`] as a table. The command only
//! prints it (`inspect`'s text is [`crate::verify::Inspection`]).

use std::fmt;

use crate::verify::VerifyReport;

impl fmt::Display for VerifyReport {
    /// The per-level table, the texture table where there are textures, and
    /// `OK` or one `FAIL` line per failure.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = self;
        writeln!(
            f,
            "{:>5} {:>7} {:>10} {:>12} {:>13} {:>11} {:>10} {:>10}",
            "level", "chunks", "δ (m)", "max err (m)", "morph gap (m)", "triangles", "slivers %", "min angle"
        )?;
        for (l, c) in &r.levels {
            let s = &c.shape;
            let share = if s.triangles == 0 { 0.0 } else { 100.0 * s.slivers as f64 / s.triangles as f64 };
            writeln!(
                f,
                "{l:>5} {:>7} {:>10.4} {:>12.4} {:>13.2e} {:>11} {:>10.3} {:>9.2}°",
                c.chunks, c.delta_m, c.max_error_m, c.max_morph_gap_m, s.triangles, share, s.min_angle_deg
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
        if r.curved {
            writeln!(
                f,
                "on the globe: curved; each error above is a sample's distance from the surface as a client \
                 places it, along the ellipsoid normal"
            )?;
        } else if let Some(e) = &r.flat_frame_error {
            writeln!(
                f,
                "on the globe: the planar tileset is drawn up to {:.3} m along the ellipsoid normal and {:.3} m \
                 across it from its samples' places (row {}, column {})",
                e.vertical_m, e.horizontal_m, e.at[0], e.at[1]
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
