//! How quantized vertex data lies in a .glb: the attribute columns (u16
//! positions, i8/i16 morph deltas, normalized texture coordinates and
//! normals), interleaved into three shared bufferViews, and the index view.

use serde_json::{Value, json};

use super::codecs::{exp_word, octahedral};
use super::quantize::{Frame, U16_STEPS};
use super::sink::{Sink, Stream, align4};
use crate::config::{Meshopt, NormalEncoding};
use crate::output::glb::{PrimData, index_bytes};

/// Appends a bufferView of `bytes` (a `stride` for vertex data, none for
/// indices) and returns its index. A zero `byteOffset` is left out, as it
/// is the default.
fn push_view(sink: &mut Sink, bytes: &[u8], stride: Option<usize>) -> usize {
    align4(&mut sink.bin);
    let mut view = json!({"buffer": 0, "byteLength": bytes.len()});
    if !sink.bin.is_empty() {
        view["byteOffset"] = sink.bin.len().into();
    }
    match stride {
        Some(stride) => {
            view["byteStride"] = stride.into();
            view["target"] = 34962.into();
        }
        None => view["target"] = 34963.into(),
    }
    sink.bin.extend_from_slice(bytes);
    sink.views.push(view);
    sink.views.len() - 1
}

/// Per-component minimum and maximum, for POSITION accessors.
pub(super) fn bounds<const N: usize>(values: impl Iterator<Item = [f64; N]>) -> (Vec<f64>, Vec<f64>) {
    let (mut lo, mut hi) = (vec![f64::INFINITY; N], vec![f64::NEG_INFINITY; N]);
    for v in values {
        for a in 0..N {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    (lo, hi)
}

/// A unit vector's component as i8 normalized.
fn snorm8(v: f32) -> i8 {
    (v.clamp(-1.0, 1.0) * 127.0).round() as i8
}

/// A texture coordinate as u16 normalized.
fn unorm16(c: f32) -> u16 {
    (f64::from(c).clamp(0.0, 1.0) * U16_STEPS).round() as u16
}

/// One vertex attribute of every primitive: `size` bytes per vertex (a
/// multiple of 4, as KHR_mesh_quantization aligns vertex elements), and
/// per primitive its bytes and its accessor (type and bounds; the view,
/// offset and count are filled in where it is laid out).
struct Column {
    size: usize,
    parts: Vec<(Vec<u8>, Value)>,
}

impl Column {
    /// `size` bytes per element from `f`, the same accessor for every primitive.
    fn each<T>(size: usize, data: &[&[T]], accessor: &Value, f: impl Fn(&T) -> Vec<u8>) -> Column {
        Column { size, parts: data.iter().map(|d| (d.iter().flat_map(&f).collect(), accessor.clone())).collect() }
    }
}

/// Lays `columns` out interleaved in one view, primitive after primitive,
/// and returns each primitive's accessors in column order. `filtered` is
/// what meshopt encodes instead, with the filter that decodes it.
fn push_columns(
    sink: &mut Sink,
    columns: &[Column],
    counts: &[usize],
    filtered: Option<(&'static str, Vec<u8>)>,
) -> Vec<Vec<usize>> {
    let stride: usize = columns.iter().map(|c| c.size).sum();
    let total: usize = counts.iter().sum();
    let mut bytes = Vec::with_capacity(stride * total);
    for (p, &n) in counts.iter().enumerate() {
        for v in 0..n {
            for c in columns {
                bytes.extend_from_slice(&c.parts[p].0[v * c.size..(v + 1) * c.size]);
            }
        }
    }
    let view = push_view(sink, &bytes, Some(stride));
    sink.streams.push(Stream { view, count: total, stride, triangles: false, vertices: total, filtered });
    let mut first = 0;
    let mut out = Vec::with_capacity(counts.len());
    for (p, &n) in counts.iter().enumerate() {
        let mut offset = first * stride;
        let mut accessors = Vec::with_capacity(columns.len());
        for c in columns {
            let mut accessor = c.parts[p].1.clone();
            accessor["bufferView"] = view.into();
            accessor["count"] = n.into();
            if offset > 0 {
                accessor["byteOffset"] = offset.into();
            }
            sink.accessors.push(accessor);
            accessors.push(sink.accessors.len() - 1);
            offset += c.size;
        }
        out.push(accessors);
        first += n;
    }
    out
}

/// A primitive's positions in u16 steps, with their per-axis bounds.
fn position_steps(frame: &Frame, p: &PrimData) -> (Vec<[u16; 3]>, Vec<f64>, Vec<f64>) {
    let q: Vec<[u16; 3]> = p.part.positions.iter().map(|v| frame.position(v)).collect();
    let (min, max) = bounds(q.iter().map(|v| v.map(f64::from)));
    (q, min, max)
}

/// POSITION: u16 steps, 8 bytes per vertex, with the primitive's bounds.
fn position_column(frame: &Frame, prims: &[PrimData]) -> Column {
    let parts = prims
        .iter()
        .map(|p| {
            let (q, min, max) = position_steps(frame, p);
            let (min, max): (Vec<u64>, Vec<u64>) =
                (min.iter().map(|&v| v as u64).collect(), max.iter().map(|&v| v as u64).collect());
            let bytes = q.iter().flat_map(|v| [v[0], v[1], v[2], 0].into_iter().flat_map(u16::to_le_bytes)).collect();
            (bytes, json!({"componentType": 5123, "type": "VEC3", "min": min, "max": max}))
        })
        .collect();
    Column { size: 8, parts }
}

/// POSITION for a chunk whose horizontal step is coarser than 1/256 of a
/// cell (one over 255 cells wide), through meshoptimizer's EXPONENTIAL
/// filter: the same step counts as f32 (12 bytes per vertex, decoded), each
/// encoded as a 24-bit mantissa in 1/256-cell units and an exponent that
/// scales it back. In u16 steps of 1/128 cell or coarser, a sample's x and
/// z low bytes carry the index's low bits, which the vertex codec pays for
/// (Fuji at 1 m, levels 0 and 1: 3.10 and 2.97 bytes per vertex for
/// positions alone, 2.56 and 2.46 this way; 2.30 at the 64-cell leaves);
/// in 1/256-cell units a sample's low byte is 0, as in a narrow chunk's.
/// Heights keep their steps (exponent 0). See [`exp_word`] for the range.
fn exp_position_column(frame: &Frame, prims: &[PrimData]) -> (Column, Vec<u8>) {
    let shift = frame.k.log2().round() as u32;
    let exp = |v: u16| exp_word(v, shift);
    let mut filtered = Vec::new();
    let parts = prims
        .iter()
        .map(|p| {
            // Whole step counts: the same JSON as f64 or f32.
            let (q, min, max) = position_steps(frame, p);
            let bytes = q.iter().flat_map(|v| v.map(f32::from).into_iter().flat_map(f32::to_le_bytes)).collect();
            for v in &q {
                let e = [exp(v[0]), exp_word(v[1], 8), exp(v[2])];
                filtered.extend(e.into_iter().flat_map(u32::to_le_bytes));
            }
            (bytes, json!({"componentType": 5126, "type": "VEC3", "min": min, "max": max}))
        })
        .collect();
    (Column { size: 12, parts }, filtered)
}

/// The morph target's POSITION: whole height steps in the narrowest type
/// that holds every primitive's (they share one view): i8 (4 bytes per
/// vertex), i16 (8) or f32 holding the same whole numbers (12). A leaf's
/// samples are within δ(L−1) = 2·max_error_m of its parent's surface, 32
/// steps of max_error_m/16 (Fuji's leaves: ±31), and i8 holds its deltas
/// without the i16 high byte that flips with every sign: meshoptimizer packs
/// them about a quarter tighter.
fn delta_column(frame: &Frame, prims: &[PrimData]) -> Column {
    let steps: Vec<Vec<i64>> = prims
        .iter()
        .map(|p| {
            p.part.positions.iter().zip(&p.part.morph_dy).map(|(q, dy)| frame.delta_steps(q[1], q[1] + dy)).collect()
        })
        .collect();
    let range = |d: &[i64]| (d.iter().copied().min().unwrap_or(0), d.iter().copied().max().unwrap_or(0));
    let (lo, hi) = range(&steps.concat());
    let (size, ctype) = if lo >= i64::from(i8::MIN) && hi <= i64::from(i8::MAX) {
        (4, 5120)
    } else if lo >= -32767 && hi <= 32767 {
        (8, 5122)
    } else {
        (12, 5126)
    };
    let parts = steps
        .iter()
        .map(|d| {
            let (lo, hi) = range(d);
            let bytes: Vec<u8> = match size {
                4 => d.iter().flat_map(|&v| [0, v as i8 as u8, 0, 0]).collect(),
                8 => d.iter().flat_map(|&v| [0, v as i16, 0, 0].into_iter().flat_map(i16::to_le_bytes)).collect(),
                _ => d.iter().flat_map(|&v| [0.0, v as f32, 0.0].into_iter().flat_map(f32::to_le_bytes)).collect(),
            };
            let accessor = if ctype == 5126 {
                let (lo, hi) = (lo as f32, hi as f32);
                json!({"componentType": ctype, "type": "VEC3", "min": [0.0, lo, 0.0], "max": [0.0, hi, 0.0]})
            } else {
                json!({"componentType": ctype, "type": "VEC3", "min": [0, lo, 0], "max": [0, hi, 0]})
            };
            (bytes, accessor)
        })
        .collect();
    Column { size, parts }
}

/// Writes the quantized vertex data (KHR_mesh_quantization) of the vertex
/// sets `prims` and the primitives `triangles` (each a set and its
/// triangles; one set per primitive, except `meshopt-v1`'s surface and
/// skirt, which share one) in three bufferViews, each holding every set in
/// turn, their accessors starting where their set does:
/// - the vertices, interleaved: POSITION (u16 steps, 8 bytes), the morph
///   delta (see `delta_column`), then TEXCOORD_0 (u16 normalized),
///   TANGENT (i8 normalized) and TEXCOORD_1 where the texture has them;
/// - NORMAL, i8 normalized, 4 bytes, in a view of its own because
///   meshopt's OCTAHEDRAL filter applies to a whole view: `meshopt` stores
///   the two octahedral coordinates (which its vertex codec packs tighter
///   than three components), `quantize` what the filter decodes them to, so
///   both read alike;
/// - the triangles, u16 (u32 for a set of more than 65 535 vertices). meshoptimizer's index codec keeps the triangles'
///   order but may rotate each one's corners; both modes write the
///   rotation it decodes to, so that `meshopt` decodes to exactly what
///   `quantize` writes. Where the skirt's indices start again at 0 the
///   codec restarts its vertex counter, so one stream costs no more than two.
///
/// Three views instead of one per stream and primitive shorten the JSON and
/// save each meshopt stream's header and tail. With `meshopt-v1`, a chunk
/// over 255 cells wide has a fourth, first: POSITION alone, through the
/// EXPONENTIAL filter (see `exp_position_column`). Returns each primitive's
/// `attributes`, index accessor and morph target accessor (its set's).
pub fn write_quantized(
    sink: &mut Sink,
    frame: &Frame,
    prims: &[PrimData],
    triangles: &[(usize, &[u32])],
    normals: NormalEncoding,
    codec: Option<Meshopt>,
) -> Vec<(Value, usize, usize)> {
    let counts: Vec<usize> = prims.iter().map(|p| p.part.positions.len()).collect();
    // meshopt-v1, a chunk over 255 cells wide: POSITION in a view of its
    // own, through the EXPONENTIAL filter (see `exp_position_column`).
    let exp_positions = (codec == Some(Meshopt::Khr) && frame.k < 256.0).then(|| {
        let (column, filtered) = exp_position_column(frame, prims);
        push_columns(sink, &[column], &counts, Some(("EXPONENTIAL", filtered)))
    });
    let mut columns = vec![delta_column(frame, prims)];
    let mut names = vec![""];
    if exp_positions.is_none() {
        columns.insert(0, position_column(frame, prims));
        names.insert(0, "POSITION");
    }
    let uv_accessor = json!({"componentType": 5123, "normalized": true, "type": "VEC2"});
    let uv_bytes = |t: &[f32; 2]| t.map(unorm16).into_iter().flat_map(u16::to_le_bytes).collect();
    let uvs: Option<Vec<&[[f32; 2]]>> = prims.iter().map(|p| p.uv.as_deref()).collect();
    if let Some(uv) = uvs {
        columns.push(Column::each(4, &uv, &uv_accessor, uv_bytes));
        names.push("TEXCOORD_0");
    }
    let tangents: Option<Vec<&[[f32; 4]]>> = prims.iter().map(|p| p.tangents.as_deref()).collect();
    if let Some(t) = tangents {
        let accessor = json!({"componentType": 5120, "normalized": true, "type": "VEC4"});
        columns.push(Column::each(4, &t, &accessor, |t| t.map(|c| snorm8(c) as u8).to_vec()));
        names.push("TANGENT");
    }
    let uv1: Option<Vec<&[[f32; 2]]>> = prims.iter().map(|p| p.uv1.as_deref()).collect();
    if let Some(uv) = uv1 {
        columns.push(Column::each(4, &uv, &uv_accessor, uv_bytes));
        names.push("TEXCOORD_1");
    }
    let vertex = push_columns(sink, &columns, &counts, None);

    // Normals through the octahedral filter, and what it decodes to.
    let unit: Vec<[f32; 3]> = prims.iter().flat_map(|p| p.normals.iter().copied()).collect();
    let (oct, decoded) = octahedral(&unit, normals);
    let mut first = 0;
    let mut parts = Vec::with_capacity(prims.len());
    for &n in &counts {
        let bytes = decoded[first..first + n].iter().flat_map(|v| v.map(|c| c as u8)).collect();
        parts.push((bytes, json!({"componentType": 5120, "normalized": true, "type": "VEC3"})));
        first += n;
    }
    let filtered = oct.iter().flat_map(|v| v.map(|c| c as u8)).collect();
    let normal = push_columns(sink, &[Column { size: 4, parts }], &counts, Some(("OCTAHEDRAL", filtered)));

    // Triangles, as the index codec rotates them.
    let all: Vec<u32> = triangles.iter().flat_map(|(_, t)| t.iter().copied()).collect();
    let vertices = counts.iter().copied().max().unwrap_or(0);
    let encoded = meshopt::encode_index_buffer(&all, vertices).expect("a triangle list");
    let rotated: Vec<u32> = meshopt::decode_index_buffer(&encoded, all.len()).expect("just encoded");
    // u16, or u32 for a set denser than u16 indices hold.
    let (bytes, component) = index_bytes(&rotated);
    let stride = if component == 5125 { 4 } else { 2 };
    let view = push_view(sink, &bytes, None);
    sink.streams.push(Stream { view, count: all.len(), stride, triangles: true, vertices, filtered: None });
    let mut first = 0;
    let mut out = Vec::with_capacity(triangles.len());
    for &(p, t) in triangles {
        let n = t.len();
        let mut accessor = json!({"bufferView": view, "componentType": component, "count": n, "type": "SCALAR"});
        if first > 0 {
            accessor["byteOffset"] = (stride * first).into();
        }
        sink.accessors.push(accessor);
        first += n;
        let mut attributes = json!({"NORMAL": normal[p][0]});
        if let Some(positions) = &exp_positions {
            attributes["POSITION"] = positions[p][0].into();
        }
        for (name, &a) in names.iter().zip(&vertex[p]) {
            if !name.is_empty() {
                attributes[*name] = a.into();
            }
        }
        let delta = names.iter().position(|n| n.is_empty()).expect("the morph delta column");
        out.push((attributes, sink.accessors.len() - 1, vertex[p][delta]));
    }
    out
}
