//! Compressed vertex data (`compress = "quantize" | "meshopt"`): integer
//! positions, normals, morph deltas and texture coordinates by
//! KHR_mesh_quantization, then optionally meshoptimizer's vertex and index
//! codecs by EXT_meshopt_compression; and the reader that turns such a file
//! back into the plain f32 glTF that `verify` and `inspect` read.
//!
//! **The grid.** Positions are u16 on a grid that is the same for every
//! chunk of a level and aligned to the world, so that two chunks round a
//! shared vertex alike and their borders stay identical:
//! - horizontally, the step is the sample spacing / 2^k(L), with k(L) the
//!   largest that fits the level's widest footprint in 65 535 steps: every
//!   DEM sample is exactly on the grid, and only the cut points (where a
//!   dividing line crosses a parent edge, the one kind of vertex off the
//!   sample grid) round, by at most half a step;
//! - vertically, one step for the whole tileset: a power of two ≤
//!   `max_error_m / 16`, doubled while the tallest chunk (the whole relief
//!   plus skirts) would need more than 65 535 steps; a DEM whose relief needs
//!   a step above `max_error_m / 4` is refused. Heights round to the nearest
//!   multiple of the step, the same in every chunk and level, so a vertex a
//!   child shares with its parent keeps morph delta 0.
//!
//! The node carries the dequantisation, as KHR_mesh_quantization intends:
//! `translation` (the footprint's north-west corner, and the lowest height
//! multiple) and `scale` = the step per axis. This changes the output
//! contract for these modes only (DESIGN.md's node has no scale): world =
//! translation + scale · POSITION.
//!
//! **The δ budget.** Rounding a vertex's height moves the surface at any
//! point by at most step/2, so each level is meshed to δ(L) − step/2
//! ([`Quantization::mesh_delta`]) and the written, dequantized chunk is
//! still within δ(L) of every sample. Cut points also move sideways by up to
//! half a horizontal step (1/512 of a cell in a 250-cell chunk); the
//! mesher's own margin (it meshes to 0.98·δ) is what covers that, and
//! `verify` re-measures the dequantized files against δ with no allowance.
//!
//! **Morph targets** are the parent's height rounded to the same grid minus
//! the vertex's rounded height, in whole steps: i16 (scaled by the node like
//! POSITION), or f32 holding the same whole numbers where a delta exceeds
//! 32 767 steps. Normals are i8 normalized (octahedral-rounded, see below),
//! texture coordinates u16 normalized, the normal map's tangent i8 normalized.
//!
//! **meshopt** encodes every vertex stream (codec version 0; normals through
//! the 8-bit OCTAHEDRAL filter, whose decoded values `quantize` writes too)
//! and every index stream (triangle codec, whose corner rotation `quantize`
//! writes too), so it decodes to exactly the bytes `quantize` writes.
//! EXT_meshopt_compression is *required* and the fallback buffer holds no
//! data (`fallback: true`): the point of the mode is size, and an
//! uncompressed fallback would make the file larger than `quantize`; a
//! reader without the decoder should use `quantize` or `none` output.

use serde_json::{Value, json};

use crate::chunk::Chunk;
use crate::heightfield::Heightfield;
use crate::quadtree::ChunkTree;

/// The largest u16.
const U16_STEPS: f64 = 65_535.0;

/// Why vertex data cannot be quantized.
#[derive(Debug, thiserror::Error)]
pub enum QuantizeError {
    /// The relief is too tall for u16 heights at a step small against δ.
    #[error(
        "compress: the DEM's relief of {relief_m} m (plus skirts) needs a height step of {step_m} m to fit \
         16 bits, more than max_error_m / 4 = {quarter_m} m; raise max_error_m or use --compress none"
    )]
    Relief {
        /// Highest minus lowest valid height, metres.
        relief_m: f64,
        /// The step it would need, metres.
        step_m: f64,
        /// `max_error_m / 4`.
        quarter_m: f64,
    },
    /// A chunk is wider than 65 535 cells: its samples cannot all be on a u16 grid.
    #[error("compress: level {level} has chunks {cells} cells wide, more than a u16 position can count")]
    TooWide {
        /// Level.
        level: u32,
        /// Widest footprint, cells.
        cells: u32,
    },
    /// A chunk's vertices do not fit the planned grid (a terrachunk bug).
    #[error("compress: chunk {chunk}: a {axis} coordinate falls outside 0..=65535 steps (please report it)")]
    Range {
        /// `L/x/y`.
        chunk: String,
        /// x, y or z.
        axis: &'static str,
    },
}

/// The quantization grid of one build (see the module comment).
#[derive(Clone, Debug, PartialEq)]
pub struct Quantization {
    /// Height step, metres: a power of two, the same for every level.
    pub step_y_m: f64,
    /// Per level `L`: the horizontal step is `spacing_m / 2^shift[L]`.
    pub shift: Vec<u32>,
    /// Sample spacing `[s_x, s_z]`, metres.
    pub spacing_m: [f64; 2],
}

impl Quantization {
    /// Plans the grid for `tree` over `hf` with leaf accuracy `max_error_m`.
    pub fn plan(hf: &Heightfield, tree: &ChunkTree, max_error_m: f64) -> Result<Self, QuantizeError> {
        let (lo, hi) = hf
            .heights
            .iter()
            .filter(|h| !h.is_nan())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &h| (a.min(f64::from(h)), b.max(f64::from(h))));
        let relief_m = if hi >= lo { hi - lo } else { 0.0 };
        // Skirts hang at most δ(L−1) + δ(L−2) ≤ 2·δ(0) below the lowest sample.
        let range = relief_m + 2.0 * tree.delta_m[0];
        let mut step = 2f64.powi((max_error_m / 16.0).log2().floor() as i32);
        while range / step > U16_STEPS - 2.0 {
            step *= 2.0;
        }
        if step > max_error_m / 4.0 {
            return Err(QuantizeError::Relief { relief_m, step_m: step, quarter_m: max_error_m / 4.0 });
        }
        let mut shift = Vec::with_capacity(tree.xs.len());
        for (level, (xs, zs)) in tree.xs.iter().zip(&tree.zs).enumerate() {
            let cells = xs.iter().chain(zs).map(|s| s.1 - s.0).max().unwrap_or(1).max(1);
            if f64::from(cells) > U16_STEPS {
                return Err(QuantizeError::TooWide { level: level as u32, cells });
            }
            shift.push((U16_STEPS / f64::from(cells)).log2().floor().min(20.0) as u32);
        }
        Ok(Quantization { step_y_m: step, shift, spacing_m: hf.spacing_m })
    }

    /// The δ a level is meshed to so that, after its heights round to the
    /// grid, it is still within `delta_m` of every sample: δ − step/2.
    pub fn mesh_delta(&self, delta_m: f64) -> f64 {
        delta_m - self.step_y_m / 2.0
    }

    /// The grid of one chunk: where its integers start and their step.
    pub fn frame(&self, chunk: &Chunk) -> Result<Frame, QuantizeError> {
        let k = f64::from(1u32 << self.shift[chunk.key.level as usize]);
        let ((x0, _), (z0, _)) = chunk.footprint;
        let lowest = chunk
            .surface
            .positions
            .iter()
            .chain(&chunk.skirt.positions)
            .map(|p| (p[1] / self.step_y_m).round())
            .fold(f64::INFINITY, f64::min);
        let lowest = if lowest.is_finite() { lowest } else { 0.0 };
        let frame = Frame {
            translation: [f64::from(x0) * self.spacing_m[0], lowest * self.step_y_m, f64::from(z0) * self.spacing_m[1]],
            scale: [self.spacing_m[0] / k, self.step_y_m, self.spacing_m[1] / k],
            corner: [f64::from(x0), f64::from(z0)],
            lowest,
            k,
            spacing_m: self.spacing_m,
        };
        let key = chunk.key;
        for p in chunk.surface.positions.iter().chain(&chunk.skirt.positions) {
            let q = frame.steps(p);
            if let Some(a) = (0..3).find(|&a| !(0.0..=U16_STEPS).contains(&q[a])) {
                return Err(QuantizeError::Range {
                    chunk: format!("{}/{}/{}", key.level, key.x, key.y),
                    axis: ["x", "y", "z"][a],
                });
            }
        }
        Ok(frame)
    }
}

/// One chunk's quantization: world = `translation` + `scale` · integer.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Node translation, metres.
    pub translation: [f64; 3],
    /// Node scale: the step per axis, metres.
    pub scale: [f64; 3],
    /// The footprint's north-west corner, samples `[x0, z0]`.
    corner: [f64; 2],
    /// The translation's height in steps.
    lowest: f64,
    /// Horizontal steps per sample spacing, 2^shift.
    k: f64,
    /// Sample spacing, metres.
    spacing_m: [f64; 2],
}

impl Frame {
    /// A world position in whole steps from the translation (as f64). x and
    /// z go through grid coordinates, so samples land on whole steps exactly.
    fn steps(&self, p: &[f64; 3]) -> [f64; 3] {
        [
            ((p[0] / self.spacing_m[0] - self.corner[0]) * self.k).round(),
            (p[1] / self.scale[1]).round() - self.lowest,
            ((p[2] / self.spacing_m[1] - self.corner[1]) * self.k).round(),
        ]
    }

    /// A world position as u16 steps (checked in [`Quantization::frame`]).
    pub fn position(&self, p: &[f64; 3]) -> [u16; 3] {
        self.steps(p).map(|v| v as u16)
    }

    /// The morph delta, in height steps, that takes a vertex at height `y`
    /// to `target_y` (both rounded to the grid first).
    pub fn delta_steps(&self, y: f64, target_y: f64) -> i64 {
        ((target_y / self.scale[1]).round() - (y / self.scale[1]).round()) as i64
    }
}

// ------------------------------------------------------------------ writing

/// The binary chunk and the JSON arrays that describe it, as a .glb is
/// built; `streams` lists the bufferViews `meshopt` compresses.
#[derive(Default)]
pub struct Sink {
    /// The binary chunk so far.
    pub bin: Vec<u8>,
    /// `bufferViews`.
    pub views: Vec<Value>,
    /// `accessors`.
    pub accessors: Vec<Value>,
    /// Vertex and index streams, for [`meshopt_pack`].
    pub streams: Vec<Stream>,
}

/// A bufferView of vertex or index data.
pub struct Stream {
    view: usize,
    count: usize,
    stride: usize,
    /// Index data (u16 triangles) rather than vertex attributes.
    triangles: bool,
    /// Vertices the indices refer to (index streams only).
    vertices: usize,
    /// What `meshopt` encodes instead, for the OCTAHEDRAL filter to decode
    /// into the bytes written.
    filtered: Option<Vec<u8>>,
}

fn align4(bin: &mut Vec<u8>) {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
}

/// Appends one vertex attribute of `count` elements `stride` bytes apart
/// (`bytes` already laid out) and returns its accessor index.
fn push_attribute(sink: &mut Sink, bytes: &[u8], stride: usize, accessor: Value) -> usize {
    align4(&mut sink.bin);
    let count = bytes.len() / stride;
    sink.views.push(json!({
        "buffer": 0, "byteOffset": sink.bin.len(), "byteLength": bytes.len(), "byteStride": stride, "target": 34962,
    }));
    sink.bin.extend_from_slice(bytes);
    let view = sink.views.len() - 1;
    sink.streams.push(Stream { view, count, stride, triangles: false, vertices: count, filtered: None });
    let mut accessor = accessor;
    accessor["bufferView"] = view.into();
    accessor["count"] = count.into();
    sink.accessors.push(accessor);
    sink.accessors.len() - 1
}

/// Per-component minimum and maximum, for POSITION accessors.
fn bounds<const N: usize>(values: impl Iterator<Item = [f64; N]>) -> (Vec<f64>, Vec<f64>) {
    let (mut lo, mut hi) = (vec![f64::INFINITY; N], vec![f64::NEG_INFINITY; N]);
    for v in values {
        for a in 0..N {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    (lo, hi)
}

/// POSITION: u16 steps, 8 bytes per vertex (KHR_mesh_quantization aligns
/// vertex elements to 4 bytes).
pub fn push_positions(sink: &mut Sink, frame: &Frame, positions: &[[f64; 3]]) -> usize {
    let q: Vec<[u16; 3]> = positions.iter().map(|p| frame.position(p)).collect();
    let bytes: Vec<u8> = q.iter().flat_map(|v| [v[0], v[1], v[2], 0].into_iter().flat_map(u16::to_le_bytes)).collect();
    let (min, max) = bounds(q.iter().map(|v| v.map(f64::from)));
    let (min, max): (Vec<u64>, Vec<u64>) =
        (min.iter().map(|&v| v as u64).collect(), max.iter().map(|&v| v as u64).collect());
    push_attribute(sink, &bytes, 8, json!({"componentType": 5123, "type": "VEC3", "min": min, "max": max}))
}

/// The morph target's POSITION: whole height steps, i16 where every delta
/// fits, else f32 holding the same whole numbers.
pub fn push_deltas(sink: &mut Sink, frame: &Frame, positions: &[[f64; 3]], morph_dy: &[f64]) -> usize {
    let d: Vec<i64> = positions.iter().zip(morph_dy).map(|(p, dy)| frame.delta_steps(p[1], p[1] + dy)).collect();
    let (lo, hi) = (d.iter().copied().min().unwrap_or(0), d.iter().copied().max().unwrap_or(0));
    if lo >= -32767 && hi <= 32767 {
        let bytes: Vec<u8> =
            d.iter().flat_map(|&v| [0, v as i16, 0, 0].into_iter().flat_map(i16::to_le_bytes)).collect();
        push_attribute(
            sink,
            &bytes,
            8,
            json!({"componentType": 5122, "type": "VEC3", "min": [0, lo, 0], "max": [0, hi, 0]}),
        )
    } else {
        let bytes: Vec<u8> =
            d.iter().flat_map(|&v| [0.0, v as f32, 0.0].into_iter().flat_map(f32::to_le_bytes)).collect();
        let (lo, hi) = (lo as f32, hi as f32);
        push_attribute(
            sink,
            &bytes,
            12,
            json!({"componentType": 5126, "type": "VEC3", "min": [0.0, lo, 0.0], "max": [0.0, hi, 0.0]}),
        )
    }
}

/// A unit vector's component as i8 normalized.
fn snorm8(v: f32) -> i8 {
    (v.clamp(-1.0, 1.0) * 127.0).round() as i8
}

/// NORMAL: i8 normalized, 4 bytes per vertex, as meshoptimizer's 8-bit
/// octahedral filter decodes them: `meshopt` stores the two octahedral
/// coordinates (filter OCTAHEDRAL, which the vertex codec packs tighter than
/// three components), `quantize` what they decode to, so both read alike.
pub fn push_normals(sink: &mut Sink, normals: &[[f32; 3]]) -> usize {
    let unit: Vec<[f32; 4]> = normals.iter().map(|n| [n[0], n[1], n[2], 0.0]).collect();
    let oct: Vec<[i8; 4]> = meshopt::encode_filter_oct(&unit, 8);
    let mut decoded = oct.clone();
    meshopt::decode_filter_oct(&mut decoded);
    let bytes: Vec<u8> = decoded.iter().flat_map(|v| v.map(|c| c as u8)).collect();
    let accessor = push_attribute(sink, &bytes, 4, json!({"componentType": 5120, "normalized": true, "type": "VEC3"}));
    let stream = sink.streams.last_mut().expect("pushed above");
    stream.filtered = Some(oct.iter().flat_map(|v| v.map(|c| c as u8)).collect());
    accessor
}

/// TANGENT: i8 normalized, 4 bytes per vertex.
pub fn push_tangents(sink: &mut Sink, tangents: &[[f32; 4]]) -> usize {
    let bytes: Vec<u8> = tangents.iter().flat_map(|t| t.map(|c| snorm8(c) as u8)).collect();
    push_attribute(sink, &bytes, 4, json!({"componentType": 5120, "normalized": true, "type": "VEC4"}))
}

/// TEXCOORD: u16 normalized, 4 bytes per vertex.
pub fn push_uv(sink: &mut Sink, uv: &[[f32; 2]]) -> usize {
    let bytes: Vec<u8> = uv
        .iter()
        .flat_map(|t| {
            t.map(|c| (f64::from(c).clamp(0.0, 1.0) * U16_STEPS).round() as u16).into_iter().flat_map(u16::to_le_bytes)
        })
        .collect();
    push_attribute(sink, &bytes, 4, json!({"componentType": 5123, "normalized": true, "type": "VEC2"}))
}

/// Triangle indices, u16. meshoptimizer's index codec keeps the triangles'
/// order but may rotate each one's corners; both modes write the rotation
/// it decodes to, so that `meshopt` decodes to exactly what `quantize` writes.
pub fn push_indices(sink: &mut Sink, indices: &[u32], vertices: usize) -> usize {
    let encoded = meshopt::encode_index_buffer(indices, vertices).expect("a triangle list");
    let indices: Vec<u32> = meshopt::decode_index_buffer(&encoded, indices.len()).expect("just encoded");
    align4(&mut sink.bin);
    let offset = sink.bin.len();
    for &i in &indices {
        sink.bin.extend_from_slice(&(i as u16).to_le_bytes());
    }
    sink.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": indices.len() * 2, "target": 34963}));
    let view = sink.views.len() - 1;
    sink.streams.push(Stream { view, count: indices.len(), stride: 2, triangles: true, vertices, filtered: None });
    sink.accessors.push(json!({"bufferView": view, "componentType": 5123, "count": indices.len(), "type": "SCALAR"}));
    sink.accessors.len() - 1
}

/// Compresses every stream with meshoptimizer (EXT_meshopt_compression):
/// the compressed bytes become the new binary chunk (buffer 0) and the
/// views keep their uncompressed layout in a fallback buffer 1 that holds
/// no data. Returns buffer 1's byte length.
pub fn meshopt_pack(sink: &mut Sink) -> usize {
    let mut packed = Vec::new();
    for s in &sink.streams {
        let view = &mut sink.views[s.view];
        let (offset, length) =
            (view["byteOffset"].as_u64().unwrap_or(0) as usize, view["byteLength"].as_u64().unwrap_or(0) as usize);
        let raw = s.filtered.as_deref().unwrap_or(&sink.bin[offset..offset + length]);
        let encoded = if s.triangles {
            let indices: Vec<u32> = raw.chunks_exact(2).map(|b| u32::from(u16::from_le_bytes([b[0], b[1]]))).collect();
            meshopt::encode_index_buffer(&indices, s.vertices).expect("a triangle list")
        } else {
            encode_vertices(raw, s.stride)
        };
        align4(&mut packed);
        view["buffer"] = 1.into();
        let mut ext = json!({
            "buffer": 0, "byteOffset": packed.len(), "byteLength": encoded.len(), "byteStride": s.stride,
            "count": s.count, "mode": if s.triangles { "TRIANGLES" } else { "ATTRIBUTES" },
        });
        if s.filtered.is_some() {
            ext["filter"] = "OCTAHEDRAL".into();
        }
        view["extensions"] = json!({"EXT_meshopt_compression": ext});
        packed.extend_from_slice(&encoded);
    }
    align4(&mut packed);
    std::mem::replace(&mut sink.bin, packed).len()
}

/// meshoptimizer's vertex codec, version 0 (the one EXT_meshopt_compression names).
fn encode_vertices(raw: &[u8], stride: usize) -> Vec<u8> {
    fn enc<const N: usize>(raw: &[u8]) -> Vec<u8> {
        let v: Vec<[u8; N]> = raw.chunks_exact(N).map(|c| c.try_into().expect("N bytes")).collect();
        meshopt::encode_vertex_buffer_level(&v, 2, Some(0)).expect("vertex encoding")
    }
    match stride {
        4 => enc::<4>(raw),
        8 => enc::<8>(raw),
        12 => enc::<12>(raw),
        16 => enc::<16>(raw),
        _ => unreachable!("vertex strides are 4, 8, 12 or 16 bytes"),
    }
}

// ------------------------------------------------------------------ reading

/// A compressed chunk as plain glTF, and the grid it was quantized to.
pub struct Decoded {
    /// The same chunk as a .glb with f32 vertex data, u32 indices and no
    /// node scale (folded into POSITION and the morph targets), which any
    /// glTF reader (the `gltf` crate included) opens.
    pub glb: Vec<u8>,
    /// The node scale: the quantization step per axis, metres.
    pub step_m: [f64; 3],
}

/// Decodes a `quantize` or `meshopt` .glb into plain glTF; `None` for a
/// file that uses neither extension.
pub fn decompress(bytes: &[u8]) -> Result<Option<Decoded>, String> {
    let glb = gltf::Glb::from_slice(bytes).map_err(|e| format!("not a GLB: {e}"))?;
    let mut json: Value = serde_json::from_slice(&glb.json).map_err(|e| format!("bad JSON: {e}"))?;
    let used: Vec<&str> = json["extensionsUsed"].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
    if !used.iter().any(|e| *e == "KHR_mesh_quantization" || *e == "EXT_meshopt_compression") {
        return Ok(None);
    }
    let bin: &[u8] = glb.bin.as_deref().unwrap_or(&[]);
    let scale = match json["nodes"][0]["scale"].as_array() {
        Some(s) if s.len() == 3 => [0, 1, 2].map(|a| s[a].as_f64().unwrap_or(f64::NAN)),
        _ => [1.0; 3],
    };
    if !scale.iter().all(|s| s.is_finite()) {
        return Err("node scale is not three numbers".into());
    }
    // Which accessors are positions (scaled by the node) and which indices.
    let mut positions = std::collections::BTreeSet::new();
    let mut indices = std::collections::BTreeSet::new();
    for prim in
        json["meshes"].as_array().into_iter().flatten().flat_map(|m| m["primitives"].as_array().into_iter().flatten())
    {
        positions.extend(prim["attributes"]["POSITION"].as_u64());
        for t in prim["targets"].as_array().into_iter().flatten() {
            positions.extend(t["POSITION"].as_u64());
        }
        indices.extend(prim["indices"].as_u64());
    }
    let mut out = Sink::default();
    let mut cache: Vec<Option<Vec<u8>>> = vec![None; json["bufferViews"].as_array().map_or(0, Vec::len)];
    let accessors: Vec<Value> = json["accessors"].as_array().cloned().unwrap_or_default();
    for (a, acc) in accessors.iter().enumerate() {
        let (values, n) = read_accessor(&json, acc, bin, &mut cache).map_err(|e| format!("accessor {a}: {e}"))?;
        align4(&mut out.bin);
        let offset = out.bin.len();
        let count = values.len() / n.max(1);
        if indices.contains(&(a as u64)) {
            for v in &values {
                out.bin.extend_from_slice(&(*v as u32).to_le_bytes());
            }
            out.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4, "target": 34963}));
            out.accessors.push(
                json!({"bufferView": out.views.len() - 1, "componentType": 5125, "count": count, "type": "SCALAR"}),
            );
            continue;
        }
        let scaled = positions.contains(&(a as u64)) && n == 3;
        let f: Vec<f32> =
            values.iter().enumerate().map(|(i, v)| (if scaled { v * scale[i % 3] } else { *v }) as f32).collect();
        for v in &f {
            out.bin.extend_from_slice(&v.to_le_bytes());
        }
        out.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": f.len() * 4, "target": 34962}));
        let mut accessor =
            json!({"bufferView": out.views.len() - 1, "componentType": 5126, "count": count, "type": acc["type"]});
        if scaled {
            let (lo, hi) = bounds(f.chunks_exact(3).map(|c| [0, 1, 2].map(|k| f64::from(c[k]))));
            accessor["min"] = lo.iter().map(|&v| v as f32).collect::<Vec<_>>().into();
            accessor["max"] = hi.iter().map(|&v| v as f32).collect::<Vec<_>>().into();
        }
        out.accessors.push(accessor);
    }
    let images = json["images"].as_array().cloned().unwrap_or_default();
    for (i, img) in images.iter().enumerate() {
        if let Some(v) = img["bufferView"].as_u64() {
            let bytes = view_bytes(&json, v as usize, bin, &mut cache)?.to_vec();
            align4(&mut out.bin);
            out.views.push(json!({"buffer": 0, "byteOffset": out.bin.len(), "byteLength": bytes.len()}));
            out.bin.extend_from_slice(&bytes);
            json["images"][i]["bufferView"] = (out.views.len() - 1).into();
        }
    }
    let root = json.as_object_mut().expect("a glTF document is an object");
    root.remove("extensionsUsed");
    root.remove("extensionsRequired");
    if let Some(node) = json["nodes"][0].as_object_mut() {
        node.remove("scale");
    }
    json["accessors"] = out.accessors.into();
    json["bufferViews"] = out.views.into();
    json["buffers"] = json!([{"byteLength": out.bin.len()}]);
    let text = serde_json::to_vec(&json).expect("JSON of plain values");
    Ok(Some(Decoded { glb: super::gltf::glb(&text, &out.bin), step_m: scale }))
}

/// The bytes of bufferView `v`, decoded if meshopt compressed them.
fn view_bytes<'c>(json: &Value, v: usize, bin: &[u8], cache: &'c mut [Option<Vec<u8>>]) -> Result<&'c [u8], String> {
    if v >= cache.len() {
        return Err(format!("bufferView {v} does not exist"));
    }
    if cache[v].is_none() {
        let view = &json["bufferViews"][v];
        let num = |x: &Value| x.as_u64().map(|n| n as usize);
        let slice = |off: usize, len: usize| {
            bin.get(off..off + len).ok_or_else(|| format!("bufferView {v} lies outside the binary chunk"))
        };
        let bytes = match view["extensions"].get("EXT_meshopt_compression") {
            Some(m) => {
                if num(&m["buffer"]) != Some(0) {
                    return Err(format!("bufferView {v}: compressed data outside the binary chunk"));
                }
                let filter = m["filter"].as_str().unwrap_or("NONE");
                if filter != "NONE" && filter != "OCTAHEDRAL" {
                    return Err(format!("bufferView {v}: meshopt filter {filter} is not supported"));
                }
                let (count, stride) = (num(&m["count"]).unwrap_or(0), num(&m["byteStride"]).unwrap_or(0));
                let data = slice(num(&m["byteOffset"]).unwrap_or(0), num(&m["byteLength"]).unwrap_or(0))?;
                let bad = |e: meshopt::Error| format!("bufferView {v}: meshopt cannot decode it: {e:?}");
                let decoded: Vec<u8> = match (m["mode"].as_str(), stride) {
                    (Some("ATTRIBUTES"), 4) => {
                        meshopt::decode_vertex_buffer::<[u8; 4]>(data, count).map_err(bad)?.concat()
                    }
                    (Some("ATTRIBUTES"), 8) => {
                        meshopt::decode_vertex_buffer::<[u8; 8]>(data, count).map_err(bad)?.concat()
                    }
                    (Some("ATTRIBUTES"), 12) => {
                        meshopt::decode_vertex_buffer::<[u8; 12]>(data, count).map_err(bad)?.concat()
                    }
                    (Some("ATTRIBUTES"), 16) => {
                        meshopt::decode_vertex_buffer::<[u8; 16]>(data, count).map_err(bad)?.concat()
                    }
                    (Some("TRIANGLES"), 2) => meshopt::decode_index_buffer::<u16>(data, count)
                        .map_err(bad)?
                        .into_iter()
                        .flat_map(u16::to_le_bytes)
                        .collect(),
                    (Some("TRIANGLES"), 4) => meshopt::decode_index_buffer::<u32>(data, count)
                        .map_err(bad)?
                        .into_iter()
                        .flat_map(u32::to_le_bytes)
                        .collect(),
                    (mode, stride) => {
                        return Err(format!("bufferView {v}: meshopt mode {mode:?} with stride {stride}"));
                    }
                };
                match (filter, stride) {
                    ("OCTAHEDRAL", 4) => {
                        let mut oct: Vec<[i8; 4]> =
                            decoded.chunks_exact(4).map(|c| [0, 1, 2, 3].map(|k| c[k] as i8)).collect();
                        meshopt::decode_filter_oct(&mut oct);
                        oct.iter().flat_map(|v| v.map(|c| c as u8)).collect()
                    }
                    ("OCTAHEDRAL", _) => return Err(format!("bufferView {v}: OCTAHEDRAL filter with stride {stride}")),
                    _ => decoded,
                }
            }
            None if num(&view["buffer"]) == Some(0) => {
                slice(num(&view["byteOffset"]).unwrap_or(0), num(&view["byteLength"]).unwrap_or(0))?.to_vec()
            }
            None => return Err(format!("bufferView {v} refers to a buffer without data")),
        };
        cache[v] = Some(bytes);
    }
    Ok(cache[v].as_deref().expect("filled above"))
}

/// An accessor's values as f64 (normalized integers mapped to [−1, 1] or
/// [0, 1]), and the number of components per element.
fn read_accessor(
    json: &Value,
    acc: &Value,
    bin: &[u8],
    cache: &mut [Option<Vec<u8>>],
) -> Result<(Vec<f64>, usize), String> {
    let n = match acc["type"].as_str() {
        Some("SCALAR") => 1,
        Some("VEC2") => 2,
        Some("VEC3") => 3,
        Some("VEC4") => 4,
        other => return Err(format!("type {other:?}")),
    };
    let ctype = acc["componentType"].as_u64().unwrap_or(0);
    let size = match ctype {
        5120 | 5121 => 1,
        5122 | 5123 => 2,
        5125 | 5126 => 4,
        other => return Err(format!("componentType {other}")),
    };
    let count = acc["count"].as_u64().ok_or("no count")? as usize;
    let normalized = acc["normalized"].as_bool().unwrap_or(false);
    let v = acc["bufferView"].as_u64().ok_or("no bufferView")? as usize;
    let stride = json["bufferViews"][v]["byteStride"].as_u64().map_or(n * size, |s| s as usize);
    let offset = acc["byteOffset"].as_u64().unwrap_or(0) as usize;
    let data = view_bytes(json, v, bin, cache)?;
    if count > 0 && offset + (count - 1) * stride + n * size > data.len() {
        return Err("reaches past its bufferView".into());
    }
    let mut out = Vec::with_capacity(count * n);
    for i in 0..count {
        for c in 0..n {
            let b = &data[offset + i * stride + c * size..];
            let x = match ctype {
                5120 => f64::from(b[0] as i8),
                5121 => f64::from(b[0]),
                5122 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                5123 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                5125 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                _ => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            };
            out.push(match (normalized, ctype) {
                (true, 5120) => (x / 127.0).max(-1.0),
                (true, 5121) => x / 255.0,
                (true, 5122) => (x / 32767.0).max(-1.0),
                (true, 5123) => x / 65535.0,
                _ => x,
            });
        }
    }
    Ok((out, n))
}
