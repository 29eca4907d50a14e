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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;
use serde_json::Value;

use crate::dem::{self, LoadOptions};
use crate::heightfield::Heightfield;
use crate::mesh::MeshVertex;
use crate::mesh::quality::{self, ShapeSummary};
use crate::morph::{LocatorIndex, SurfaceLocator, barycentric, points_near_triangle};
use crate::output::gltf::{Imported, import};
use crate::output::tileset::{TileExtras, TilesetExtras};
use crate::quadtree::ChunkKey;
use crate::texture::{Limit, TextureExtras};

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

/// One chunk as read back from its .glb.
#[derive(Clone, Debug)]
pub struct ChunkFile {
    /// Level/x/y from the node extras.
    pub key: ChunkKey,
    /// δ(L) from the node extras.
    pub delta_m: f64,
    /// Footprint `[x0, x1, z0, z1]` in samples, from the node extras.
    pub footprint: [u32; 4],
    /// Node translation (f64 as written).
    pub translation: [f64; 3],
    /// `[s_x, s_z]` from the node extras, metres.
    pub spacing_m: [f64; 2],
    /// Surface: world positions (translation + local), morph y deltas, triangles.
    pub surface: Prim,
    /// Skirt part, if any.
    pub skirt: Option<Prim>,
    /// Whether `mesh.weights == [0]` and `targetNames == ["parent"]`.
    pub morph_contract: bool,
    /// The texture tile(s), if the chunk has a textured material.
    pub texture: Option<ChunkTexture>,
    /// The quantization step per axis (the node scale), metres, for a
    /// `quantize` or `meshopt` file; None for f32 vertex data.
    pub quantization_m: Option<[f64; 3]>,
}

/// A chunk's textures as read back.
#[derive(Clone, Debug)]
pub struct ChunkTexture {
    /// The base colour image.
    pub colour: ImageEdges,
    /// The normal map, if any, and its texCoord set.
    pub normal: Option<(ImageEdges, u32)>,
    /// Where the material or sampler departs from the contract.
    pub contract: Vec<String>,
}

/// An embedded image's size and its four border lines of texels (RGB).
#[derive(Clone, Debug, Default)]
pub struct ImageEdges {
    /// Texels across (x).
    pub width: u32,
    /// Texels down (z).
    pub height: u32,
    /// `image/png` or `image/jpeg`.
    pub mime: String,
    /// First row, west to east.
    pub north: Vec<[u8; 3]>,
    /// Last row.
    pub south: Vec<[u8; 3]>,
    /// First column, north to south.
    pub west: Vec<[u8; 3]>,
    /// Last column.
    pub east: Vec<[u8; 3]>,
}

/// A primitive read back.
#[derive(Clone, Debug, Default)]
pub struct Prim {
    /// World positions, metres.
    pub positions: Vec<[f64; 3]>,
    /// Morph target y deltas, metres (x and z deltas must be 0).
    pub morph_dy: Vec<f64>,
    /// Largest |x| or |z| morph delta found (must be 0).
    pub morph_dxz: f64,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Largest |local coordinate| per axis (x, y, z), metres: sets the f32
    /// tolerances, horizontal and vertical apart (at 1 mm spacing under
    /// 400 m of relief they differ by five orders of magnitude).
    pub local_extent: [f64; 3],
    /// TEXCOORD_0 (empty when untextured).
    pub uv: Vec<[f32; 2]>,
    /// TEXCOORD_1 (empty unless the normal map has its own).
    pub uv1: Vec<[f32; 2]>,
}

impl Prim {
    /// The positions in grid coordinates (column, row) with their heights.
    /// A coordinate within f32 rounding of a whole sample index is that
    /// index: the vertex is the sample. Unsnapped, steep ground turns the
    /// rounding of a vertex that *is* a sample into an apparent error there
    /// (5 km of noise on 1 mm cells: 10⁻⁶ cells of rounding read as 5 mm).
    pub fn grid_vertices(&self, spacing: [f64; 2]) -> Vec<MeshVertex> {
        let snap = self.snap(spacing);
        self.positions.iter().map(|p| to_grid(p, spacing, snap)).collect()
    }

    /// The f32 rounding of this primitive's chunk-local x and z, in grid
    /// units (twice the half-ulp bound of its largest coordinate).
    fn snap(&self, spacing: [f64; 2]) -> [f64; 2] {
        let r = |extent: f64, s: f64| extent * f64::from(f32::EPSILON) / s;
        [r(self.local_extent[0], spacing[0]), r(self.local_extent[2], spacing[1])]
    }
}

/// A world position (metres) in grid coordinates, with its height, each
/// coordinate snapped to a whole index when within `snap` of it.
fn to_grid(p: &[f64; 3], spacing: [f64; 2], snap: [f64; 2]) -> MeshVertex {
    let grid = |v: f64, snap: f64| {
        let r = v.round();
        if (v - r).abs() <= snap { r } else { v }
    };
    let (x, z) = (grid(p[0] / spacing[0], snap[0]), grid(p[2] / spacing[1], snap[1]));
    MeshVertex { x, z, h: p[1], ph: p[1] }
}

fn file_err(path: &Path, what: impl Into<String>) -> VerifyError {
    VerifyError::File { path: path.into(), what: what.into() }
}

/// Reads one chunk file.
pub fn read_chunk(path: &Path) -> Result<ChunkFile, VerifyError> {
    let bytes = std::fs::read(path).map_err(|e| file_err(path, format!("cannot read: {e}")))?;
    parse_chunk(path, &bytes)
}

/// [`read_chunk`] on bytes already read from `path` (which errors name):
/// any bytes give a chunk or an error, never a panic (the `chunk` fuzz
/// target).
pub fn parse_chunk(path: &Path, bytes: &[u8]) -> Result<ChunkFile, VerifyError> {
    let decoded = crate::output::compress::decompress(bytes).map_err(|e| file_err(path, e))?;
    let quantization_m = decoded.as_ref().map(|d| d.step_m);
    let bytes: std::borrow::Cow<[u8]> = decoded.map_or(bytes.into(), |d| d.glb.into());
    let Imported { doc, buffers, images, json } = import(&bytes).map_err(|e| file_err(path, e))?;
    let node = &json["nodes"][0];
    let tc = &node["extras"]["terrachunk"];
    let num = |v: &Value, what: &str| v.as_f64().ok_or_else(|| file_err(path, format!("node extras lack {what}")));
    let whole = |v: &Value, what: &str| {
        v.as_u64()
            .and_then(|n| u32::try_from(n).ok())
            .ok_or_else(|| file_err(path, format!("node extras lack {what} as a whole number under 2³²")))
    };
    let key = ChunkKey { level: whole(&tc["level"], "level")?, x: whole(&tc["x"], "x")?, y: whole(&tc["y"], "y")? };
    let fp = &tc["footprint"];
    let footprint =
        [whole(&fp["x0"], "x0")?, whole(&fp["x1"], "x1")?, whole(&fp["z0"], "z0")?, whole(&fp["z1"], "z1")?];
    if footprint[0] >= footprint[1] || footprint[2] >= footprint[3] {
        return Err(file_err(path, format!("node extras hold an empty footprint {footprint:?}")));
    }
    let t = &node["translation"];
    let translation = [num(&t[0], "translation")?, num(&t[1], "translation")?, num(&t[2], "translation")?];
    let mesh = doc.meshes().next().ok_or_else(|| file_err(path, "no mesh"))?;
    let mjson = &json["meshes"][0];
    let morph_contract =
        mjson["weights"] == serde_json::json!([0.0]) && mjson["extras"]["targetNames"] == serde_json::json!(["parent"]);
    let mut surface = None;
    let mut skirt = None;
    // A quantized file holds whole steps from the translation. The f32 form
    // it is decoded into rounds them by up to half an ulp of the chunk-local
    // coordinate, which a steep slope turns into a height error beyond f64
    // slack (California at 1 m with wide top chunks: 2·10⁻⁵ m at a sample
    // exactly δ off beside a cut point), so the steps are recovered exactly:
    // the rounding is under 0.01 of a step.
    let on_steps = |l: f32, axis: usize| {
        let v = f64::from(l);
        quantization_m.map_or(v, |step| (v / step[axis]).round() * step[axis])
    };
    for (pi, prim) in mesh.primitives().enumerate() {
        let role = json["meshes"][0]["primitives"][pi]["extras"]["role"].as_str().unwrap_or("").to_string();
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        let local: Vec<[f32; 3]> = reader.read_positions().ok_or_else(|| file_err(path, "no POSITION"))?.collect();
        let tris: Vec<u32> = reader.read_indices().ok_or_else(|| file_err(path, "no indices"))?.into_u32().collect();
        let mut targets = reader.read_morph_targets();
        let (dpos, _, _) = targets.next().ok_or_else(|| file_err(path, format!("{role}: no morph target")))?;
        let deltas: Vec<[f32; 3]> = dpos.ok_or_else(|| file_err(path, "morph target has no POSITION"))?.collect();
        if deltas.len() != local.len()
            || !tris.len().is_multiple_of(3)
            || tris.iter().any(|&i| i as usize >= local.len())
        {
            return Err(file_err(path, format!("{role}: inconsistent accessor sizes")));
        }
        let read_uv = |set: u32| -> Result<Vec<[f32; 2]>, VerifyError> {
            let uv: Vec<[f32; 2]> = reader.read_tex_coords(set).map(|t| t.into_f32().collect()).unwrap_or_default();
            if !uv.is_empty() && uv.len() != local.len() {
                return Err(file_err(
                    path,
                    format!("{role}: TEXCOORD_{set} has {} of {} vertices", uv.len(), local.len()),
                ));
            }
            Ok(uv)
        };
        let (uv, uv1) = (read_uv(0)?, read_uv(1)?);
        let p = Prim {
            uv,
            uv1,
            positions: local.iter().map(|l| [0, 1, 2].map(|a| translation[a] + on_steps(l[a], a))).collect(),
            morph_dy: deltas.iter().map(|d| f64::from(d[1])).collect(),
            morph_dxz: deltas.iter().map(|d| d[0].abs().max(d[2].abs())).fold(0.0f32, f32::max).into(),
            triangles: tris.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
            local_extent: [0, 1, 2].map(|a| local.iter().map(|l| f64::from(l[a].abs())).fold(0.0, f64::max)),
        };
        match role.as_str() {
            "surface" => surface = Some(p),
            "skirt" => skirt = Some(p),
            other => return Err(file_err(path, format!("primitive with unknown role {other:?}"))),
        }
    }
    Ok(ChunkFile {
        key,
        delta_m: num(&tc["delta_m"], "delta_m")?,
        footprint,
        translation,
        spacing_m: [num(&tc["spacing_m"][0], "spacing_m")?, num(&tc["spacing_m"][1], "spacing_m")?],
        surface: surface.ok_or_else(|| file_err(path, "no surface primitive"))?,
        skirt,
        morph_contract,
        texture: read_texture(path, &json, &images)?,
        quantization_m,
    })
}

/// The material's textures, their images' borders, and what in the
/// material and sampler departs from the contract.
fn read_texture(path: &Path, json: &Value, images: &[gltf::image::Data]) -> Result<Option<ChunkTexture>, VerifyError> {
    let mat = &json["materials"][0];
    let pbr = &mat["pbrMetallicRoughness"];
    let Some(index) = pbr["baseColorTexture"]["index"].as_u64() else {
        return Ok(None);
    };
    let mut contract = Vec::new();
    if pbr["metallicFactor"].as_f64() != Some(0.0) || pbr["roughnessFactor"].as_f64().unwrap_or(1.0) != 1.0 {
        contract.push("material is not metallic 0, roughness 1".to_string());
    }
    if pbr["baseColorTexture"]["texCoord"].as_u64().unwrap_or(0) != 0 {
        contract.push("base colour does not use TEXCOORD_0".to_string());
    }
    let image_of = |texture: u64| -> Result<ImageEdges, VerifyError> {
        let t = &json["textures"][texture as usize];
        let src = t["source"].as_u64().ok_or_else(|| file_err(path, format!("texture {texture} has no image")))?;
        let mime = json["images"][src as usize]["mimeType"].as_str().unwrap_or("").to_string();
        let img = images.get(src as usize).ok_or_else(|| file_err(path, format!("image {src} is missing")))?;
        let c = match img.format {
            gltf::image::Format::R8G8B8 => 3,
            gltf::image::Format::R8G8B8A8 => 4,
            other => return Err(file_err(path, format!("image {src} has pixel format {other:?}, not 8-bit RGB"))),
        };
        let (w, h) = (img.width as usize, img.height as usize);
        if w < 2 || h < 2 || img.pixels.len() < w * h * c {
            return Err(file_err(path, format!("image {src} is {w} × {h}")));
        }
        let px = |i: usize, j: usize| {
            let p = &img.pixels[(i * w + j) * c..];
            [p[0], p[1], p[2]]
        };
        Ok(ImageEdges {
            width: img.width,
            height: img.height,
            mime,
            north: (0..w).map(|j| px(0, j)).collect(),
            south: (0..w).map(|j| px(h - 1, j)).collect(),
            west: (0..h).map(|i| px(i, 0)).collect(),
            east: (0..h).map(|i| px(i, w - 1)).collect(),
        })
    };
    let colour = image_of(index)?;
    let normal = match mat["normalTexture"]["index"].as_u64() {
        Some(n) => Some((image_of(n)?, mat["normalTexture"]["texCoord"].as_u64().unwrap_or(0) as u32)),
        None => None,
    };
    for t in json["textures"].as_array().into_iter().flatten() {
        let sampler = &json["samplers"][t["sampler"].as_u64().unwrap_or(u64::MAX) as usize];
        if sampler["wrapS"] != 33071 || sampler["wrapT"] != 33071 {
            contract.push("sampler does not clamp to edge".to_string());
        }
        if !(9984..=9987).contains(&sampler["minFilter"].as_u64().unwrap_or(0)) {
            contract.push("sampler's minFilter is not a mipmap filter".to_string());
        }
    }
    Ok(Some(ChunkTexture { colour, normal, contract }))
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

/// Why a tile may exceed T_g ≤ δ/τ_max.
#[derive(Clone, Copy, PartialEq, PartialOrd)]
enum Texel {
    Bound,
    AtSource,
    Capped,
}

/// How far neighbours' border texels may differ: `(largest channel
/// difference, largest RMS over one edge)`. PNG: not at all. JPEG: each
/// side carries its own compression error, which grows with the texel-to-
/// texel contrast; the bands are the worst measured on the fixtures (2.4 km
/// topo-bathymetry in 31-texel tiles: max 19 / RMS 6.7 at quality 95,
/// 64 / 17.9 at 80, 84 / 20.2 at 50, 97 / 27.5 at 20) with a third or more
/// to spare. They catch a wrong or shifted image on smooth ground, not a
/// one-texel slip on rough ground; the texel positions themselves are the
/// PNG check's to prove, the encoding being the only difference.
fn seam_tolerance(tx: &TextureExtras) -> (u8, f64) {
    match tx.jpeg_quality {
        None => (0, 0.0),
        Some(q) if q >= 90 => (48, 12.0),
        Some(q) if q >= 70 => (96, 24.0),
        Some(q) if q >= 50 => (112, 28.0),
        Some(_) => (144, 36.0),
    }
}

/// Checks the tileset at `dir`; `dem` overrides the source it names.
pub fn verify(dir: &Path, dem_override: Option<&[PathBuf]>) -> Result<VerifyReport, VerifyError> {
    verify_with_progress(dir, dem_override, false)
}

/// [`verify`], with a progress bar over the chunks on stderr where
/// `progress` (the command line's, on a terminal: a large tileset takes
/// about as long to verify as to build).
pub fn verify_with_progress(
    dir: &Path,
    dem_override: Option<&[PathBuf]>,
    progress: bool,
) -> Result<VerifyReport, VerifyError> {
    let ts_path = dir.join("tileset.json");
    let text = std::fs::read_to_string(&ts_path).map_err(|e| file_err(&ts_path, format!("cannot read: {e}")))?;
    let ts: Value = serde_json::from_str(&text).map_err(|e| file_err(&ts_path, format!("bad JSON: {e}")))?;
    let extras: TilesetExtras = serde_json::from_value(ts["extras"]["terrachunk"].clone())
        .map_err(|e| file_err(&ts_path, format!("extras.terrachunk: {e}")))?;
    let mut report = VerifyReport::default();
    if let Some(tx) = &extras.texture {
        let (seam_tolerance, seam_rms_tolerance) = seam_tolerance(tx);
        report.texture = Some(TextureCheck { seam_tolerance, seam_rms_tolerance, ..TextureCheck::default() });
    }
    let fail = |r: &mut VerifyReport, s: String| r.failures.push(s);

    // Structure.
    if ts["asset"]["version"] != "1.1" {
        fail(&mut report, "tileset.json: asset.version is not \"1.1\"".into());
    }
    let mut tiles: BTreeMap<ChunkKey, Vec<ChunkKey>> = BTreeMap::new();
    check_tile(&ts["root"], None, &extras, &mut tiles, &mut report.failures, "REPLACE");

    let sources: Vec<PathBuf> = match dem_override {
        Some(d) => d.to_vec(),
        None => extras.source.iter().map(PathBuf::from).collect(),
    };
    let opts = LoadOptions { vertical_scale: Some(extras.vertical_scale), spacing_m: Some(extras.spacing_m) };
    let hf = dem::load(&sources, &opts)?;
    if [hf.width as u32, hf.height as u32] != [extras.grid.width, extras.grid.height] {
        report.failures.push(format!(
            "DEM is {}×{} but the tileset was built from {}×{}",
            hf.width, hf.height, extras.grid.width, extras.grid.height
        ));
        return Ok(report);
    }

    // Down the tree, each chunk read once and checked against its parent
    // (error, coverage, morph, texture), then dropped but for what its
    // borders need; so only the chunks along the paths being walked are
    // held, not a level and its parents (California at 1 m: 8 192 chunks
    // each). Then level by level, as before: each chunk's findings in key
    // order, then the borders between same-level neighbours.
    let children: std::collections::BTreeSet<ChunkKey> = tiles.values().flatten().copied().collect();
    let roots: Vec<ChunkKey> = tiles.keys().filter(|k| !children.contains(k)).copied().collect();
    let bar = crate::progress::bar(progress, tiles.len() as u64, "chunks");
    let walk = Walk { dir, hf: &hf, extras: &extras, tiles: &tiles, bar: &bar };
    let found: Vec<Visited> = roots.par_iter().flat_map_iter(|&k| walk.visit(k, Parent::None)).collect();
    bar.finish_and_clear();
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

/// A read parent's surface as its children's morph checks read it: in grid
/// units, with the bucket index that finds the triangle under a point. Made
/// once for all its children: each child made its own before, and on
/// California's 2049² crop at 1 m those four indexes took a tenth of
/// `verify`'s time.
struct ParentSurface<'a> {
    file: &'a ChunkFile,
    verts: Vec<MeshVertex>,
    index: LocatorIndex,
}

impl<'a> ParentSurface<'a> {
    fn new(file: &'a ChunkFile, spacing: [f64; 2]) -> Self {
        let verts = file.surface.grid_vertices(spacing);
        let index = LocatorIndex::new(&verts, &file.surface.triangles);
        ParentSurface { file, verts, index }
    }

    fn locator(&self) -> SurfaceLocator<'_> {
        SurfaceLocator::with_index(&self.verts, &self.file.surface.triangles, &self.index)
    }
}

/// What every chunk's check reads.
struct Walk<'a> {
    dir: &'a Path,
    hf: &'a crate::heightfield::Heightfield,
    extras: &'a TilesetExtras,
    tiles: &'a BTreeMap<ChunkKey, Vec<ChunkKey>>,
    bar: &'a indicatif::ProgressBar,
}

impl Walk<'_> {
    /// Reads and checks chunk `k` against `parent`, then its subtree in
    /// parallel.
    fn visit(&self, k: ChunkKey, parent: Parent) -> Vec<Visited> {
        let path = self.dir.join(format!("tiles/{}/{}/{}.glb", k.level, k.x, k.y));
        let file = read_chunk(&path);
        let kids = &self.tiles[&k];
        let surface = match &file {
            Ok(c) if !kids.is_empty() => Some(ParentSurface::new(c, self.extras.spacing_m)),
            _ => None,
        };
        let kids_parent = surface.as_ref().map_or(Parent::Unreadable, Parent::Read);
        let mut out: Vec<Visited> = kids.par_iter().flat_map_iter(|&kid| self.visit(kid, kids_parent)).collect();
        out.push(match &file {
            Ok(c) => {
                let read = (c.key != k).then(|| format!("chunk {}: node extras say {:?}", name(k), c.key));
                let checked = Some(self.check(k, c, parent));
                Visited { key: k, read: read.into_iter().collect(), checked, borders: Some(border_record(c)) }
            }
            Err(e) => Visited { key: k, read: vec![format!("chunk {}: {e}", name(k))], checked: None, borders: None },
        });
        self.bar.inc(1);
        out
    }

    /// Error, coverage and morph of one chunk (against its parent), and its texture.
    fn check(&self, k: ChunkKey, c: &ChunkFile, parent: Parent) -> Findings {
        let extras = self.extras;
        let mut problems = Vec::new();
        let has_children = !self.tiles[&k].is_empty();
        let err = check_error(self.hf, c, extras.spacing_m, &mut problems);
        if !has_children && snap_error(c, err, extras.max_error_m) > extras.max_error_m {
            problems.push(format!("leaf error {err:.4} m exceeds max_error_m {}", extras.max_error_m));
        }
        let gap = match parent {
            Parent::Read(p) => check_morph(c, p, extras.spacing_m, &mut problems),
            Parent::Unreadable => 0.0,
            Parent::None => {
                let m = c.surface.morph_dy.iter().fold(0.0f64, |a, d| a.max(d.abs()));
                if m > 0.0 {
                    problems.push(format!("top-level chunk has nonzero morph deltas (up to {m} m)"));
                }
                m
            }
        };
        if !c.morph_contract {
            problems.push("mesh.weights is not [0] or targetNames is not [\"parent\"]".into());
        }
        let texel = extras.texture.as_ref().and_then(|tx| check_texture(c, extras, tx, &mut problems));
        let plan: Vec<[f64; 2]> = c.surface.positions.iter().map(|p| [p[0], p[2]]).collect();
        let shape = quality::summarize(&plan, &c.surface.triangles);
        Findings { delta_m: c.delta_m, error_m: err, morph_gap_m: gap, texel, shape, problems }
    }
}

/// Chunk `c` with only what [`compare_border`] and [`compare_seam`] read:
/// the surface vertices within a quarter cell of a footprint edge, the
/// triangles with an edge between two of them near the same edge (with
/// their far corners; all in their order), and the texture's edge texels. A vertex off the border is at least a quarter
/// cell from it unless it is a cut point near a corner, which is kept and
/// filtered out there as before; the comparison's own tolerance (at most
/// 10⁻⁴ of a cell plus the f32 rounding, well under a quarter cell for any
/// footprint a u16 or f32 chunk can have) selects among these exactly what
/// it selected among all, so the outcome is the same.
fn border_record(c: &ChunkFile) -> ChunkFile {
    let [x0, x1, z0, z1] = c.footprint.map(f64::from);
    let [sx, sz] = c.spacing_m;
    let near = |p: &[f64; 3]| -> [bool; 4] {
        [
            (p[0] - x0 * sx).abs() <= 0.25 * sx,
            (p[0] - x1 * sx).abs() <= 0.25 * sx,
            (p[2] - z0 * sz).abs() <= 0.25 * sz,
            (p[2] - z1 * sz).abs() <= 0.25 * sz,
        ]
    };
    let s = &c.surface;
    let bands: Vec<[bool; 4]> = s.positions.iter().map(near).collect();
    let along_an_edge = |t: &&[u32; 3]| {
        (0..3).any(|e| {
            let (u, v) = (bands[t[e] as usize], bands[t[(e + 1) % 3] as usize]);
            (0..4).any(|l| u[l] && v[l])
        })
    };
    let kept: Vec<[u32; 3]> = s.triangles.iter().filter(along_an_edge).copied().collect();
    // The vertices near an edge and the far corners of those triangles, in
    // their order.
    let mut keep: Vec<bool> = bands.iter().map(|b| b.iter().any(|&x| x)).collect();
    for t in &kept {
        for &i in t {
            keep[i as usize] = true;
        }
    }
    let mut remap = vec![u32::MAX; s.positions.len()];
    let mut positions = Vec::new();
    for (i, p) in s.positions.iter().enumerate() {
        if keep[i] {
            remap[i] = positions.len() as u32;
            positions.push(*p);
        }
    }
    let triangles = kept.iter().map(|t| t.map(|i| remap[i as usize])).collect();
    ChunkFile {
        key: c.key,
        delta_m: c.delta_m,
        footprint: c.footprint,
        translation: c.translation,
        spacing_m: c.spacing_m,
        surface: Prim { positions, triangles, local_extent: s.local_extent, ..Prim::default() },
        skirt: None,
        morph_contract: c.morph_contract,
        texture: c.texture.clone(),
        quantization_m: c.quantization_m,
    }
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

/// The texture of one chunk: texel size against δ/τ_max and the source,
/// TEXCOORDs against the footprint, material and sampler. Returns T_g and
/// why it may exceed the bound.
fn check_texture(
    c: &ChunkFile,
    ex: &TilesetExtras,
    tx: &TextureExtras,
    problems: &mut Vec<String>,
) -> Option<(f64, Texel)> {
    let Some(t) = &c.texture else {
        problems.push("has no base colour texture, but the tileset says its chunks are textured".into());
        return None;
    };
    problems.extend(t.contract.iter().cloned());
    let [x0, x1, z0, z1] = c.footprint;
    let extents = [f64::from(x1 - x0) * ex.spacing_m[0], f64::from(z1 - z0) * ex.spacing_m[1]];
    let bound_m = c.delta_m / ex.tau_max_px;
    let level = tx.levels.iter().find(|l| l.level == c.key.level);
    let cap_stated = level.is_some_and(|l| l.limit == Limit::MaxTexturePx && !l.bound_holds);
    let judge = |what: &str, img: &ImageEdges, source_m: [f64; 2], problems: &mut Vec<String>| {
        let mut worst = (0.0f64, Texel::Bound);
        for (a, n) in [img.width, img.height].into_iter().enumerate() {
            let texel_m = extents[a] / f64::from(n - 1);
            let axis = ["across", "down"][a];
            if n > 2 && texel_m < source_m[a] * (1.0 - 1e-9) {
                problems.push(format!(
                    "{what} texels {axis} are {texel_m:.4} m apart, finer than the source's {:.4} m",
                    source_m[a]
                ));
            }
            let why = if texel_m <= bound_m * (1.0 + 1e-9) {
                Texel::Bound
            } else if extents[a] / f64::from(n) < source_m[a] * (1.0 + 1e-9) {
                Texel::AtSource // one more texel would be finer than the source
            } else if n == tx.max_texture_px && cap_stated {
                Texel::Capped
            } else {
                problems.push(format!(
                    "{what} T_g {axis} = {texel_m:.4} m exceeds δ/τ_max = {bound_m:.4} m with {n} texels,                      though neither its source nor a stated max_texture_px stops a larger tile"
                ));
                Texel::Bound
            };
            if texel_m > worst.0 {
                worst.0 = texel_m;
            }
            worst.1 = if why > worst.1 { why } else { worst.1 };
        }
        worst
    };
    let found = judge("colour", &t.colour, tx.source_texel_m, problems);
    let mut sets = vec![(0u32, [t.colour.width, t.colour.height])];
    if let Some((nm, set)) = &t.normal {
        judge("normal map", nm, ex.spacing_m, problems);
        if *set == 0 && [nm.width, nm.height] != [t.colour.width, t.colour.height] {
            problems.push("the normal map uses TEXCOORD_0 but differs in size from the colour".into());
        }
        if *set == 1 {
            sets.push((1, [nm.width, nm.height]));
        }
    }
    for (role, prim) in std::iter::once(("surface", &c.surface)).chain(c.skirt.iter().map(|s| ("skirt", s))) {
        for &(set, texels) in &sets {
            let uv = if set == 0 { &prim.uv } else { &prim.uv1 };
            // u16 normalized coordinates round by half of 1/65535. (The
            // coordinate is made from the position as written, on the grid:
            // `Frame::on_grid`.)
            let rounding = c.quantization_m.map_or(0.0, |_| 0.5 / 65535.0);
            if let Some(p) = check_uv(prim, uv, c.footprint, ex.spacing_m, texels, rounding) {
                problems.push(format!("{role} TEXCOORD_{set}: {p}"));
            }
        }
    }
    Some(found)
}

/// Every vertex's TEXCOORD lies in [0, 1] at
/// `(½ + (n − 1)·(x − x0)/(x1 − x0)) / n` (and likewise for z): the
/// footprint mapped exactly onto the texel centres.
fn check_uv(
    prim: &Prim,
    uv: &[[f32; 2]],
    fp: [u32; 4],
    spacing: [f64; 2],
    texels: [u32; 2],
    rounding: f64,
) -> Option<String> {
    if uv.len() != prim.positions.len() {
        return Some(format!("{} coordinates for {} vertices", uv.len(), prim.positions.len()));
    }
    let [x0, x1, z0, z1] = fp;
    let spans = [(x0, x1), (z0, z1)];
    // f32 rounding of the chunk-local position, then of the coordinate.
    let tol = |a: usize| {
        let cells = f64::from(spans[a].1 - spans[a].0);
        1e-6 + rounding + 8.0 * f64::from(f32::EPSILON) * prim.local_extent[2 * a] / spacing[a] / cells
    };
    for (p, t) in prim.positions.iter().zip(uv) {
        for a in 0..2 {
            let (lo, hi) = spans[a];
            let n = f64::from(texels[a]);
            let g = p[2 * a] / spacing[a];
            let want = (0.5 + (n - 1.0) * (g - f64::from(lo)) / f64::from(hi - lo)) / n;
            let got = f64::from(t[a]);
            if !(0.0..=1.0).contains(&got) || (got - want).abs() > tol(a) {
                return Some(format!(
                    "vertex at ({:.3}, {:.3}) m has {} = {got}, expected {want} (footprint onto the texel centres)",
                    p[0],
                    p[2],
                    ["u", "v"][a]
                ));
            }
        }
    }
    None
}

/// The border texels of `a` and its east or south neighbour `b`: the same
/// number, and equal within the format's tolerance.
fn compare_seam(a: &ChunkFile, b: &ChunkFile, east: bool, tc: &mut TextureCheck) -> Result<(), String> {
    let (Some(ta), Some(tb)) = (&a.texture, &b.texture) else {
        return Ok(()); // reported per chunk
    };
    let mut pairs = vec![("colour", &ta.colour, &tb.colour, tc.seam_tolerance, tc.seam_rms_tolerance)];
    if let (Some((na, _)), Some((nb, _))) = (&ta.normal, &tb.normal) {
        pairs.push(("normal map", na, nb, 0, 0.0)); // always PNG
    }
    for (what, ia, ib, tol, rms_tol) in pairs {
        let (ea, eb) = if east { (&ia.east, &ib.west) } else { (&ia.south, &ib.north) };
        if ea.len() != eb.len() {
            return Err(format!("{what}: {} vs {} texels along the shared edge", ea.len(), eb.len()));
        }
        let diffs: Vec<u8> = ea.iter().zip(eb).flat_map(|(p, q)| (0..3).map(|c| p[c].abs_diff(q[c]))).collect();
        let diff = diffs.iter().copied().max().unwrap_or(0);
        let rms = (diffs.iter().map(|&d| f64::from(d).powi(2)).sum::<f64>() / diffs.len().max(1) as f64).sqrt();
        if what == "colour" {
            tc.max_seam_diff = tc.max_seam_diff.max(diff);
            tc.max_seam_rms = tc.max_seam_rms.max(rms);
        }
        if diff > tol || rms > rms_tol {
            return Err(format!(
                "{what}: border texels differ by up to {diff}, RMS {rms:.2} (allowed {tol}, RMS {rms_tol:.2})"
            ));
        }
    }
    Ok(())
}

/// `L/x/y`.
pub fn name(k: ChunkKey) -> String {
    format!("{}/{}/{}", k.level, k.x, k.y)
}

fn check_tile(
    t: &Value,
    parent: Option<(ChunkKey, f64)>,
    extras: &TilesetExtras,
    tiles: &mut BTreeMap<ChunkKey, Vec<ChunkKey>>,
    failures: &mut Vec<String>,
    inherited_refine: &str,
) -> Option<ChunkKey> {
    let refine = t["refine"].as_str().unwrap_or(inherited_refine);
    if refine != "REPLACE" {
        failures.push(format!("tile refine is {refine}, not REPLACE"));
    }
    let ge = t["geometricError"].as_f64();
    let bx = t["boundingVolume"]["box"].as_array().filter(|b| b.len() == 12);
    if ge.is_none() || bx.is_none() {
        failures.push("a tile lacks geometricError or boundingVolume.box".into());
    }
    let mut me = None;
    if t.get("content").is_some() {
        match serde_json::from_value::<TileExtras>(t["extras"]["terrachunk"].clone()) {
            Ok(te) => {
                let k = ChunkKey { level: te.level, x: te.x, y: te.y };
                let uri = format!("tiles/{}/{}/{}.glb", k.level, k.x, k.y);
                if t["content"]["uri"] != uri.as_str() {
                    failures.push(format!("tile {}: content uri is {}", name(k), t["content"]["uri"]));
                }
                let want = extras.delta_m.get(k.level as usize).copied().unwrap_or(f64::NAN);
                if ge != Some(te.delta_m) || te.delta_m != want {
                    failures.push(format!(
                        "tile {}: geometricError {:?} / delta_m {} but level δ is {want}",
                        name(k),
                        ge,
                        te.delta_m
                    ));
                }
                if let Some((pk, pd)) = parent {
                    if k.level != pk.level + 1 || (te.delta_m * 2.0 - pd).abs() > 1e-9 * pd {
                        failures.push(format!(
                            "tile {}: δ {} does not halve its parent {}'s δ {pd}",
                            name(k),
                            te.delta_m,
                            name(pk)
                        ));
                    }
                    if let Some(e) = tiles.get_mut(&pk) {
                        e.push(k);
                    }
                }
                // Its children, as they are found (not a copy of the tile:
                // that held each subtree once per tile above it).
                tiles.insert(k, Vec::new());
                me = Some((k, te.delta_m));
            }
            Err(e) => failures.push(format!("tile without valid extras.terrachunk: {e}")),
        }
    }
    if let Some(children) = t["children"].as_array() {
        for c in children {
            check_tile(c, me.or(parent.filter(|_| me.is_some())), extras, tiles, failures, refine);
        }
    }
    me.map(|m| m.0)
}

/// Largest |surface − sample| over the footprint; records uncovered samples
/// and vertices outside the footprint.
fn check_error(hf: &Heightfield, c: &ChunkFile, spacing: [f64; 2], problems: &mut Vec<String>) -> f64 {
    let [x0, x1, z0, z1] = c.footprint;
    if x1 as usize >= hf.width || z1 as usize >= hf.height || x0 >= x1 || z0 >= z1 {
        problems.push(format!("footprint {:?} is outside the {}×{} grid", c.footprint, hf.width, hf.height));
        return f64::INFINITY;
    }
    let verts = c.surface.grid_vertices(spacing);
    let tol = 1e-4 * ((x1 - x0) + (z1 - z0)) as f64;
    if verts.iter().any(|v| {
        v.x < f64::from(x0) - tol || v.x > f64::from(x1) + tol || v.z < f64::from(z0) - tol || v.z > f64::from(z1) + tol
    }) {
        problems.push("a surface vertex lies outside the footprint".into());
    }
    // Each sample's error is taken from the triangle that fits it best: on a
    // shared edge all agree, and a zero-width sliver's neighbour must not
    // count a vertex it merely touches (within f32 rounding) against it.
    let w = (x1 - x0 + 1) as usize;
    let mut best = vec![f64::INFINITY; w * (z1 - z0 + 1) as usize];
    let (mut over_nodata, mut turned) = (0, 0);
    for t in &c.surface.triangles {
        let tri = t.map(|i| verts[i as usize]);
        turned += usize::from(turned_over(&tri));
        let alone = scan_written(hf, &tri, c.footprint, |i, j, e| {
            let best = &mut best[(i - z0 as usize) * w + (j - x0 as usize)];
            *best = best.min(e);
        });
        over_nodata += usize::from(alone);
    }
    if over_nodata > 0 {
        problems.push(format!("{over_nodata} triangles stand over nodata alone"));
    }
    if turned > 0 {
        problems.push(format!("{turned} triangles are turned over (wound against the rest in plan)"));
    }
    let covered: Vec<bool> = best.iter().map(|e| e.is_finite()).collect();
    let max_err = best.iter().copied().filter(|e| e.is_finite()).fold(0.0, f64::max);
    let mut uncovered = 0;
    for i in z0..=z1 {
        for j in x0..=x1 {
            if !hf.get(i as usize, j as usize).is_nan() && !covered[(i - z0) as usize * w + (j - x0) as usize] {
                uncovered += 1;
            }
        }
    }
    if uncovered > 0 {
        problems.push(format!("{uncovered} valid samples are not covered by any triangle"));
    }
    let max_err = snap_error(c, max_err, c.delta_m);
    if max_err > c.delta_m {
        problems.push(format!("error {max_err:.4} m exceeds δ {} m", c.delta_m));
    }
    max_err
}

/// Scans triangle `tri` (grid units, as read back) over the samples of
/// `footprint`: calls `valid(i, j, error)` for each valid sample within f32
/// rounding (10⁻⁴ grid units) of it, and says whether it stands over
/// nodata alone: no valid sample that near, and a nodata sample inside it
/// by more than that. A nodata sample only that near its edge is no more
/// covered by it than by the triangle across the edge (Seamount at 1 m,
/// 32-cell leaves: a cut piece 0.08 cells wide passed 9·10⁻⁵ cells from
/// one, which the mesher, meshing in f64, rightly saw outside it).
fn scan_written(
    hf: &Heightfield,
    tri: &[MeshVertex; 3],
    footprint: [u32; 4],
    mut valid: impl FnMut(usize, usize, f64),
) -> bool {
    const ROUNDING: f64 = 1e-4;
    let [x0, x1, z0, z1] = footprint.map(f64::from);
    let [a, b, d] = tri;
    let (zlo, zhi) = (a.z.min(b.z).min(d.z), a.z.max(b.z).max(d.z));
    let (xlo, xhi) = (a.x.min(b.x).min(d.x), a.x.max(b.x).max(d.x));
    let rows = ((zlo - ROUNDING).ceil().max(z0), (zhi + ROUNDING).floor().min(z1));
    let cols = ((xlo - ROUNDING).ceil().max(x0), (xhi + ROUNDING).floor().min(x1));
    let (mut any_valid, mut nodata_inside) = (false, false);
    points_near_triangle(tri, rows, cols, ROUNDING, |i, j, h| {
        let s = hf.get(i, j);
        if s.is_nan() {
            nodata_inside = nodata_inside || inside_by(tri, j as f64, i as f64, ROUNDING);
        } else {
            any_valid = true;
            valid(i, j, (h - f64::from(s)).abs());
        }
    });
    nodata_inside && !any_valid
}

/// Whether triangle `tri` (grid units, as read back, in file order) is
/// wound the wrong way in plan: the surface folds over itself there, drawn
/// twice or, with back faces culled, not at all. Chunks are written
/// counter-clockwise seen from above (+y), which in x-east, z-south grid
/// space is a negative signed area; a zero area (two corners on one point,
/// as a quantized file may put close crossings) is not turned.
fn turned_over([a, b, c]: &[MeshVertex; 3]) -> bool {
    let o = robust::orient2d(
        robust::Coord { x: a.x, y: a.z },
        robust::Coord { x: b.x, y: b.z },
        robust::Coord { x: c.x, y: c.z },
    );
    o > 0.0
}

/// Whether (x, z) lies inside triangle `tri` by more than `margin` from
/// each of its edges (never, for a triangle with no area).
fn inside_by(tri: &[MeshVertex; 3], x: f64, z: f64, margin: f64) -> bool {
    let [a, b, c] = tri;
    let area = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
    if area == 0.0 {
        return false;
    }
    [(a, b), (b, c), (c, a)].iter().all(|(p, q)| {
        let len = (q.x - p.x).hypot(q.z - p.z);
        let cross = (q.x - p.x) * (z - p.z) - (q.z - p.z) * (x - p.x);
        cross * area.signum() > margin * len
    })
}

/// What f64 arithmetic may add to an error measured over chunk `c`: this
/// interpolation and the mesher's own (which found a sample exactly δ off
/// within δ) each round by a few units in the last place of the heights
/// involved; 256 of them is ample and far below any real error (4·10⁻¹⁰ m
/// at 3 km). An error within that of a bound is the bound, as a coordinate
/// within f32 rounding of a sample index is that index.
fn snap_error(c: &ChunkFile, err: f64, bound: f64) -> f64 {
    let (lo, hi) = c
        .surface
        .positions
        .iter()
        .map(|p| p[1])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| (lo.min(h), hi.max(h)));
    let slack = if lo > hi { 0.0 } else { 256.0 * f64::EPSILON * (lo.abs().max(hi.abs()) + (hi - lo)) };
    if err > bound && err <= bound + slack { bound } else { err }
}

/// Morph targets on the parent surface; child triangles inside parent ones.
fn check_morph(c: &ChunkFile, parent: &ParentSurface, spacing: [f64; 2], problems: &mut Vec<String>) -> f64 {
    let (p, pv, loc) = (parent.file, &parent.verts, parent.locator());
    // f32 rounding of both chunks' chunk-local coordinates: horizontally (in
    // metres and in grid units), where a slope turns it into a height
    // difference, and vertically.
    let [rx, ry, rz] = [0, 1, 2].map(|a| f32_rounding(c, p)[a] + half_steps(c, p, a));
    let round_grid = (rx / spacing[0]).max(rz / spacing[1]);
    let allowed = |t: u32| {
        let [gx, gz] = plane_gradient(p.surface.triangles[t as usize].map(|i| pv[i as usize]), spacing);
        1e-5 + 2.0 * ry + gx.abs() * rx + gz.abs() * rz
    };
    let (mut gap, mut worst_excess): (f64, f64) = (0.0, 0.0);
    let mut missing = 0;
    let cv = c.surface.grid_vertices(spacing);
    let skirt_tops: Vec<(MeshVertex, f64)> = c
        .skirt
        .iter()
        .flat_map(|s| s.grid_vertices(spacing).into_iter().zip(s.morph_dy.iter().copied()))
        .filter(|(_, dy)| *dy != 0.0)
        .collect();
    for (v, dy) in cv.iter().copied().zip(c.surface.morph_dy.iter().copied()).chain(skirt_tops) {
        // The vertex truly lies in one of the parent triangles within the
        // rounding of where it was read; the one that explains its target
        // best decides (on a crease, the triangle it was read into may be
        // the neighbour of the one it is on).
        // The gap reported is the smallest over those triangles: the one
        // with the most allowance may be a steep sliver whose plane, read a
        // rounding away, says nothing of how far the target is (Sierra
        // N36W119 with `quantize`: 103 m "gaps" beside clustered cut points,
        // where the vertex sat exactly on the parent surface).
        // A sliver's plane is not read from its gradient (which says
        // nothing a rounding away, see above) but from the heights it takes
        // within rounding of the vertex: the target may be any of them (DFW
        // at 2 m, 16-cell leaves: a parent sliver 6·10⁻⁵ cells wide rose
        // 5 m across, and the child's vertex on it read 0.1 m "off").
        let target = v.h + dy;
        let best = loc
            .near(v.x, v.z, round_grid)
            .into_iter()
            .map(|(t, h)| {
                let g = (target - h).abs();
                let excess = g - allowed(t);
                if excess <= 0.0 {
                    return (excess, g);
                }
                let corners = p.surface.triangles[t as usize].map(|i| pv[i as usize]);
                let within = heights_within(corners, (v.x, v.z), [rx / spacing[0], rz / spacing[1]])
                    .map_or(f64::INFINITY, |(lo, hi)| (lo - target).max(target - hi).max(0.0) - 1e-5 - 2.0 * ry);
                (excess.min(within), g)
            })
            .reduce(|a, b| (a.0.min(b.0), a.1.min(b.1)));
        match best {
            Some((excess, g)) => {
                gap = gap.max(g);
                worst_excess = worst_excess.max(excess);
            }
            None => missing += 1,
        }
    }
    if missing > 0 {
        problems.push(format!("{missing} vertices lie outside the parent {}'s surface", name(p.key)));
    }
    let mut straddling = 0;
    for t in &c.surface.triangles {
        let child = t.map(|i| cv[i as usize]);
        let [a, b, d] = child;
        let (cx, cz) = ((a.x + b.x + d.x) / 3.0, (a.z + b.z + d.z) / 3.0);
        if let Some((pt, _)) = loc.locate(cx, cz, round_grid) {
            let parent = p.surface.triangles[pt as usize].map(|i| pv[i as usize]);
            if straddles(child, parent, 1e-4 + 2.0 * round_grid) {
                straddling += 1;
            }
        }
    }
    if straddling > 0 {
        problems.push(format!("{straddling} triangles straddle an edge of the parent {}", name(p.key)));
    }
    if worst_excess > 0.0 {
        problems.push(format!(
            "morph target misses the parent {} surface by {gap:.6} m (beyond f32 rounding)",
            name(p.key)
        ));
    }
    if c.surface.morph_dxz != 0.0 {
        problems.push("morph target has nonzero x/z deltas".into());
    }
    gap
}

/// Whether a child triangle reaches more than `tol` grid units outside the
/// parent triangle that holds its centroid, i.e. straddles one of its
/// edges. A sliver whose height over its longest side is within `tol` has
/// no inside to straddle with: it is a segment as far as the rounding can
/// tell, and which side of a parent edge its centroid reads on is noise.
/// Such slivers come from cut points: one on the line through two collinear
/// parent edges makes a zero-area child triangle with their shared vertex,
/// whose f64 coordinates leave it a hair of area (Sierra N36W119 at 1 m,
/// `quantize`). Its corners are checked on the parent surface like every
/// vertex, and it covers no sample the triangles beside it do not.
fn straddles(child: [MeshVertex; 3], parent: [MeshVertex; 3], tol: f64) -> bool {
    let [a, b, d] = child;
    let twice_area = ((b.x - a.x) * (d.z - a.z) - (d.x - a.x) * (b.z - a.z)).abs();
    // Compared squared: grid coordinates are far from overflow, and no root
    // is needed (this runs once per child triangle).
    let side2 = |p: &MeshVertex, q: &MeshVertex| (p.x - q.x).powi(2) + (p.z - q.z).powi(2);
    let longest2 = side2(&a, &b).max(side2(&b, &d)).max(side2(&d, &a));
    if twice_area * twice_area <= tol * tol * longest2 {
        return false;
    }
    let [pa, pb, pd] = parent;
    child.iter().any(|v| barycentric(&pa, &pb, &pd, v.x, v.z).0 > tol)
}

/// The f32 rounding, metres, of positions written chunk-local in two chunks,
/// per axis (x, y, z) from that axis' extent: with 1 mm cells under 400 m of
/// relief, or 1 mm by 10 km cells, the axes differ by orders of magnitude.
fn f32_rounding(a: &ChunkFile, b: &ChunkFile) -> [f64; 3] {
    let four_eps = 4.0 * f64::from(f32::EPSILON);
    [0, 1, 2].map(|k| four_eps * (a.surface.local_extent[k] + b.surface.local_extent[k]))
}

/// Half the quantization steps of two chunks along axis `a`, metres (0 for
/// f32 files): how far each may have rounded one vertex.
fn half_steps(a: &ChunkFile, b: &ChunkFile, axis: usize) -> f64 {
    [a, b].iter().map(|c| c.quantization_m.map_or(0.0, |s| s[axis] / 2.0)).sum()
}

/// The lowest and highest heights triangle `t` (grid units) takes within
/// the box of half-widths `half` (grid units) around `at`, or `None` if
/// none of it lies there: its plane's extremes over the triangle clipped
/// to the box, at the clipped polygon's corners, each interpolated along a
/// segment (no barycentric weights, which a sliver makes ill-conditioned).
fn heights_within(t: [MeshVertex; 3], at: (f64, f64), half: [f64; 2]) -> Option<(f64, f64)> {
    let mut poly: Vec<[f64; 3]> = t.iter().map(|v| [v.x, v.z, v.h]).collect();
    let sides =
        [(0, at.0 - half[0], 1.0), (0, at.0 + half[0], -1.0), (1, at.1 - half[1], 1.0), (1, at.1 + half[1], -1.0)];
    for (axis, bound, sign) in sides {
        let inside = |p: &[f64; 3]| sign * (p[axis] - bound) >= 0.0;
        let mut out = Vec::with_capacity(poly.len() + 1);
        for (k, p) in poly.iter().enumerate() {
            let q = &poly[(k + 1) % poly.len()];
            if inside(p) {
                out.push(*p);
            }
            if inside(p) != inside(q) {
                let s = (bound - p[axis]) / (q[axis] - p[axis]);
                out.push([0, 1, 2].map(|c| p[c] + s * (q[c] - p[c])));
            }
        }
        poly = out;
        if poly.is_empty() {
            return None;
        }
    }
    Some(poly.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[2]), hi.max(p[2]))))
}

/// Gradient `[∂h/∂x, ∂h/∂z]` (m per m) of a triangle given in grid coordinates.
fn plane_gradient(t: [MeshVertex; 3], spacing: [f64; 2]) -> [f64; 2] {
    let [a, b, c] = t.map(|v| [v.x * spacing[0], v.z * spacing[1], v.h]);
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if det.abs() < 1e-3 * spacing[0] * spacing[1] {
        return [0.0; 2]; // a sliver: no vertex is located in it (see SurfaceLocator)
    }
    let gx = ((b[2] - a[2]) * (c[1] - a[1]) - (c[2] - a[2]) * (b[1] - a[1])) / det;
    let gz = ((b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2])) / det;
    [gx, gz]
}

/// Compares the shared edge of `a` and its east (`east`) or south
/// neighbour `b`: wherever one chunk has a vertex strictly inside an edge the
/// other chunk draws along the line, that is a T-junction (a crack), and
/// vertices at the same place must have the same height. Stretches over
/// nodata that only one side draws are not compared.
fn compare_border(a: &ChunkFile, b: &ChunkFile, east: bool, spacing: [f64; 2]) -> Option<String> {
    let (line, axis, along) = if east { (a.footprint[1], 0, 2) } else { (a.footprint[3], 2, 0) };
    let (s_across, s_along) = if east { (spacing[0], spacing[1]) } else { (spacing[1], spacing[0]) };
    let c = f64::from(line) * s_across;
    // Positions: 0.1 mm, or 1e-4 of a cell where cells are smaller than a
    // metre, plus the f32 rounding of that axis; heights: their own rounding.
    let round = f32_rounding(a, b);
    let tol = 1e-4 * s_across.min(1.0) + round[axis];
    let tol_along = 1e-4 * s_along.min(1.0) + round[along];
    // Vertices on the line, and the edges along it (as index pairs).
    let on_line = |f: &ChunkFile| {
        let on: Vec<bool> = f.surface.positions.iter().map(|p| (p[axis] - c).abs() <= tol).collect();
        let mut edges = Vec::new();
        for t in &f.surface.triangles {
            for e in 0..3 {
                let (u, v) = (t[e] as usize, t[(e + 1) % 3] as usize);
                if on[u] && on[v] {
                    let (pu, pv) = (f.surface.positions[u], f.surface.positions[v]);
                    edges.push(if pu[along] <= pv[along] { (pu, pv) } else { (pv, pu) });
                }
            }
        }
        let verts: Vec<[f64; 3]> = f.surface.positions.iter().zip(&on).filter(|(_, o)| **o).map(|(p, _)| *p).collect();
        (verts, edges)
    };
    let (va, ea) = on_line(a);
    let (vb, eb) = on_line(b);
    // Compare the vertices that lie where both chunks draw an edge: each
    // must have one at its place in the other chunk, at its height. A
    // T-junction shows as a vertex with none at its place, a moved vertex
    // as one with none at its place or at its height.
    let drawn = |t: f64, edges: &[([f64; 3], [f64; 3])]| {
        edges.iter().any(|(u, v)| t >= u[along] - tol_along && t <= v[along] + tol_along)
    };
    let common = |verts: Vec<[f64; 3]>| {
        let mut v: Vec<[f64; 3]> = verts.into_iter().filter(|p| drawn(p[along], &ea) && drawn(p[along], &eb)).collect();
        v.sort_by(|p, q| p[along].total_cmp(&q[along]));
        v
    };
    let (ca, cb) = (common(va), common(vb));
    // Each side against the other, not one by one in order: distinct
    // vertices closer together than the f32 rounding (cut points where many
    // parent edges meet a line) read back in either order, at one place or
    // a rounding apart, and with heights a rounding apart or equal, each
    // chunk by its own rounding. Counting them after merging those within
    // the rounding (as this did) counted two on one side and one on the
    // other wherever their true height difference lay at the rounding
    // (Sierra 3 × 3 at 5 m with 32-cell leaves: 5 pairs of chunks).
    let slack = 10.0 * round[1] + 1e-3;
    let unmatched = |x: &[[f64; 3]], y: &[[f64; 3]]| -> Option<String> {
        x.iter().find_map(|p| {
            let from = y.partition_point(|q| q[along] < p[along] - tol_along);
            let place = y[from..].iter().take_while(|q| q[along] <= p[along] + tol_along);
            match place.min_by(|q, r| (q[1] - p[1]).abs().total_cmp(&(r[1] - p[1]).abs())) {
                None => {
                    Some(format!("border vertex {p:?} has none at its place across the shared edge (a T-junction)"))
                }
                Some(q) if (q[1] - p[1]).abs() > slack => Some(format!("border vertex {p:?} vs {q:?}")),
                Some(_) => None,
            }
        })
    };
    unmatched(&ca, &cb).or_else(|| unmatched(&cb, &ca))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The border comparisons give the same answer on chunks cut down to
    /// their borders as on the whole chunks, on a real build (untextured,
    /// `quantize` as well) and where a vertex was moved or one dropped.
    #[test]
    fn borders_compare_alike_on_whole_chunks_and_their_border_records() {
        use crate::config::{Compress, Config};
        use crate::pipeline::{BuildOptions, build};
        use crate::texture::TextureSource;
        let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/dfw_texas_srtm3.tif");
        for compress in [Compress::None, Compress::Quantize] {
            let tmp = tempfile::tempdir().unwrap();
            let out = tmp.path().join("out");
            let config = Config { max_error_m: 1.0, compress, ..Config::default() };
            let options = BuildOptions {
                inputs: vec![dem.clone()],
                out: out.clone(),
                force: false,
                config,
                texture: TextureSource::None,
                progress: false,
            };
            build(&options).unwrap();
            let mut chunks = BTreeMap::new();
            for level in std::fs::read_dir(out.join("tiles")).unwrap() {
                for x in std::fs::read_dir(level.unwrap().path()).unwrap() {
                    for f in std::fs::read_dir(x.unwrap().path()).unwrap() {
                        let c = read_chunk(&f.unwrap().path()).unwrap();
                        chunks.insert(c.key, c);
                    }
                }
            }
            let spacing = chunks.values().next().unwrap().spacing_m;
            let (mut compared, mut lifted_ones) = (0, 0);
            for (k, a) in &chunks {
                for east in [true, false] {
                    let nk = ChunkKey { x: k.x + u32::from(east), y: k.y + u32::from(!east), ..*k };
                    let Some(b) = chunks.get(&nk) else { continue };
                    // As built; one border vertex of `a` lifted 0.5 m; one
                    // of its triangles along the border dropped.
                    let line = if east {
                        f64::from(a.footprint[1]) * spacing[0]
                    } else {
                        f64::from(a.footprint[3]) * spacing[1]
                    };
                    let axis = if east { 0 } else { 2 };
                    let cell = spacing[axis / 2];
                    let on = a.surface.positions.iter().position(|p| (p[axis] - line).abs() < 1e-3 * cell);
                    let mut lifted = a.clone();
                    let mut dropped = a.clone();
                    if let Some(i) = on {
                        lifted.surface.positions[i][1] += 0.5;
                        let t = dropped.surface.triangles.iter().position(|t| t.contains(&(i as u32))).unwrap();
                        dropped.surface.triangles.remove(t);
                    }
                    for a in [a, &lifted, &dropped] {
                        let whole = compare_border(a, b, east, spacing);
                        let cut = compare_border(&border_record(a), &border_record(b), east, spacing);
                        assert_eq!(whole, cut, "{k:?} east {east}");
                    }
                    if on.is_some() {
                        assert!(compare_border(&lifted, b, east, spacing).is_some(), "a lifted vertex is a failure");
                        lifted_ones += 1;
                    }
                    compared += 1;
                }
            }
            assert!(compared > 20 && lifted_ones * 2 > compared, "{compared} borders, {lifted_ones} lifted");
        }
    }

    /// California at 1 m (f32, textured; stop 29 and 30 builds): chunks
    /// 6/37/4 and 6/37/5 share the line z = 375, where crowded cut points
    /// put two vertices at x = 2456.5113 in each. Read back, chunk 4 has
    /// them 4 µm apart in height and chunk 5 at one height, so exact
    /// de-duplication counted 135 against 134 and `verify` failed the
    /// build with a T-junction that is not there (as it did three more
    /// pairs of chunks below them and 6/127/38–39 with theirs).
    #[test]
    fn two_border_vertices_a_rounding_apart_are_one_point_of_the_border() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/verify");
        let a = read_chunk(&dir.join("california_1m_6_37_4.glb")).unwrap();
        let b = read_chunk(&dir.join("california_1m_6_37_5.glb")).unwrap();
        assert_eq!((a.key, b.key.y), (ChunkKey { level: 6, x: 37, y: 4 }, 5));
        let spacing = a.spacing_m;
        let line = f64::from(a.footprint[3]) * spacing[1];
        let near = |c: &ChunkFile| {
            let mut h: Vec<f64> = c
                .surface
                .positions
                .iter()
                .filter(|p| (p[2] - line).abs() < 1e-3 && (p[0] / spacing[0] - 2456.5113).abs() < 1e-4)
                .map(|p| p[1])
                .collect();
            h.sort_by(f64::total_cmp);
            h
        };
        // The case as read back: two vertices each side, apart in one only.
        let (ha, hb) = (near(&a), near(&b));
        assert_eq!((ha.len(), hb.len()), (2, 2));
        assert!(ha[1] - ha[0] > 1e-6 && hb[1] == hb[0], "{ha:?} {hb:?}");
        assert_eq!(compare_border(&a, &b, false, spacing), None);
        assert_eq!(compare_border(&border_record(&a), &border_record(&b), false, spacing), None);
        // A border vertex taken out of one side (its triangles joined to a
        // neighbour on the line) is still a T-junction.
        let mut dropped = b.clone();
        let pos = &dropped.surface.positions;
        let x = |i: usize| pos[i][0] / spacing[0];
        let on: Vec<usize> = (0..pos.len()).filter(|&i| (pos[i][2] - line).abs() < 1e-3).collect();
        // A sample's vertex mid-line, and the next one along it.
        let gone = *on
            .iter()
            .filter(|&&i| (x(i) - x(i).round()).abs() < 1e-6 && x(i) > 2458.0)
            .min_by(|&&i, &&j| x(i).total_cmp(&x(j)))
            .unwrap();
        let keep = *on.iter().filter(|&&i| x(i) > x(gone) + 1e-3).min_by(|&&i, &&j| x(i).total_cmp(&x(j))).unwrap();
        for t in dropped.surface.triangles.iter_mut() {
            for k in t.iter_mut() {
                if *k == gone as u32 {
                    *k = keep as u32;
                }
            }
        }
        dropped.surface.positions[gone] = [f64::NAN; 3];
        let found = compare_border(&a, &dropped, false, spacing);
        assert!(found.as_deref().is_some_and(|m| m.contains("T-junction")), "{found:?}");
    }

    /// Sierra 3 × 3 at 5 m with 32-cell leaves (f32): chunks 6/15/5 and
    /// 6/15/6 share row 337, where two cut points lie 0.004 m apart at
    /// heights 0.5 mm apart: within the f32 rounding of heights in one
    /// chunk's reading, just past it in the other's. Merging the vertices
    /// within the rounding before counting counted 49 against 50, and
    /// `verify` failed the build with a T-junction that is not there (five
    /// pairs of chunks). The same here on California's pair: its two
    /// vertices at x = 2456.5113 set 1.5 roundings apart in one chunk and
    /// half a rounding in the other.
    #[test]
    fn border_vertices_a_rounding_apart_in_one_chunk_only_make_no_t_junction() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/verify");
        let mut a = read_chunk(&dir.join("california_1m_6_37_4.glb")).unwrap();
        let mut b = read_chunk(&dir.join("california_1m_6_37_5.glb")).unwrap();
        let spacing = a.spacing_m;
        let line = f64::from(a.footprint[3]) * spacing[1];
        let round = f32_rounding(&a, &b)[1];
        let pair = |c: &ChunkFile| -> Vec<usize> {
            (0..c.surface.positions.len())
                .filter(|&i| {
                    let p = c.surface.positions[i];
                    (p[2] - line).abs() < 1e-3 && (p[0] / spacing[0] - 2456.5113).abs() < 1e-4
                })
                .collect()
        };
        let h0 = a.surface.positions[pair(&a)[0]][1];
        for (c, apart) in [(&mut a, 1.5 * round), (&mut b, 0.5 * round)] {
            let ids = pair(c);
            assert_eq!(ids.len(), 2);
            c.surface.positions[ids[0]][1] = h0;
            c.surface.positions[ids[1]][1] = h0 + apart;
        }
        assert_eq!(compare_border(&a, &b, false, spacing), None);
        assert_eq!(compare_border(&b, &a, false, spacing), None);
        // A real step between them is still found: one of them a metre up.
        let mut stepped = a.clone();
        stepped.surface.positions[pair(&a)[1]][1] += 1.0;
        let found = compare_border(&stepped, &b, false, spacing);
        assert!(found.as_deref().is_some_and(|m| m.starts_with("border vertex")), "{found:?}");
    }

    fn v(x: f64, z: f64) -> MeshVertex {
        MeshVertex { x, z, h: 0.0, ph: 0.0 }
    }

    /// Sierra N36W119 at 1 m, `quantize`: chunk 4/12/0 holds a zero-area
    /// triangle along two collinear edges of its parent 3/6/0, through their
    /// shared vertex (929, 48); as read back, its centroid falls in the
    /// parent's sliver beside them and its far corner is 9.5 cells outside
    /// it. `verify` failed the build for it.
    #[test]
    fn a_sliver_along_collinear_parent_edges_does_not_straddle() {
        let child = [v(937.0, 42.888_671_875), v(929.0, 48.0), v(900.0, 66.529_296_875)];
        let parent = [v(927.0, 49.0), v(900.0, 66.531_25), v(929.0, 48.0)];
        // Half the child's step (1/512 cell) plus half the parent's (1/256).
        let tol = 1e-4 + 2.0 * (1.0 / 1024.0 + 1.0 / 512.0);
        assert!(barycentric(&parent[0], &parent[1], &parent[2], 937.0, 42.888_671_875).0 > 9.0);
        assert!(!straddles(child, parent, tol));
        // A real triangle across the same parent edge still straddles it.
        let across = [v(937.0, 42.0), v(929.0, 48.0), v(915.0, 50.0)];
        assert!(straddles(across, parent, tol));
        // And one inside the parent triangle does not.
        let inside = [v(928.0, 48.6), v(927.5, 48.9), v(910.0, 60.1)];
        assert!(!straddles(inside, parent, tol));
    }

    /// Seamount at 1 m with 32-cell leaves failed `verify` ("1 triangles
    /// stand over nodata alone"): a cut piece 0.08 cells wide, whose only
    /// sample within 10⁻⁴ was a nodata one 9·10⁻⁵ outside its edge. A
    /// triangle stands over nodata alone only where a nodata sample is
    /// inside it by more than rounding and no valid one is that near.
    #[test]
    fn a_triangle_wound_against_the_file_order_is_turned_over_and_a_flat_one_is_not() {
        // Written counter-clockwise seen from above: clockwise in x-east,
        // z-south grid space.
        let written = [v(0.0, 0.0), v(0.0, 1.0), v(1.0, 0.0)];
        assert!(!turned_over(&written));
        let [a, b, c] = written;
        assert!(turned_over(&[a, c, b]));
        // A sliver a step wide, as the Sierra chunks had it, either way round.
        let sliver = [v(129.0, 276.0), v(120.7890625, 253.0), v(130.78515625, 281.0)];
        assert!(turned_over(&sliver));
        assert!(!turned_over(&[sliver[0], sliver[2], sliver[1]]));
        // Two corners on one point (close crossings on one lattice point).
        assert!(!turned_over(&[v(3.0, 2.0), v(3.0, 2.0), v(5.0, 7.0)]));
    }

    #[test]
    fn a_sliver_passing_a_rounding_from_a_nodata_sample_does_not_stand_over_it() {
        let (w, h) = (460, 270);
        let mut heights = vec![f32::NAN; w * h];
        let footprint = [0, w as u32 - 1, 0, h as u32 - 1];
        let sliver =
            [v(445.188_640_792_341_23, 249.0), v(445.111_151_621_413_8, 249.0), v(436.0, 263.909_281_785_734_4)];
        let hf = Heightfield::ungeoreferenced(w, h, heights.clone(), "test".into());
        assert!(!scan_written(&hf, &sliver, footprint, |_, _, _| {}), "the sliver covers no sample");
        // A triangle with nodata well inside it, and nothing valid near.
        let over = [v(430.0, 250.0), v(440.0, 250.0), v(430.0, 260.0)];
        assert!(scan_written(&hf, &over, footprint, |_, _, _| {}));
        // One valid sample on its edge, within rounding: it covers data.
        heights[255 * w + 435] = -4100.0;
        let hf = Heightfield::ungeoreferenced(w, h, heights, "test".into());
        let mut seen = Vec::new();
        assert!(!scan_written(&hf, &over, footprint, |i, j, _| seen.push((i, j))));
        assert_eq!(seen, [(255, 435)]);
    }

    /// DFW at 2 m with 16-cell leaves failed `verify` (a morph target
    /// 0.099 m "off"): the parent 3/1/6 holds a sliver 6·10⁻⁵ cells wide
    /// along x + z = 358 whose plane rises 5 m across it, and the child's
    /// vertex (56, 302), on it, took the height of its upper edge. Within
    /// rounding of the vertex the sliver takes every height from its lower
    /// edge's to its upper edge's, and the target is one of them.
    #[test]
    fn a_morph_target_on_a_steep_parent_sliver_is_on_the_parent_surface() {
        let h = |x: f64, z: f64, h: f64| MeshVertex { x, z, h, ph: 0.0 };
        let sliver =
            [h(53.0, 305.0, 240.0), h(67.999_913_671_474_19, 290.0, 248.000_085_830_688_48), h(48.0, 310.0, 229.0)];
        let at = (56.0, 301.999_982);
        let (lo, hi) = heights_within(sliver, at, [2e-5, 2e-5]).expect("the sliver passes the vertex");
        assert!(lo < 237.0 && hi > 241.6, "{lo}..{hi}");
        // Away from the sliver, nothing; inside a broad triangle, its plane
        // a rounding either way.
        assert_eq!(heights_within(sliver, (56.0, 300.0), [2e-5, 2e-5]), None);
        let flat = [h(0.0, 0.0, 0.0), h(10.0, 0.0, 10.0), h(0.0, 10.0, 0.0)];
        let (lo, hi) = heights_within(flat, (5.0, 2.0), [0.01, 0.01]).unwrap();
        assert!((lo - 4.99).abs() < 1e-9 && (hi - 5.01).abs() < 1e-9, "{lo}..{hi}");
    }
}
