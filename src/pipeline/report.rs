//! What a build tells its user: the figures of [`Report`] (also written as
//! JSON with `--report`), and the summary the command prints
//! ([`Report::summary`], [`Report::over_delta_warning`]).

use std::path::{Path, PathBuf};

use serde::Serialize;

#[cfg(doc)]
use crate::quadtree::estimate::Estimate;

/// Per-level figures of a build.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelReport {
    /// Level.
    pub level: u32,
    /// δ(L), metres.
    pub delta_m: f64,
    /// Chunks written.
    pub chunks: usize,
    /// Surface triangles.
    pub triangles: usize,
    /// Skirt triangles.
    pub skirt_triangles: usize,
    /// Surface vertices.
    pub vertices: usize,
    /// Largest measured error of any chunk of the level, metres.
    pub max_error_m: f64,
    /// Chunks of this level that have no children (already within max_error).
    pub leaves: usize,
    /// Bytes of the level's .glb files.
    pub bytes: u64,
    /// The level's texture tiles (absent when untextured).
    pub texture: Option<LevelTexture>,
}

/// Per-level figures of the texture tiles.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelTexture {
    /// Largest T_g (texel spacing on the ground, either axis) of the level's
    /// chunks, metres.
    pub texel_m: f64,
    /// δ(L)/τ_max, metres: the bound T_g should keep.
    pub bound_m: f64,
    /// Chunks whose tile the bound sized (T_g ≤ δ/τ_max, power of two).
    pub limited_by_bound: usize,
    /// Chunks whose tile the source's resolution stopped (as fine as the source).
    pub limited_by_source: usize,
    /// Chunks whose tile `max_texture_px` stopped.
    pub limited_by_cap: usize,
    /// Chunks with T_g > δ/τ_max.
    pub over_bound: usize,
    /// Largest tile, texels `[across, down]`.
    pub largest: [u32; 2],
    /// Texels written, all chunks of the level (colour only).
    pub texels: u64,
    /// Bytes of encoded images (colour and normal map) in the level's .glb files.
    pub texture_bytes: u64,
}

/// What a build did and cost.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    /// Input samples (width × height).
    pub samples: usize,
    /// Samples holding data.
    pub valid_samples: usize,
    /// Grid size.
    pub grid: [usize; 2],
    /// Spacing, metres.
    pub spacing_m: [f64; 2],
    /// Levels by level.
    pub levels: Vec<LevelReport>,
    /// Bytes written (all .glb plus tileset.json).
    pub bytes: u64,
    /// Bytes per input sample.
    pub bytes_per_sample: f64,
    /// Wall seconds per stage: load, plan, texture source, chunks (mesh,
    /// skirt, morph, texture, write), index.
    pub seconds: StageTimes,
    /// Thread-seconds spent inside each per-chunk stage (summed over threads).
    pub thread_seconds: ChunkStageTimes,
    /// Peak resident memory, bytes, if known: Linux VmHWM, or more where
    /// the memory limit's own looks saw more (VmHWM misses mapped pages
    /// dropped before the kernel updates it).
    pub peak_rss_bytes: Option<u64>,
    /// The memory limit the build kept to, bytes (`None`: no limit).
    pub memory_limit_bytes: Option<u64>,
    /// Bytes of whole-grid arrays kept in mapped scratch files, past the
    /// limit's share ([`crate::store`]); 0 when all fit in memory.
    pub scratch_bytes: u64,
    /// Index files written: `tileset.json` and the external tilesets it
    /// refers to (more than one where the tree has more than
    /// `index_tiles` tiles).
    pub index_files: usize,
    /// Threads used.
    pub threads: usize,
    /// Levels added at the bottom (same footprint, half the δ) so that the
    /// coarser chunks fit `max_chunk_vertices`.
    pub refine_levels: u32,
    /// Of `refine_levels`, those taken from the estimate alone (a top chunk
    /// surely too dense with fewer: [`Estimate::refine_levels`]), not from
    /// an attempt.
    pub refine_estimated: u32,
    /// Wall seconds of the attempts with fewer refine levels that stopped at
    /// a chunk too dense for `max_chunk_vertices` (part of `seconds.chunks`).
    pub discarded_s: f64,
    /// The bound on a deepest-level chunk's width, in cells (set, or chosen
    /// from the data).
    pub leaf_cells: u32,
    /// The widest deepest-level chunk, in cells (at most `leaf_cells`: the
    /// tree halves the grid, so California's 8 400 cells with `leaf_cells =
    /// 256` make leaves of 131 × 150).
    pub leaf_width_cells: u32,
    /// The top-level footprints' count (those with no valid sample
    /// included: they make no chunk) and the widest, in cells (one unless
    /// the grid is elongated or `root_cells` is set).
    pub roots: (usize, u32),
    /// The top-level chunks are narrower than `root_cells` asks (or than
    /// the grid) because the grid's last column or row is off the
    /// bintree's coarse lines ([`crate::mesh::rtin::fitting_root`]).
    pub roots_narrowed: bool,
    /// Quantized output: chunks meshed again with a wider margin next to
    /// cut points, so that rounding those sideways to the grid keeps δ.
    pub remeshed_for_cut_points: usize,
    /// Quantized output: chunks that miss δ as written even with no error
    /// left next to their cut points (each written at the margin that came
    /// closest; `verify` reports them).
    pub over_delta_as_written: Vec<OverDelta>,
    /// Why a georeferenced grid got no root transform (its CRS is not
    /// named, not known, or not one the projection library can invert);
    /// absent when it was placed or the file has no georeference at all.
    pub not_placed: Option<String>,
    /// How far the root transform draws the planar grid from its place on
    /// the ellipsoid (placed grids only).
    pub flat_frame_error: Option<crate::geodesy::FlatFrameError>,
    /// The frame the chunks are written in (`config::Frame`).
    pub frame: crate::geodesy::FrameKind,
}

/// A chunk whose error as written is beyond its δ.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct OverDelta {
    /// `L/x/y`.
    pub chunk: String,
    /// Its error as written, metres.
    pub error_m: f64,
    /// Its level's δ, metres.
    pub delta_m: f64,
}

/// Wall time per pipeline stage, seconds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StageTimes {
    /// Reading the DEM.
    pub load: f64,
    /// Void fill and tree plan (the leaf width and refine levels
    /// [`Estimate`] measures on sample windows).
    pub plan: f64,
    /// Loading or generating the texture source. A generated one is made
    /// while the plan runs, so the two overlap (`total` is wall time).
    pub texture_source: f64,
    /// All chunks: mesh, skirt, morph, encode, write.
    pub chunks: f64,
    /// tileset.json and the final rename.
    pub index: f64,
    /// Everything.
    pub total: f64,
}

/// Thread-seconds per per-chunk stage.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ChunkStageTimes {
    /// Greedy insertion.
    pub mesh: f64,
    /// Normals, morph targets and skirts.
    pub skirt_morph: f64,
    /// Quantized output only: each chunk measured again as it will be
    /// written ([`crate::output::compress::Quantization::cut_error`]).
    pub check: f64,
    /// Resampling and encoding texture tiles.
    pub texture: f64,
    /// glTF encoding and file writes.
    pub write: f64,
}

impl Report {
    /// The memory figures at the end of a build: the peak (the larger of
    /// VmHWM and the memory limit's own looks, since VmHWM misses mapped
    /// pages dropped before the kernel next updates it), the limit and
    /// what went to scratch files.
    pub(crate) fn record_memory(&mut self, memory: Option<&crate::store::Memory>) {
        self.peak_rss_bytes = peak_rss().max(memory.map(crate::store::Memory::most_resident_bytes).filter(|&b| b > 0));
        self.memory_limit_bytes = memory.map(crate::store::Memory::limit);
        self.scratch_bytes = memory.map_or(0, crate::store::Memory::mapped_bytes);
    }
}

/// Peak resident set size of this process, bytes (Linux only).
pub fn peak_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Why the report cannot be written where `--report` says.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The path cannot take a file: no folder, not writable, not a regular file.
    #[error("{path}: cannot write the report there: {why}")]
    Path {
        /// The report path.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// The path is one of the build's inputs.
    #[error("{path}: is an input of the build; write the report to another file")]
    Input {
        /// The report path.
        path: PathBuf,
    },
    /// Writing failed.
    #[error("{path}: cannot write the report: {source}")]
    Io {
        /// The report path.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

impl Report {
    /// Checks, before a build, that a report can be written at `path`: its
    /// folder exists and takes a new file, it is no input, and what is
    /// there already is a regular file (never a folder, a device or a link).
    pub fn check_path(path: &Path, inputs: &[PathBuf]) -> Result<(), ReportError> {
        let bad = |why: &str| ReportError::Path { path: path.into(), why: why.into() };
        match std::fs::symlink_metadata(path) {
            Ok(m) if !m.is_file() => return Err(bad("it exists and is not a regular file")),
            Ok(_) => {
                let same = |input: &PathBuf| {
                    let canon = |p: &Path| std::fs::canonicalize(p).ok();
                    canon(input).is_some_and(|i| canon(path) == Some(i))
                };
                if inputs.iter().any(same) {
                    return Err(ReportError::Input { path: path.into() });
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(bad(&e.to_string())),
        }
        // A probe file is the one test of "takes a new file" that holds for
        // read-only mounts and permissions alike.
        let probe = temp_beside(path).ok_or_else(|| bad("it names no file"))?;
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
            Ok(_) => {
                let _ = std::fs::remove_file(&probe);
                Ok(())
            }
            Err(e) => Err(bad(&format!("its folder does not take a new file ({e})"))),
        }
    }

    /// Writes the report as JSON to `path` whole: into a temporary file
    /// beside it, renamed over it when complete.
    pub fn write(&self, path: &Path) -> Result<(), ReportError> {
        let io = |source| ReportError::Io { path: path.into(), source };
        let tmp =
            temp_beside(path).ok_or_else(|| ReportError::Path { path: path.into(), why: "it names no file".into() })?;
        let json = serde_json::to_vec_pretty(self).expect("JSON of plain values");
        let written = std::fs::write(&tmp, json).and_then(|_| std::fs::rename(&tmp, path));
        if written.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        written.map_err(io)
    }
}

/// `.NAME.terrachunk-tmp-PID` beside `path`, or `None` where it names no file.
fn temp_beside(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?;
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let mut tmp = std::ffi::OsString::from(".");
    tmp.push(name);
    tmp.push(format!(".terrachunk-tmp-{}", std::process::id()));
    Some(parent.join(tmp))
}

/// [`Report`] as the lines `terrachunk build` prints ([`Report::summary`]).
pub struct Summary<'a> {
    report: &'a Report,
    out: &'a Path,
    max_chunk_vertices: u32,
}

impl Report {
    /// The summary of a build into `out` with `max_chunk_vertices` (which the
    /// refine levels' line names), for printing.
    pub fn summary<'a>(&'a self, out: &'a Path, max_chunk_vertices: u32) -> Summary<'a> {
        Summary { report: self, out, max_chunk_vertices }
    }

    /// The warning for chunks that miss δ as written, naming the worst, if any.
    pub fn over_delta_warning(&self) -> Option<String> {
        let over = &self.over_delta_as_written;
        (!over.is_empty()).then(|| {
            format!(
                "warning: {} chunk(s) miss δ as written even so (cut points rounded to the u16 grid on steep ground; \
                 `verify` reports them, --compress none avoids it): {}",
                over.len(),
                worst_over_delta(over, 10)
            )
        })
    }
}

impl Report {
    /// The warning for a placed grid whose planar frame puts some sample
    /// farther from its place on the ellipsoid than the leaf δ.
    pub fn flat_frame_warning(&self) -> Option<String> {
        let e = self.flat_frame_error.as_ref().filter(|_| self.frame == crate::geodesy::FrameKind::Flat)?;
        let leaf = self.levels.last()?.delta_m;
        (e.worst_m() > leaf).then(|| {
            format!(
                "warning: the tileset is planar, and a 3D Tiles client draws it up to {:.1} m off the ellipsoid \
                 (row {}, column {}), more than the leaf δ {leaf} m: a grid this large needs the curved frame \
                 (--frame curved, with --mesher rtin and --compress none; a grid of degrees must reach no pole \
                 and span less than 360° of longitude)",
                e.worst_m(),
                e.at[0],
                e.at[1]
            )
        })
    }

    /// The warning for a georeferenced grid the tileset does not place on
    /// the globe, if it is one.
    pub fn not_placed_warning(&self) -> Option<String> {
        self.not_placed.as_ref().map(|why| {
            format!(
                "warning: not placed on the globe: {why}; the tileset has no root transform and stays in its \
                 local frame"
            )
        })
    }
}

impl std::fmt::Display for Summary<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (r, out, max_chunk_vertices) = (self.report, self.out, self.max_chunk_vertices);
        writeln!(
            f,
            "{} × {} samples ({} valid), spacing {:.3} × {:.3} m",
            r.grid[0], r.grid[1], r.valid_samples, r.spacing_m[0], r.spacing_m[1]
        )?;
        writeln!(
            f,
            "{:>5} {:>10} {:>7} {:>7} {:>11} {:>9} {:>11}",
            "level", "δ (m)", "chunks", "leaves", "triangles", "skirt tri", "max err (m)"
        )?;
        for l in &r.levels {
            writeln!(
                f,
                "{:>5} {:>10.4} {:>7} {:>7} {:>11} {:>9} {:>11.4}",
                l.level, l.delta_m, l.chunks, l.leaves, l.triangles, l.skirt_triangles, l.max_error_m
            )?;
        }
        if r.levels.iter().any(|l| l.texture.is_some()) {
            writeln!(
                f,
                "{:>5} {:>10} {:>10} {:>11} {:>13} {:>21} {:>13} {:>14}",
                "level", "T_g (m)", "δ/τ (m)", "largest", "texels", "sized by b/s/cap", "texture B", "geometry B"
            )?;
            for l in &r.levels {
                if let Some(t) = &l.texture {
                    writeln!(
                        f,
                        "{:>5} {:>10.4} {:>10.4} {:>11} {:>13} {:>21} {:>13} {:>14}",
                        l.level,
                        t.texel_m,
                        t.bound_m,
                        format!("{}×{}", t.largest[0], t.largest[1]),
                        t.texels,
                        format!("{}/{}/{}", t.limited_by_bound, t.limited_by_source, t.limited_by_cap),
                        t.texture_bytes,
                        l.bytes - t.texture_bytes
                    )?;
                }
            }
            for l in &r.levels {
                if let Some(t) = l.texture.as_ref().filter(|t| t.over_bound > 0) {
                    let why = if t.limited_by_cap > 0 {
                        "max_texture_px caps them (raise it to keep the bound)"
                    } else {
                        "the texture source is coarser than that (no tile is finer than its source)"
                    };
                    writeln!(
                        f,
                        "level {}: {} chunk(s) have T_g up to {:.4} m > δ/τ_max = {:.4} m: {why}",
                        l.level, t.over_bound, t.texel_m, t.bound_m
                    )?;
                }
            }
        }
        match (&r.flat_frame_error, r.frame) {
            (Some(e), crate::geodesy::FrameKind::Curved) => writeln!(
                f,
                "on the globe: curved, every vertex at its WGS 84 position (a planar frame would have drawn \
                 samples up to {:.3} m along the ellipsoid normal and {:.3} m across it from their places)",
                e.vertical_m, e.horizontal_m
            )?,
            (Some(e), _) => writeln!(
                f,
                "on the globe: planar, drawn up to {:.3} m along the ellipsoid normal and {:.3} m across it from \
                 the samples' places",
                e.vertical_m, e.horizontal_m
            )?,
            (None, _) => {}
        }
        let s = &r.seconds;
        writeln!(f, "{} bytes ({:.3} bytes per input sample) in {}", r.bytes, r.bytes_per_sample, out.display())?;
        if r.index_files > 1 {
            writeln!(
                f,
                "index: tileset.json and {} external tilesets beside it (more than index_tiles tiles in all)",
                r.index_files - 1
            )?;
        }
        writeln!(
            f,
            "time: load {:.2} s, plan {:.2} s, texture source {:.2} s, chunks {:.2} s (mesh {:.2}, skirt+morph {:.2}, {}texture {:.2}, write {:.2} thread-s), index {:.2} s, total {:.2} s on {} threads",
            s.load,
            s.plan,
            s.texture_source,
            s.chunks,
            r.thread_seconds.mesh,
            r.thread_seconds.skirt_morph,
            if r.thread_seconds.check > 0.0 {
                format!("as-written check {:.2}, ", r.thread_seconds.check)
            } else {
                String::new()
            },
            r.thread_seconds.texture,
            r.thread_seconds.write,
            s.index,
            s.total,
            r.threads
        )?;
        let chunks: usize = r.levels.iter().map(|l| l.chunks).sum();
        let vertices: usize = r.levels.iter().map(|l| l.vertices).sum();
        if chunks > 0 {
            writeln!(
                f,
                "leaves up to {} cells wide{}; {:.0} surface vertices per chunk on average ({:.0} at the deepest level)",
                r.leaf_width_cells,
                if r.leaf_width_cells < r.leaf_cells {
                    format!(" (leaf_cells {})", r.leaf_cells)
                } else {
                    String::new()
                },
                vertices as f64 / chunks as f64,
                r.levels.last().map_or(0.0, |l| l.vertices as f64 / l.chunks.max(1) as f64)
            )?;
        }
        if r.roots.0 > 1 {
            let written = r.levels.first().map_or(0, |l| l.chunks);
            writeln!(
                f,
                "{written} top-level chunks, up to {} cells wide, each the top of its own tree{}{}",
                r.roots.1,
                if written < r.roots.0 {
                    format!(" ({} more footprints hold no valid sample)", r.roots.0 - written)
                } else {
                    String::new()
                },
                if r.roots_narrowed {
                    ": the grid's cell counts are odd or hold a small power of two, so the bintree splits \
                     its last column and row down to single cells at every level, which wider top chunks \
                     could not hold within max_chunk_vertices"
                } else {
                    ""
                }
            )?;
        }
        if r.refine_levels > 0 {
            writeln!(
                f,
                "{} level(s) refine the leaves in place (same footprint, half the δ): with fewer, coarser chunks would need more than {} vertices (max_chunk_vertices; {})",
                r.refine_levels,
                max_chunk_vertices,
                match (r.refine_estimated, r.refine_levels - r.refine_estimated) {
                    (_, 0) => "estimated from the data, not built".to_string(),
                    (0, _) => format!("found by attempts that took {:.1} s", r.discarded_s),
                    (e, _) => format!(
                        "{e} estimated from the data, the rest found by attempts that took {:.1} s",
                        r.discarded_s
                    ),
                }
            )?;
        }
        if r.remeshed_for_cut_points > 0 {
            writeln!(
                f,
                "{} chunk(s) meshed again with a wider margin next to cut points, so that rounding them to the u16 grid keeps δ",
                r.remeshed_for_cut_points
            )?;
        }
        if let Some(b) = r.peak_rss_bytes {
            let limit = r.memory_limit_bytes.map_or(String::new(), |l| format!(" (limit {:.0} MB)", l as f64 / 1e6));
            writeln!(f, "peak memory: {:.1} MB{limit}", b as f64 / 1e6)?;
        }
        if r.scratch_bytes > 0 {
            writeln!(
                f,
                "{:.1} MB of grid-sized arrays in scratch files beside the output (unlinked, gone when the build ends)",
                r.scratch_bytes as f64 / 1e6
            )?;
        }
        Ok(())
    }
}

/// The `shown` chunks furthest over their δ, each with its error and by how
/// much it misses (a miss of 10⁻⁹ m printed as "1.000 m" said nothing), and
/// how many more the report lists: California once warned of 865 chunks on
/// one line.
fn worst_over_delta(over: &[OverDelta], shown: usize) -> String {
    let mut by_excess: Vec<&OverDelta> = over.iter().collect();
    by_excess.sort_by(|a, b| {
        (b.error_m - b.delta_m).total_cmp(&(a.error_m - a.delta_m)).then_with(|| a.chunk.cmp(&b.chunk))
    });
    let mut list: Vec<String> = by_excess
        .iter()
        .take(shown)
        .map(|o| format!("{} ({:.4} m, {:.1e} m over δ {} m)", o.chunk, o.error_m, o.error_m - o.delta_m, o.delta_m))
        .collect();
    if over.len() > shown {
        list.push(format!("and {} more (`--report FILE` lists them all)", over.len() - shown));
    }
    list.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_over_delta_warning_names_the_worst_chunks_and_counts_the_rest() {
        let over: Vec<OverDelta> =
            [("2/0/0", 1.000_000_001, 1.0), ("0/0/0", 4.5, 4.0), ("1/3/1", 2.25, 2.0), ("2/5/7", 1.1, 1.0)]
                .map(|(chunk, error_m, delta_m)| OverDelta { chunk: chunk.into(), error_m, delta_m })
                .into();
        let text = worst_over_delta(&over, 2);
        assert_eq!(
            text,
            "0/0/0 (4.5000 m, 5.0e-1 m over δ 4 m), 1/3/1 (2.2500 m, 2.5e-1 m over δ 2 m), and 2 more (`--report FILE` lists them all)"
        );
        let all = worst_over_delta(&over, 10);
        assert!(all.ends_with("2/0/0 (1.0000 m, 1.0e-9 m over δ 1 m)"), "{all}");
    }
}
