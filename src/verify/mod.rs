//! Verify: re-check a written tileset from its files alone (DESIGN.md's
//! promises 1–3 and 5), independently of the code that built it.
//!
//! It reads `tileset.json` and every `.glb` back (the `gltf` crate for the
//! accessors, `serde_json` for the f64 node translation), reloads the DEM the
//! tileset names (or `--dem`), and measures:
//! - error: every valid sample of a chunk's footprint lies within δ(L) of the
//!   written surface (rasterised in f64 from the f32 positions), is covered by
//!   a triangle, and chunks without children are within `max_error_m`; an
//!   error within f64 rounding of the bound is the bound (`snap_error`): a
//!   sample may be exactly δ off, as on integer heights;
//! - borders: same-level neighbours have the same vertices on their shared
//!   edge (within f32 rounding of the chunk-local positions);
//! - morph: every vertex moved by its morph target lands on the parent's
//!   surface, and every child triangle lies inside one parent triangle, so
//!   the morphed chunk coincides with its parent everywhere; skirt bottoms do
//!   not morph;
//! - structure: 3D Tiles 1.1 fields, REPLACE, geometricError = δ(L) halving
//!   with each level, boxes that contain their content, extras that match;
//! - compressed chunks (`compress = "quantize" | "meshopt" |
//!   "meshopt-v1"`) are decoded first (`output::compress::decompress`,
//!   meshoptimizer's decoders) and checked alike: the error against δ(L)
//!   with no allowance for the quantization, the borders as
//!   exactly, and the morph targets with the quantization step in place of
//!   the f32 rounding;
//! - texture (when the tileset says its chunks are textured): every tile's
//!   texel spacing T_g = footprint / (texels − 1), from the embedded image's
//!   size, is ≤ δ/τ_max, or the tile is as fine as its source allows, or
//!   `max_texture_px` caps it on a level the extras state as capped (counted
//!   as exceptions, not failures); no tile is finer than its source; every
//!   vertex's TEXCOORD lies in [0, 1] where the footprint → texel-centre map
//!   puts it; the material and sampler are as the contract says; and
//!   neighbouring same-level tiles have equal border texels (exactly for
//!   PNG, within the compression error for JPEG).

mod border;
mod checks;
mod curved;
pub(crate) use curved::Curved;
mod inspect;
mod morph;
mod read;
mod source;
mod texture;
mod tree;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;
use serde_json::Value;

pub use inspect::{Inspection, inspect};
pub use read::{
    ChunkFile, ChunkTexture, ImageEdges, MAX_INDEX_BYTES, MAX_TILE_BYTES, Prim, inline_external, parse_chunk,
    read_chunk, read_tile, read_tileset,
};

use crate::dem::{self, LoadOptions};
use crate::mesh::quality::{self, ShapeSummary};
use crate::output::tileset::TilesetExtras;
use crate::quadtree::ChunkKey;
use border::{border_record, compare_border};
use checks::{check_error, snap_error};
use curved::CurvedChunk;
use morph::{ParentSurface, check_curved_morph, check_morph};
use texture::{Texel, check_texture, compare_seam, seam_tolerance};
use tree::{Index, check_transform, check_tree, content_in_box};

/// Why verification could not run (as opposed to finding problems).
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    /// A file is missing, unreadable or not what it should be.
    #[error("{path}: {what}")]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The DEM could not be loaded.
    #[error(transparent)]
    Dem(#[from] dem::DemError),
}

pub(crate) fn file_err(path: &Path, what: impl Into<String>) -> VerifyError {
    VerifyError::File { path: path.into(), what: what.into() }
}

/// Per-level measurements.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelCheck {
    /// Chunks checked.
    pub chunks: usize,
    /// δ(L).
    pub delta_m: f64,
    /// Largest measured error, metres.
    pub max_error_m: f64,
    /// Largest morph mismatch, metres.
    pub max_morph_gap_m: f64,
    /// The surface triangles' shapes in plan, as written (promise 8).
    pub shape: ShapeSummary,
}

/// What verify found.
#[derive(Clone, Debug, Default, Serialize)]
pub struct VerifyReport {
    /// Per level.
    pub levels: BTreeMap<u32, LevelCheck>,
    /// Border pairs compared.
    pub borders_checked: usize,
    /// Problems, each naming the chunk.
    pub failures: Vec<String>,
    /// Levels that break promise 8 (more than 0.1 % of their triangles
    /// slivers), each naming the level: reported apart from `failures`,
    /// since the greedy mesher does not keep that promise on every DEM.
    pub slivers: Vec<String>,
    /// Texture measurements (absent for an untextured tileset).
    pub texture: Option<TextureCheck>,
    /// How far the root transform draws the planar grid from its place on
    /// the ellipsoid, measured from the transform in the file (absent when
    /// the tileset has none).
    pub flat_frame_error: Option<crate::geodesy::FlatFrameError>,
    /// The tileset is written in the curved frame, and each level's error
    /// was measured along the ellipsoid normal in ECEF.
    pub curved: bool,
}

/// What verify measured of the texture tiles.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TextureCheck {
    /// Per level.
    pub levels: BTreeMap<u32, TextureLevelCheck>,
    /// Shared borders whose edge texels were compared.
    pub seams_checked: usize,
    /// Largest difference of one channel of a border texel between
    /// neighbours (0 when they are equal).
    pub max_seam_diff: u8,
    /// The largest difference allowed: 0 for PNG, the JPEG error otherwise.
    pub seam_tolerance: u8,
    /// Largest root-mean-square channel difference along one shared edge.
    pub max_seam_rms: f64,
    /// The largest RMS allowed.
    pub seam_rms_tolerance: f64,
}

/// One level's tiles, as measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TextureLevelCheck {
    /// Textured chunks.
    pub chunks: usize,
    /// Largest T_g = footprint / (texels − 1), either axis, metres.
    pub texel_m: f64,
    /// δ(L)/τ_max, metres.
    pub bound_m: f64,
    /// Chunks with T_g > δ/τ_max that are as fine as their source allows.
    pub at_source: usize,
    /// Chunks with T_g > δ/τ_max because `max_texture_px` caps them, on a
    /// level the extras state as capped: the stated exception.
    pub capped: usize,
}

/// Checks the tileset at `dir`; `dem` overrides the source it names.
pub fn verify(dir: &Path, dem_override: Option<&[PathBuf]>) -> Result<VerifyReport, VerifyError> {
    verify_with_progress(dir, dem_override, None, false)
}

/// [`verify`], with a progress bar over the chunks on stderr where
/// `progress` (the command line's, on a terminal: a large tileset takes
/// about as long to verify as to build).
pub fn verify_with_progress(
    dir: &Path,
    dem_override: Option<&[PathBuf]>,
    geoid_override: Option<&Path>,
    progress: bool,
) -> Result<VerifyReport, VerifyError> {
    let (ts_path, text) = read::read_index(dir)?;
    let mut ts: Value = serde_json::from_slice(&text).map_err(|e| file_err(&ts_path, format!("bad JSON: {e}")))?;
    let extras: TilesetExtras = serde_json::from_value(ts["extras"]["terrachunk"].clone())
        .map_err(|e| file_err(&ts_path, format!("extras.terrachunk: {e}")))?;
    let mut report = VerifyReport::default();
    if let Some(tx) = &extras.texture {
        let (seam_tolerance, seam_rms_tolerance) = seam_tolerance(tx);
        report.texture = Some(TextureCheck { seam_tolerance, seam_rms_tolerance, ..TextureCheck::default() });
    }

    // Structure.
    if ts["asset"]["version"] != "1.1" {
        report.failures.push("tileset.json: asset.version is not \"1.1\"".into());
    }
    // The external tilesets, in place of the tiles that refer to them: a
    // missing or damaged one is the tileset's fault, not the input's.
    if let Err(e) = inline_external(dir, &mut ts) {
        report.failures.push(e.to_string());
        return Ok(report);
    }
    let index = Index::read(&ts["root"], &extras, &mut report.failures);

    let sources: Vec<PathBuf> = match dem_override {
        Some(d) => d.to_vec(),
        None => source::locate(dir, &ts_path, &extras.source)?,
    };
    // The heights the build meshed: the DEM's plus the same geoid model's
    // undulation, when one was given.
    let geoid = match (&extras.geoid, geoid_override) {
        (Some(_), Some(g)) => Some(g.to_path_buf()),
        (Some(model), None) => Some(source::locate_one(dir, &ts_path, model)?),
        (None, Some(g)) => {
            return Err(file_err(
                &ts_path,
                format!("was built without a geoid model; --geoid {} does not apply", g.display()),
            ));
        }
        (None, None) => None,
    };
    let opts = LoadOptions {
        vertical_scale: Some(extras.vertical_scale),
        spacing_m: Some(extras.spacing_m),
        geoid,
        memory: None,
    };
    let hf = dem::load(&sources, &opts)?;
    if [hf.width as u32, hf.height as u32] != [extras.grid.width, extras.grid.height] {
        report.failures.push(format!(
            "DEM is {}×{} but the tileset was built from {}×{}",
            hf.width, hf.height, extras.grid.width, extras.grid.height
        ));
        return Ok(report);
    }
    report.flat_frame_error = check_transform(&ts, &hf, &mut report.failures);
    let curved = match Curved::of(&ts, &hf) {
        Ok(c) => c,
        Err(why) => {
            report.failures.push(format!("tileset.json: {why}"));
            return Ok(report);
        }
    };

    // Down the tree, each chunk read once and checked against its parent
    // (error, coverage, morph, texture), then dropped but for what its
    // borders need; so only the chunks along the paths being walked are
    // held, not a level and its parents. Then the tree's shape from every
    // chunk's footprint, and level by level each chunk's findings in key
    // order, then the borders between same-level neighbours.
    let bar = crate::progress::bar(progress, index.tiles.len() as u64, "chunks");
    report.curved = curved.is_some();
    let walk = Walk { dir, hf: &hf, extras: &extras, index: &index, bar: &bar, curved: curved.as_ref() };
    let found: Vec<Visited> = index.roots().par_iter().flat_map_iter(|&k| walk.visit(k, Parent::None)).collect();
    bar.finish_and_clear();
    let footprints = found.iter().filter_map(|v| v.footprint.map(|f| (v.key, f))).collect();
    check_tree(&index, &footprints, &hf, &mut report.failures);
    let mut by_level: BTreeMap<u32, BTreeMap<ChunkKey, Visited>> = BTreeMap::new();
    for v in found {
        by_level.entry(v.key.level).or_default().insert(v.key, v);
    }
    for level in by_level.values() {
        finish_level(&extras, level, &mut report);
    }
    Ok(report)
}

/// What checking one chunk found, and its borders for the neighbours.
struct Visited {
    key: ChunkKey,
    /// The file's own failures: unreadable, or naming another chunk.
    read: Vec<String>,
    /// What its checks found, if it was read.
    checked: Option<Findings>,
    /// The chunk cut down to its borders ([`border_record`]).
    borders: Option<ChunkFile>,
    /// Its footprint, from its file, if it was read.
    footprint: Option<[u32; 4]>,
}

/// What one chunk's own checks found.
struct Findings {
    /// δ(L) from its node extras, metres.
    delta_m: f64,
    /// Largest error against the DEM, metres.
    error_m: f64,
    /// Largest morph gap to the parent surface (top level: largest delta), metres.
    morph_gap_m: f64,
    /// Its tile's T_g and why that may exceed the bound (textured tilesets).
    texel: Option<(f64, Texel)>,
    /// Its surface triangles' shapes.
    shape: ShapeSummary,
    /// What failed.
    problems: Vec<String>,
}

/// What a chunk's morph targets are checked against.
#[derive(Clone, Copy)]
enum Parent<'a> {
    /// A top-level chunk: its deltas must be 0.
    None,
    /// The parent's file, read, and its surface as the morph check reads it.
    Read(&'a ParentSurface<'a>),
    /// The parent's file could not be read (a failure of its own): nothing
    /// to check the targets against.
    Unreadable,
}

/// What every chunk's check reads.
struct Walk<'a> {
    dir: &'a Path,
    hf: &'a crate::heightfield::Heightfield,
    extras: &'a TilesetExtras,
    index: &'a Index,
    bar: &'a indicatif::ProgressBar,
    /// The map of a tileset written in the curved frame.
    curved: Option<&'a Curved>,
}

impl Walk<'_> {
    /// Reads and checks chunk `k` against `parent`, then its subtree in
    /// parallel.
    fn visit(&self, k: ChunkKey, parent: Parent) -> Vec<Visited> {
        let uri = crate::output::tileset::tile_uri(k);
        let file = read_tile(self.dir, &uri).and_then(|bytes| parse_chunk(&self.dir.join(&uri), &bytes));
        // In the curved frame the checks read the chunk in grid space, and
        // its written surface in ECEF beside it.
        let bent: Option<Result<(ChunkFile, CurvedChunk), String>> = match (&file, self.curved) {
            (Ok(c), Some(cv)) if checks::finite(c) => Some(cv.unbend(c)),
            _ => None,
        };
        let (flat, ecef) = match &bent {
            Some(Ok((f, e))) => (Some(f), Some(e)),
            _ => (file.as_ref().ok(), None),
        };
        let kids = &self.index.tiles[&k].children;
        // A parent whose positions are not all finite has no surface to
        // check its children's targets against (its own failure says why).
        let surface = match flat {
            Some(c) if !kids.is_empty() && checks::finite(c) => {
                Some(ParentSurface::new(c, self.extras.spacing_m).with_curved(ecef))
            }
            _ => None,
        };
        let kids_parent = surface.as_ref().map_or(Parent::Unreadable, Parent::Read);
        let mut out: Vec<Visited> = kids.par_iter().flat_map_iter(|&kid| self.visit(kid, kids_parent)).collect();
        out.push(match (&file, flat) {
            (Ok(c), Some(f)) => {
                let mut read: Vec<String> = (c.key != k)
                    .then(|| format!("chunk {}: node extras say {:?}", name(k), c.key))
                    .into_iter()
                    .collect();
                if let Some(Err(why)) = &bent {
                    read.push(format!("chunk {}: {why}", name(k)));
                }
                let checked = Some(self.check(k, c, f, ecef, parent));
                Visited { key: k, read, checked, borders: Some(border_record(f)), footprint: Some(c.footprint) }
            }
            (Err(e), _) => Visited {
                key: k,
                read: vec![format!("chunk {}: {e}", name(k))],
                checked: None,
                borders: None,
                footprint: None,
            },
            (Ok(_), None) => unreachable!("a read chunk is its own grid-space view"),
        });
        self.bar.inc(1);
        out
    }

    /// Error, coverage and morph of one chunk (against its parent), and its texture.
    fn check(
        &self,
        k: ChunkKey,
        c: &ChunkFile,
        flat: &ChunkFile,
        ecef: Option<&CurvedChunk>,
        parent: Parent,
    ) -> Findings {
        let extras = self.extras;
        let mut problems = Vec::new();
        let tile = &self.index.tiles[&k];
        if let Some(p) = tile.bbox.as_ref().and_then(|b| content_in_box(c, b)) {
            problems.push(p);
        }
        if !checks::finite(c) {
            // Every measure below would read NaN as "no error".
            problems.extend(checks::not_finite(c));
            return Findings {
                delta_m: c.delta_m,
                error_m: f64::INFINITY,
                morph_gap_m: 0.0,
                texel: None,
                shape: ShapeSummary::default(),
                problems,
            };
        }
        checks::normals(c, ecef.map(|e| &e.ups), &mut problems);
        let has_children = !tile.children.is_empty();
        let planar = check_error(self.hf, flat, extras.spacing_m, &mut problems);
        let err = match (self.curved, ecef) {
            (Some(cv), Some(e)) => cv.check_error(self.hf, flat, e, c.delta_m, &mut problems),
            _ => planar,
        };
        if !has_children
            && snap_error(c, err, extras.max_error_m) > extras.max_error_m + ecef.map_or(0.0, |e| e.rounding_m)
        {
            problems.push(format!("leaf error {err:.4} m exceeds max_error_m {}", extras.max_error_m));
        }
        let gap = match parent {
            Parent::Read(p) => match (self.curved, ecef, p.curved()) {
                (Some(cv), Some(e), Some(pe)) => check_curved_morph(cv, flat, e, p, pe, &mut problems),
                _ => check_morph(c, p, extras.spacing_m, &mut problems),
            },
            Parent::Unreadable => 0.0,
            Parent::None => {
                let m = c.surface.morph_dy.iter().fold(0.0f64, |a, d| a.max(d.abs())).max(c.surface.largest_dxz());
                if m > 0.0 {
                    problems.push(format!("top-level chunk has nonzero morph deltas (up to {m} m)"));
                }
                m
            }
        };
        if !c.morph_contract {
            problems.push("mesh.weights is not [0] or targetNames is not [\"parent\"]".into());
        }
        let texel = extras.texture.as_ref().and_then(|tx| check_texture(flat, extras, tx, &mut problems));
        let plan: Vec<[f64; 2]> = flat.surface.positions.iter().map(|p| [p[0], p[2]]).collect();
        let shape = quality::summarize(&plan, &flat.surface.triangles);
        Findings { delta_m: c.delta_m, error_m: err, morph_gap_m: gap, texel, shape, problems }
    }
}

/// Promise 8 for one level: what is wrong if more than
/// [`quality::SLIVER_SHARE`] of its triangles are slivers.
fn sliver_problem(s: &ShapeSummary) -> Option<String> {
    (!s.meets_promise()).then(|| {
        format!(
            "{} of {} triangles ({:.3} %) are slivers (aspect over {}), more than {} % ({} over {}; smallest angle {:.2e}°)",
            s.slivers,
            s.triangles,
            100.0 * s.sliver_share(),
            quality::SLIVER_ASPECT,
            100.0 * quality::SLIVER_SHARE,
            s.needles,
            quality::NEEDLE_ASPECT,
            s.min_angle_deg
        )
    })
}

/// One level's findings in key order (as the tileset lists its chunks),
/// then the borders between same-level neighbours (east and south).
fn finish_level(extras: &TilesetExtras, level: &BTreeMap<ChunkKey, Visited>, report: &mut VerifyReport) {
    for v in level.values() {
        report.failures.extend(v.read.iter().cloned());
    }
    for (k, v) in level {
        let Some(f) = &v.checked else { continue };
        if let (Some(tc), Some((texel_m, why))) = (report.texture.as_mut(), f.texel) {
            let l = tc.levels.entry(k.level).or_default();
            l.chunks += 1;
            l.texel_m = l.texel_m.max(texel_m);
            l.bound_m = f.delta_m / extras.tau_max_px;
            l.at_source += usize::from(why == Texel::AtSource);
            l.capped += usize::from(why == Texel::Capped);
        }
        let l = report.levels.entry(k.level).or_default();
        l.chunks += 1;
        l.delta_m = f.delta_m;
        l.max_error_m = l.max_error_m.max(f.error_m);
        l.max_morph_gap_m = l.max_morph_gap_m.max(f.morph_gap_m);
        l.shape = l.shape.merge(f.shape);
        for p in &f.problems {
            report.failures.push(format!("chunk {}: {p}", name(*k)));
        }
    }
    if let Some(&k) = level.keys().next()
        && let Some(p) = report.levels.get(&k.level).and_then(|l| sliver_problem(&l.shape))
    {
        report.slivers.push(format!("level {}: {p}", k.level));
    }
    for (k, v) in level {
        let Some(c) = &v.borders else { continue };
        for (dx, dy) in [(1, 0), (0, 1)] {
            let nk = ChunkKey { level: k.level, x: k.x + dx, y: k.y + dy };
            if let Some(n) = level.get(&nk).and_then(|n| n.borders.as_ref()) {
                report.borders_checked += 1;
                if let Some(p) = compare_border(c, n, dx == 1, extras.spacing_m) {
                    report.failures.push(format!("chunks {} and {}: {p}", name(*k), name(nk)));
                }
                if let Some(tc) = report.texture.as_mut() {
                    tc.seams_checked += 1;
                    if let Err(p) = compare_seam(c, n, dx == 1, tc) {
                        report.failures.push(format!("chunks {} and {}: {p}", name(*k), name(nk)));
                    }
                }
            }
        }
    }
}

/// `L/x/y`.
pub fn name(k: ChunkKey) -> String {
    format!("{}/{}/{}", k.level, k.x, k.y)
}
