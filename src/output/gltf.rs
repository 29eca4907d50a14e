//! Write one chunk as a binary glTF 2.0 (.glb), per the output contract in
//! DESIGN.md: y-up metres, one node with an f64 `translation`, chunk-local
//! f32 positions, u16 indices (u32 for a chunk of more than 65 535 vertices)
//! reordered for the vertex cache and vertex fetch
//! (meshoptimizer), and one "parent" morph target per primitive. A textured
//! chunk adds TEXCOORD_0 (the footprint onto its tile's texel centres; see
//! `texture`), its tile as an image in a bufferView, a clamp-to-edge
//! mipmapping sampler and a metallic 0 / roughness 1 material; without a
//! texture the file is exactly what it was before textures existed.
//!
//! The JSON is built with `serde_json` directly rather than `gltf-json`'s
//! builder types: the contract's extras (`role`, `targetNames`, the chunk
//! record) are plain JSON, and the whole document is a few dozen lines.
//! Files are read back with the `gltf` crate (verify, inspect, tests).
//!
//! With `compress = "quantize"`, `"meshopt"` or `"meshopt-v1"` the vertex
//! data is written by [`super::compress`] instead (KHR_mesh_quantization in
//! three bufferViews the surface and skirt share, then EXT_ or
//! KHR_meshopt_compression), and the node also carries a `scale`; the rest
//! of the document is the same but for the primitive mode, left at its
//! default, and with `meshopt-v1` the names and the default roughness, left
//! out.

use serde_json::{Value, json};

use crate::chunk::{Chunk, Part};
use crate::config::{Meshopt, NormalEncoding, VertexCache};
use crate::output::compress::{self, Quantization, QuantizeError, Sink, align4};
use crate::output::glb::{PrimData, accessor_layout, glb, index_bytes};
use crate::texture::{TextureTile, TileImage};

/// What the writer needs besides the chunk itself.
pub struct GlbContext<'a> {
    /// `[s_x, s_z]` in metres (recorded in the chunk extras).
    pub spacing_m: [f64; 2],
    /// Generator string for `asset.generator`.
    pub generator: &'a str,
    /// Triangle order for the vertex cache.
    pub vertex_cache: VertexCache,
    /// The quantization grid when vertex data is quantized (None: f32).
    pub quantization: Option<&'a Quantization>,
    /// Compress the quantized streams with meshoptimizer for this extension
    /// (needs `quantization`).
    pub meshopt: Option<Meshopt>,
    /// How quantized normals are chosen (see [`compress::octahedral`]).
    pub normals: NormalEncoding,
}

/// The chunk-local origin: the chunk's west/north corner, and vertically the
/// lowest DEM height among its vertices if every DEM height (an f32, as the
/// grid holds it) minus that is exact in f32, else 0 (where it always is).
/// The mesher counts on sample heights being written exactly
/// ([`crate::mesh::decimate::Targets`]); only cut points and skirt bottoms,
/// whose heights are not DEM samples, round.
pub fn chunk_origin(chunk: &Chunk) -> [f64; 3] {
    let mut o = [f64::INFINITY; 3];
    for p in chunk.surface.positions.iter().chain(&chunk.skirt.positions) {
        o[0] = o[0].min(p[0]);
        o[2] = o[2].min(p[2]);
    }
    let samples = || chunk.surface.positions.iter().map(|p| p[1]).filter(|&h| f64::from(h as f32) == h);
    let low = samples().fold(f64::INFINITY, f64::min);
    let exact = |y0: f64| samples().all(|h| f64::from((h - y0) as f32) == h - y0);
    o[1] = if low.is_finite() && exact(low) { low } else { 0.0 };
    o
}

/// TEXCOORD for the world point `p` of a chunk with footprint `fp`, on an
/// image of `texels`: the footprint's edges map to the edge texels' centres.
pub fn texcoord(p: &[f64; 3], fp: ((u32, u32), (u32, u32)), spacing_m: [f64; 2], texels: [u32; 2]) -> [f32; 2] {
    let ((x0, x1), (z0, z1)) = fp;
    let along = |g: f64, a: u32, b: u32, n: u32| {
        let n = f64::from(n);
        ((0.5 + (n - 1.0) * (g - f64::from(a)) / f64::from(b - a)) / n) as f32
    };
    [along(p[0] / spacing_m[0], x0, x1, texels[0]), along(p[2] / spacing_m[1], z0, z1, texels[1])]
}

/// Encodes `chunk` (with its texture tile, if any) as a .glb file. Fails
/// only when quantized vertices fall off the planned grid.
pub fn encode_glb(chunk: &Chunk, texture: Option<&TextureTile>, ctx: &GlbContext) -> Result<Vec<u8>, QuantizeError> {
    let frame = ctx.quantization.map(|q| q.frame(chunk)).transpose()?;
    let origin = frame.as_ref().map_or_else(|| chunk_origin(chunk), |f| f.translation);
    let parts: Vec<(&str, Part)> = [("surface", &chunk.surface), ("skirt", &chunk.skirt)]
        .into_iter()
        .filter(|(_, part)| !part.indices.is_empty())
        .map(|(role, part)| (role, optimise(part, ctx.vertex_cache)))
        .collect();
    // With a normal map, the map carries the shading and the vertices fix
    // its tangent frame to the map's axes (see `texture`).
    let normal_map = texture.and_then(|t| t.normal.as_ref());
    // meshopt-v1 writes one vertex set for both primitives: the skirt's tops
    // are the surface's own vertices (see `share_skirt`).
    let shared = ctx.meshopt == Some(Meshopt::Khr) && frame.is_some() && parts.len() == 2;
    let (sets, triangles): (Vec<Part>, Vec<(usize, Vec<u32>)>) = if shared {
        let (set, skirt) = share_skirt(&parts[0].1, &parts[1].1);
        let surface = set.indices.clone();
        (vec![set], vec![(0, surface), (0, skirt)])
    } else {
        let triangles = parts.iter().enumerate().map(|(k, (_, p))| (k, p.indices.clone())).collect();
        (parts.iter().map(|(_, p)| p.clone()).collect(), triangles)
    };
    let prims: Vec<PrimData> = sets
        .iter()
        .map(|p| {
            let n = p.positions.len();
            // Quantized, each coordinate maps the position as written.
            let uv = |img: &TileImage| -> Vec<[f32; 2]> {
                (0..n)
                    .map(|k| match &frame {
                        Some(f) => f.on_grid(&p.positions[k]),
                        None => {
                            let [x, z] = p.plan(k);
                            [x, 0.0, z]
                        }
                    })
                    .map(|q| texcoord(&q, chunk.footprint, ctx.spacing_m, img.texels))
                    .collect()
            };
            PrimData {
                part: p,
                // In the flat frame the map's axes are the chunk's own; the
                // curved frame turns them per vertex (`Part::tangents`).
                normals: match normal_map {
                    Some(_) if p.tangents.is_empty() => vec![[0.0, 1.0, 0.0]; n],
                    _ => p.normals.clone(),
                },
                uv: texture.map(|t| uv(&t.colour)),
                tangents: normal_map.map(|_| match p.tangents.is_empty() {
                    true => vec![[1.0, 0.0, 0.0, 1.0]; n],
                    false => p.tangents.iter().map(|&[x, y, z]| [x, y, z, 1.0]).collect(),
                }),
                uv1: texture.and_then(|t| t.normal.as_ref().filter(|nm| nm.texels != t.colour.texels)).map(uv),
            }
        })
        .collect();
    let mut sink = Sink::default();
    let written = match &frame {
        None => prims.iter().map(|p| float_attributes(&mut sink, p, origin)).collect(),
        Some(f) => {
            let triangles: Vec<(usize, &[u32])> = triangles.iter().map(|(k, t)| (*k, t.as_slice())).collect();
            compress::write_quantized(&mut sink, f, &prims, &triangles, ctx.normals, ctx.meshopt)
        }
    };
    let prims: Vec<Value> = parts
        .iter()
        .zip(written)
        .map(|((role, _), (attributes, idx, dlt))| {
            let mut prim = json!({
                "attributes": attributes,
                "indices": idx,
                "material": 0,
                "targets": [{"POSITION": dlt}],
                "extras": {"role": role},
            });
            // TRIANGLES, the default, spelled out only where bytes are not the point.
            if frame.is_none() {
                prim["mode"] = 4.into();
            }
            prim
        })
        .collect();
    let codec = ctx.meshopt.filter(|_| frame.is_some());
    let fallback = codec.map(|c| compress::meshopt_pack(&mut sink, c));
    let Sink { mut bin, mut views, accessors, .. } = sink;
    let k = chunk.key;
    let ((x0, x1), (z0, z1)) = chunk.footprint;
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": ctx.generator},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{
            "name": format!("chunk {}/{}/{}", k.level, k.x, k.y),
            "mesh": 0,
            "translation": origin,
            "extras": {"terrachunk": {
                "level": k.level, "x": k.x, "y": k.y,
                "delta_m": chunk.delta_m,
                "max_error_m": chunk.max_error_m,
                "footprint": {"x0": x0, "x1": x1, "z0": z0, "z1": z1},
                "spacing_m": ctx.spacing_m,
            }},
        }],
        "meshes": [{
            "name": format!("terrain {}/{}/{}", k.level, k.x, k.y),
            "primitives": prims,
            "weights": [0.0],
            "extras": {"targetNames": ["parent"]},
        }],
        "materials": [{
            "name": "terrain",
            "pbrMetallicRoughness": {"baseColorFactor": [0.55, 0.52, 0.45, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "doubleSided": true,
        }],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    if let Some(f) = &frame {
        doc["nodes"][0]["scale"] = json!(f.scale);
        let used = match codec {
            Some(c) => json!(["KHR_mesh_quantization", c.extension()]),
            None => json!(["KHR_mesh_quantization"]),
        };
        doc["extensionsUsed"] = used.clone();
        doc["extensionsRequired"] = used;
    }
    if let Some(tex) = texture {
        let mut images = Vec::new();
        for img in std::iter::once(&tex.colour).chain(&tex.normal) {
            align4(&mut bin);
            views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": img.bytes.len()}));
            bin.extend_from_slice(&img.bytes);
            images.push(json!({"bufferView": views.len() - 1, "mimeType": img.mime}));
        }
        let mut material = json!({
            "name": "terrain",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "doubleSided": true,
        });
        if let Some(nm) = &tex.normal {
            let set = u32::from(nm.texels != tex.colour.texels);
            material["normalTexture"] = json!({"index": 1, "texCoord": set});
        }
        let texture_info =
            |img: &TileImage| json!({"texels": img.texels, "texel_m": img.texel_m, "limited_by": img.limit});
        let mut info = json!({"colour": texture_info(&tex.colour)});
        if let Some(nm) = &tex.normal {
            info["normal"] = texture_info(nm);
        }
        doc["nodes"][0]["extras"]["terrachunk"]["texture"] = info;
        doc["materials"] = json!([material]);
        doc["textures"] = (0..images.len()).map(|i| json!({"sampler": 0, "source": i})).collect();
        doc["images"] = images.into();
        // LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE.
        doc["samplers"] = json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]);
        doc["bufferViews"] = views.into();
        doc["buffers"] = json!([{"byteLength": bin.len()}]);
    }
    if let (Some(c), Some(n)) = (codec, fallback) {
        // The compressed streams' uncompressed layout: no data of its own.
        doc["buffers"] = json!([
            {"byteLength": bin.len()},
            {"byteLength": n, "extensions": {c.extension(): {"fallback": true}}},
        ]);
    }
    if codec == Some(Meshopt::Khr) {
        // Only where bytes are the point and no earlier file is to be
        // matched: the names only label what the chunk record says, and
        // roughness 1 is the default.
        for object in ["nodes", "meshes", "materials"] {
            doc[object][0].as_object_mut().expect("an object").remove("name");
        }
        let pbr = doc["materials"][0]["pbrMetallicRoughness"].as_object_mut().expect("an object");
        pbr.remove("roughnessFactor");
    }
    Ok(glb(&serde_json::to_vec(&doc).expect("JSON of plain values"), &bin))
}

/// POSITION (chunk-local f32), NORMAL, the morph target, the indices and
/// then the texture's attributes, as the portable float output writes them.
fn float_attributes(sink: &mut Sink, prim: &PrimData, origin: [f64; 3]) -> (Value, usize, usize) {
    let Sink { bin, views, accessors, .. } = sink;
    let p = prim.part;
    let local: Vec<[f32; 3]> = p.positions.iter().map(|q| [0, 1, 2].map(|a| (q[a] - origin[a]) as f32)).collect();
    let delta: Vec<[f32; 3]> = (0..p.positions.len()).map(|k| p.morph(k).map(|d| d as f32)).collect();
    let pos = push_vec3(bin, views, accessors, &local);
    let nrm = push_vec3(bin, views, accessors, &prim.normals);
    let dlt = push_vec3(bin, views, accessors, &delta);
    let idx = push_indices(bin, views, accessors, &p.indices);
    let mut attributes = json!({"POSITION": pos, "NORMAL": nrm});
    if let Some(uv) = &prim.uv {
        attributes["TEXCOORD_0"] = push_vec2(bin, views, accessors, uv).into();
    }
    if let Some(t) = &prim.tangents {
        attributes["TANGENT"] = push_vec4(bin, views, accessors, t).into();
    }
    if let Some(uv) = &prim.uv1 {
        attributes["TEXCOORD_1"] = push_vec2(bin, views, accessors, uv).into();
    }
    (attributes, idx, dlt)
}

/// `meshopt-v1`'s one vertex set for surface and skirt: the skirt's top
/// vertices are surface vertices (the same position, normal and morph
/// delta, as `mesh::skirt` copies them), so the set is the surface's
/// vertices then the skirt's bottoms, in the order the skirt's triangles
/// first use them (the order the index codec expects of new vertices).
/// Returns the set, whose `indices` are the surface's, and the skirt's
/// triangles in it. Only where no surface vertex matches does a top become
/// a vertex of its own (not seen: the tops are copies).
fn share_skirt(surface: &Part, skirt: &Part) -> (Part, Vec<u32>) {
    let key = |p: &[f64; 3]| p.map(f64::to_bits);
    let at: std::collections::HashMap<[u64; 3], usize> =
        surface.positions.iter().enumerate().map(|(i, p)| (key(p), i)).collect();
    let mut set = surface.clone();
    let mut remap: Vec<Option<u32>> = skirt
        .positions
        .iter()
        .enumerate()
        .map(|(k, p)| {
            at.get(&key(p))
                .filter(|&&i| surface.normals[i] == skirt.normals[k] && surface.morph(i) == skirt.morph(k))
                .map(|&i| i as u32)
        })
        .collect();
    let indices = skirt
        .indices
        .iter()
        .map(|&v| {
            let v = v as usize;
            *remap[v].get_or_insert_with(|| {
                set.push_from(skirt, v);
                (set.positions.len() - 1) as u32
            })
        })
        .collect();
    (set, indices)
}

/// Vertex-cache then vertex-fetch order (meshoptimizer); same triangles.
fn optimise(p: &Part, order: VertexCache) -> Part {
    let n = p.positions.len();
    let indices = match order {
        VertexCache::Fast => meshopt::optimize_vertex_cache_fifo(&p.indices, n, 16),
        VertexCache::Best => meshopt::optimize_vertex_cache(&p.indices, n),
        VertexCache::Strip => meshopt::optimize_vertex_cache_strip(&p.indices, n),
    };
    let remap = meshopt::optimize_vertex_fetch_remap(&indices, n);
    // The remap numbers the used vertices 0, 1, …: its inverse is the new order.
    let mut order = vec![usize::MAX; remap.iter().filter(|&&r| r != u32::MAX).count()];
    for (old, &new) in remap.iter().enumerate().filter(|(_, r)| **r != u32::MAX) {
        order[new as usize] = old;
    }
    p.gather(&order, indices.iter().map(|&i| remap[i as usize]).collect())
}

fn push_vec3(bin: &mut Vec<u8>, views: &mut Vec<Value>, accessors: &mut Vec<Value>, data: &[[f32; 3]]) -> usize {
    align4(bin);
    let offset = bin.len();
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for v in data {
        for a in 0..3 {
            bin.extend_from_slice(&v[a].to_le_bytes());
            min[a] = min[a].min(v[a]);
            max[a] = max[a].max(v[a]);
        }
    }
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len() * 12, "target": 34962}));
    accessors.push(json!({
        "bufferView": views.len() - 1, "componentType": 5126, "count": data.len(),
        "type": "VEC3", "min": min, "max": max,
    }));
    accessors.len() - 1
}

fn push_vec2(bin: &mut Vec<u8>, views: &mut Vec<Value>, accessors: &mut Vec<Value>, data: &[[f32; 2]]) -> usize {
    align4(bin);
    let offset = bin.len();
    for v in data {
        bin.extend_from_slice(&v[0].to_le_bytes());
        bin.extend_from_slice(&v[1].to_le_bytes());
    }
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len() * 8, "target": 34962}));
    accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126, "count": data.len(), "type": "VEC2"}));
    accessors.len() - 1
}

fn push_vec4(bin: &mut Vec<u8>, views: &mut Vec<Value>, accessors: &mut Vec<Value>, data: &[[f32; 4]]) -> usize {
    align4(bin);
    let offset = bin.len();
    for v in data {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len() * 16, "target": 34962}));
    accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126, "count": data.len(), "type": "VEC4"}));
    accessors.len() - 1
}

/// Triangles as u16, or as u32 where they index a vertex past
/// [`U16_INDEXED`] (a chunk denser than u16 indices hold).
fn push_indices(bin: &mut Vec<u8>, views: &mut Vec<Value>, accessors: &mut Vec<Value>, idx: &[u32]) -> usize {
    align4(bin);
    let offset = bin.len();
    let (bytes, component) = index_bytes(idx);
    bin.extend_from_slice(&bytes);
    views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": 34963}));
    accessors.push(json!({
        "bufferView": views.len() - 1, "componentType": component, "count": idx.len(), "type": "SCALAR",
    }));
    accessors.len() - 1
}

// ------------------------------------------------------------------ reading

/// A plain (uncompressed) .glb as the `gltf` crate imports it (the
/// document, its buffers and its decoded images) and its JSON as
/// `serde_json` reads it (the node translation in f64, the extras).
pub struct Imported {
    /// The validated document.
    pub doc: ::gltf::Document,
    /// Its buffers' bytes (the binary chunk).
    pub buffers: Vec<::gltf::buffer::Data>,
    /// Its images, decoded.
    pub images: Vec<::gltf::image::Data>,
    /// The JSON chunk, parsed once for the checks and kept for the caller.
    pub json: Value,
}

/// Imports a plain .glb with the `gltf` crate once [`references_hold`] has
/// checked what that crate (1.4) trusts before its own validation runs: a
/// damaged file is an error, never a panic in `verify`, `inspect` or the
/// viewer.
pub fn import(bytes: &[u8]) -> Result<Imported, String> {
    let glb = ::gltf::Glb::from_slice(bytes).map_err(|e| format!("not a GLB: {e}"))?;
    let json: Value = serde_json::from_slice(&glb.json).map_err(|e| format!("bad JSON: {e}"))?;
    references_hold(&json, glb.bin.as_deref().map_or(0, <[u8]>::len))?;
    let (doc, buffers, images) = ::gltf::import_slice(bytes).map_err(|e| format!("bad glTF: {e}"))?;
    Ok(Imported { doc, buffers, images, json })
}

/// Whether every reference the `gltf` crate follows unchecked holds, where
/// a damaged file made it panic instead of returning an error: a
/// primitive's accessor indices (its validation looks up the POSITION
/// accessor before it checks the index) and their types (its readers reach
/// `unreachable!` on float indices), an image's source and an embedded
/// image's MIME type (unwrapped), and each accessor's extent within its
/// bufferView, each bufferView's within its buffer and the buffer's within
/// the binary chunk (its readers compute these ends unchecked). Sparse
/// accessors, which terrachunk never writes, are refused rather than
/// checked. `bin_len`: the binary chunk's length.
pub fn references_hold(json: &Value, bin_len: usize) -> Result<(), String> {
    let list = |key: &str| json[key].as_array().map_or(&[][..], Vec::as_slice);
    let num = |v: &Value| v.as_u64().and_then(|n| usize::try_from(n).ok());
    let (buffers, views, accessors) = (list("buffers"), list("bufferViews"), list("accessors"));
    let index = |v: &Value, len: usize, what: &str| match num(v) {
        Some(i) if i < len => Ok(i),
        _ => Err(format!("{what} refers to {v}, of {len}")),
    };
    let mut buffer_len = Vec::with_capacity(buffers.len());
    for (b, buffer) in buffers.iter().enumerate() {
        let len = num(&buffer["byteLength"]).ok_or_else(|| format!("buffer {b} has no byteLength"))?;
        if buffer.get("uri").is_none() && len > bin_len {
            return Err(format!("buffer {b} claims {len} bytes, the binary chunk holds {bin_len}"));
        }
        buffer_len.push(len);
    }
    for (v, view) in views.iter().enumerate() {
        let b = index(&view["buffer"], buffers.len(), &format!("bufferView {v}"))?;
        let end = num(&view["byteLength"]).zip(view.get("byteOffset").map_or(Some(0), num));
        if end.and_then(|(len, off)| off.checked_add(len)).is_none_or(|e| e > buffer_len[b]) {
            return Err(format!("bufferView {v} lies outside buffer {b}"));
        }
    }
    for (a, acc) in accessors.iter().enumerate() {
        let what = format!("accessor {a}");
        if acc.get("sparse").is_some() {
            return Err(format!("{what} is sparse, which terrachunk never writes"));
        }
        let count = num(&acc["count"]).filter(|&c| c > 0).ok_or_else(|| format!("{what} has no elements"))?;
        let Some(v) = acc.get("bufferView") else { continue };
        let view = &views[index(v, views.len(), &what)?];
        let (components, size) = accessor_layout(acc).map_err(|e| format!("{what}: {e}"))?;
        let element = components * size;
        let stride = view.get("byteStride").map_or(Some(element), num);
        if stride.is_none_or(|s| s < element) {
            return Err(format!(
                "{what}: byteStride {} is shorter than its {element}-byte elements",
                view["byteStride"]
            ));
        }
        let offset = acc.get("byteOffset").map_or(Some(0), num);
        let end = stride
            .zip(offset)
            .and_then(|(s, o)| (count - 1).checked_mul(s).and_then(|e| e.checked_add(o)))
            .and_then(|e| e.checked_add(element));
        if end.is_none_or(|e| Some(e) > num(&view["byteLength"])) {
            return Err(format!("{what} reaches past its bufferView"));
        }
    }
    for (m, mesh) in list("meshes").iter().enumerate() {
        for (p, prim) in mesh["primitives"].as_array().into_iter().flatten().enumerate() {
            let what = format!("mesh {m} primitive {p}");
            let attributes = prim["attributes"].as_object().into_iter().flatten();
            let targets = prim["targets"].as_array().into_iter().flatten();
            let indices = prim.get("indices").map(|i| ("indices", i));
            let all = attributes
                .map(|(k, v)| (k.as_str(), v))
                .chain(targets.filter_map(Value::as_object).flatten().map(|(k, v)| (k.as_str(), v)))
                .chain(indices);
            for (semantic, a) in all {
                let acc = &accessors[index(a, accessors.len(), &what)?];
                if !semantic_type_holds(semantic, acc["type"].as_str(), acc["componentType"].as_u64()) {
                    return Err(format!(
                        "{what}: {semantic} is accessor {a} of type {} {}",
                        acc["type"], acc["componentType"]
                    ));
                }
            }
        }
    }
    for (i, image) in list("images").iter().enumerate() {
        match image.get("bufferView") {
            Some(v) => {
                index(v, views.len(), &format!("image {i}"))?;
                if !image["mimeType"].is_string() {
                    return Err(format!("image {i} lies in a bufferView and has no mimeType"));
                }
            }
            None if !image["uri"].is_string() => return Err(format!("image {i} has neither a bufferView nor a uri")),
            None => {}
        }
    }
    Ok(())
}

/// Whether an accessor of `kind` and `component` type may hold `semantic`
/// (an attribute, a morph target's attribute or "indices") in plain glTF
/// 2.0: the `gltf` crate's readers take the spec's types for granted.
/// Attributes it has no reader for pass.
fn semantic_type_holds(semantic: &str, kind: Option<&str>, component: Option<u64>) -> bool {
    let (kind, c) = (kind.unwrap_or(""), component.unwrap_or(0));
    let base = semantic.split('_').next().unwrap_or(semantic);
    match base {
        "POSITION" | "NORMAL" => kind == "VEC3" && c == 5126,
        "TANGENT" => matches!(kind, "VEC3" | "VEC4") && c == 5126,
        "TEXCOORD" => kind == "VEC2" && matches!(c, 5121 | 5123 | 5126),
        "COLOR" => matches!(kind, "VEC3" | "VEC4") && matches!(c, 5121 | 5123 | 5126),
        "JOINTS" => kind == "VEC4" && matches!(c, 5121 | 5123),
        "WEIGHTS" => kind == "VEC4" && matches!(c, 5121 | 5123 | 5126),
        "indices" => kind == "SCALAR" && matches!(c, 5121 | 5123 | 5125),
        _ => true,
    }
}
