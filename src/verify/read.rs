//! Reading a tileset's files back: only regular files inside the tileset
//! (no symbolic link, no `..`, no absolute path), each checked against a
//! size limit before it is read and, for a chunk, against the length its
//! GLB header declares; then the chunk's glTF into plain data
//! ([`ChunkFile`]) that the checks and `inspect` read.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::{VerifyError, file_err};
use crate::mesh::MeshVertex;
use crate::output::gltf::{Imported, import};
use crate::quadtree::ChunkKey;

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
    /// Morph target x and z deltas, metres (0 in the flat frame).
    pub morph_xz: Vec<[f64; 2]>,
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
    /// NORMAL (empty when the primitive has none).
    pub normals: Vec<[f32; 3]>,
}

impl Prim {
    /// The x and z morph delta of vertex `k`.
    pub fn morph_dxz_at(&self, k: usize) -> [f64; 2] {
        self.morph_xz.get(k).copied().unwrap_or([0.0; 2])
    }

    /// The largest |x| or |z| morph delta (0 in the flat frame).
    pub fn largest_dxz(&self) -> f64 {
        self.morph_xz.iter().fold(0.0, |m, d| m.max(d[0].abs()).max(d[1].abs()))
    }

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

/// The largest chunk file a reader takes, bytes (2 GiB): a chunk of
/// `max_chunk_vertices` at its largest with two textures of
/// `max_texture_px` at their largest stays under it, so a larger file is
/// damaged or not a chunk, and is refused before it is read.
pub const MAX_TILE_BYTES: u64 = 1 << 31;

/// The largest `tileset.json` a reader takes, bytes (1 GiB: a hundred
/// times the index of a tileset of 27 000 chunks).
pub const MAX_INDEX_BYTES: u64 = 1 << 30;

/// The path of `uri` inside the tileset at `root`, where every step of it
/// is a real folder (no symbolic link) and the last a regular file: a
/// relative, `/`-separated path without `.`, `..` or empty parts. Returns
/// the path and the file's length.
fn inside(root: &Path, uri: &str) -> Result<(PathBuf, u64), VerifyError> {
    let refuse = |what: String| file_err(&root.join(uri), what);
    let parts: Vec<&str> = uri.split('/').collect();
    let plain = |p: &&str| {
        let mut c = Path::new(p).components();
        matches!((c.next(), c.next()), (Some(std::path::Component::Normal(_)), None)) && !p.contains(['\\', '\0'])
    };
    if uri.is_empty() || !parts.iter().all(plain) {
        return Err(refuse(format!(
            "{uri:?} is not a relative path inside the tileset (no `..`, `.`, empty part or absolute path)"
        )));
    }
    let mut path = root.to_path_buf();
    for (i, part) in parts.iter().enumerate() {
        path.push(part);
        let meta = std::fs::symlink_metadata(&path).map_err(|e| file_err(&path, format!("cannot read: {e}")))?;
        let kind = meta.file_type();
        if kind.is_symlink() {
            return Err(file_err(&path, "is a symbolic link; readers do not follow links out of the tileset"));
        }
        let last = i + 1 == parts.len();
        if !last && !kind.is_dir() {
            return Err(file_err(&path, "is not a folder"));
        }
        if last && !kind.is_file() {
            return Err(file_err(&path, "is not a regular file"));
        }
        if last {
            return Ok((path, meta.len()));
        }
    }
    unreachable!("a non-empty uri has a last part")
}

/// Reads the regular file at `path`, of `len` bytes by its metadata, if it
/// is at most `limit` bytes; a GLB (`glb`) only when its header declares
/// exactly its length, checked before the rest is read (a padded tile is
/// refused without reading the padding).
fn read_bounded(path: &Path, len: u64, limit: u64, glb: bool) -> Result<Vec<u8>, VerifyError> {
    use std::io::Read;
    if len > limit {
        return Err(file_err(path, format!("is {len} bytes, over the {limit}-byte limit")));
    }
    let cannot = |e: std::io::Error| file_err(path, format!("cannot read: {e}"));
    let file = std::fs::File::open(path).map_err(cannot)?;
    // The file that was opened, not only the name that was checked.
    let meta = file.metadata().map_err(cannot)?;
    if !meta.is_file() || meta.len() != len {
        return Err(file_err(path, "changed while it was being read"));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    let mut file = file.take(len);
    if glb {
        file.by_ref().take(12).read_to_end(&mut bytes).map_err(cannot)?;
        glb_length_holds(path, &bytes, len)?;
    }
    file.read_to_end(&mut bytes).map_err(cannot)?;
    if bytes.len() as u64 != len {
        return Err(file_err(path, format!("ended after {} of {len} bytes", bytes.len())));
    }
    Ok(bytes)
}

/// Whether a GLB's 12-byte header (`head`) is glTF 2.0's and declares
/// `len`, the file's whole length: trailing bytes are damage, not data.
fn glb_length_holds(path: &Path, head: &[u8], len: u64) -> Result<(), VerifyError> {
    if head.len() < 12 || &head[..4] != b"glTF" {
        return Err(file_err(path, "not a GLB: no `glTF` header"));
    }
    let declared = u32::from_le_bytes([head[8], head[9], head[10], head[11]]);
    if u64::from(declared) != len {
        return Err(file_err(path, format!("not a GLB of {len} bytes: its header declares {declared}")));
    }
    Ok(())
}

/// The bytes of the file at `uri` inside the tileset at `root`, as every
/// reader of a tileset (`verify`, the viewer) takes them: a regular file
/// reached through real folders only, at most [`MAX_TILE_BYTES`], and for
/// a `.glb`, exactly as long as its header says.
pub fn read_tile(root: &Path, uri: &str) -> Result<Vec<u8>, VerifyError> {
    let (path, len) = inside(root, uri)?;
    read_bounded(&path, len, MAX_TILE_BYTES, uri.ends_with(".glb"))
}

/// `tileset.json` at `root`, read as [`read_tile`] reads a chunk, up to
/// [`MAX_INDEX_BYTES`].
pub(crate) fn read_index(root: &Path) -> Result<(PathBuf, Vec<u8>), VerifyError> {
    let (path, len) = inside(root, "tileset.json")?;
    let bytes = read_bounded(&path, len, MAX_INDEX_BYTES, false)?;
    Ok((path, bytes))
}

/// `tileset.json` at `root` as one tree: parsed, with every external
/// tileset it refers to read in its place ([`inline_external`]). What
/// `verify`, the viewer and the benchmarks read.
pub fn read_tileset(root: &Path) -> Result<Value, VerifyError> {
    let (path, text) = read_index(root)?;
    let mut ts: Value = serde_json::from_slice(&text).map_err(|e| file_err(&path, format!("bad JSON: {e}")))?;
    inline_external(root, &mut ts)?;
    Ok(ts)
}

/// Puts in place of each tile of `ts` whose content is an external
/// tileset (a `.json` URI) that tileset's root, read as `tileset.json` is
/// read: a file beside `tileset.json` (the only place terrachunk writes
/// one, so that the content URIs inside it mean what they mean in the
/// root), of 3D Tiles 1.1, whose root has no transform of its own, lies in
/// the referring tile's box and has no larger geometric error; the
/// referring tile has no children (3D Tiles), and no file is read twice.
/// Returns how many were read.
pub fn inline_external(root: &Path, ts: &mut Value) -> Result<usize, VerifyError> {
    let index = root.join("tileset.json");
    let mut seen = std::collections::HashSet::new();
    let mut stack: Vec<&mut Value> = vec![&mut ts["root"]];
    while let Some(tile) = stack.pop() {
        let external = tile["content"]["uri"].as_str().filter(|u| u.ends_with(".json")).map(str::to_owned);
        let Some(uri) = external else {
            if let Some(kids) = tile.get_mut("children").and_then(Value::as_array_mut) {
                stack.extend(kids.iter_mut());
            }
            continue;
        };
        let path = root.join(&uri);
        let refuse = |why: String| Err(file_err(&index, format!("the tile that refers to {uri:?} {why}")));
        if uri.contains('/') || uri == "tileset.json" {
            return refuse("names a file other than one beside tileset.json".into());
        }
        if !seen.insert(uri.clone()) {
            return refuse("is not the first to refer to it".into());
        }
        if tile["children"].as_array().is_some_and(|k| !k.is_empty()) {
            return refuse("has children (3D Tiles: a tile whose content is a tileset has none)".into());
        }
        let (at, len) = inside(root, &uri)?;
        let bytes = read_bounded(&at, len, MAX_INDEX_BYTES, false)?;
        let mut ext: Value = serde_json::from_slice(&bytes).map_err(|e| file_err(&path, format!("bad JSON: {e}")))?;
        if ext["asset"]["version"] != "1.1" {
            return Err(file_err(&path, "asset.version is not \"1.1\""));
        }
        let sub = ext["root"].take();
        if !sub.is_object() {
            return Err(file_err(&path, "has no root tile"));
        }
        if !sub["transform"].is_null() {
            return Err(file_err(&path, "its root has a transform (readers take the referring tile's frame)"));
        }
        match (aabb(&tile["boundingVolume"]["box"]), aabb(&sub["boundingVolume"]["box"])) {
            (Some(outer), Some(inner)) => {
                let tol = |v: f64| 1e-6 * (1.0 + v.abs());
                if (0..3)
                    .any(|a| inner.0[a] < outer.0[a] - tol(outer.0[a]) || inner.1[a] > outer.1[a] + tol(outer.1[a]))
                {
                    return Err(file_err(&path, "its root's box is not inside the referring tile's"));
                }
            }
            _ => return Err(file_err(&path, "its root or the referring tile has no 12-number boundingVolume.box")),
        }
        let (outer, inner) = (tile["geometricError"].as_f64(), sub["geometricError"].as_f64());
        if !matches!((outer, inner), (Some(o), Some(i)) if i <= o) {
            return Err(file_err(&path, "its root's geometricError is missing or larger than the referring tile's"));
        }
        *tile = sub;
        stack.push(tile);
    }
    Ok(seen.len())
}

/// The axis-aligned extent of a 3D Tiles `box` (centre, three half-axes).
fn aabb(b: &Value) -> Option<([f64; 3], [f64; 3])> {
    let v: Vec<f64> = b.as_array()?.iter().map(Value::as_f64).collect::<Option<_>>()?;
    if v.len() != 12 || v.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let half = [0, 1, 2].map(|a| v[3 + a].abs() + v[6 + a].abs() + v[9 + a].abs());
    Some(([0, 1, 2].map(|a| v[a] - half[a]), [0, 1, 2].map(|a| v[a] + half[a])))
}

/// Reads one chunk file a user names (`inspect`): a regular file (a link
/// to one is followed, since the user chose it), at most
/// [`MAX_TILE_BYTES`], exactly as long as its GLB header says.
pub fn read_chunk(path: &Path) -> Result<ChunkFile, VerifyError> {
    let meta = std::fs::metadata(path).map_err(|e| file_err(path, format!("cannot read: {e}")))?;
    if !meta.is_file() {
        return Err(file_err(path, "is not a regular file"));
    }
    let bytes = read_bounded(path, meta.len(), MAX_TILE_BYTES, true)?;
    parse_chunk(path, &bytes)
}

/// [`read_chunk`] on bytes already read from `path` (which errors name):
/// any bytes give a chunk or an error, never a panic (the `chunk` fuzz
/// target).
pub fn parse_chunk(path: &Path, bytes: &[u8]) -> Result<ChunkFile, VerifyError> {
    glb_length_holds(path, bytes, bytes.len() as u64)?;
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
        let normals: Vec<[f32; 3]> = reader.read_normals().map(Iterator::collect).unwrap_or_default();
        if !normals.is_empty() && normals.len() != local.len() {
            return Err(file_err(path, format!("{role}: NORMAL has {} of {} vertices", normals.len(), local.len())));
        }
        let p = Prim {
            uv,
            uv1,
            normals,
            positions: local.iter().map(|l| [0, 1, 2].map(|a| translation[a] + on_steps(l[a], a))).collect(),
            morph_dy: deltas.iter().map(|d| f64::from(d[1])).collect(),
            morph_xz: deltas.iter().map(|d| [f64::from(d[0]), f64::from(d[2])]).collect(),
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
