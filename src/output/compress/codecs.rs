//! meshoptimizer's codecs as the writer uses them and the reader undoes
//! them: the vertex codec (version 0 for EXT_meshopt_compression, 1 for
//! KHR_meshopt_compression), the index codec, and the OCTAHEDRAL and
//! EXPONENTIAL filters' words.

use serde_json::{Value, json};

use super::sink::{Sink, align4};
use crate::config::{Meshopt, NormalEncoding};
use crate::output::glb::index_values;

/// The extensions [`super::decompress`] reads compressed bufferViews of.
pub(super) const MESHOPT_EXTENSIONS: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

impl Meshopt {
    /// The extension's name, as `extensionsUsed` and the bufferViews spell it.
    pub fn extension(self) -> &'static str {
        match self {
            Meshopt::Ext => MESHOPT_EXTENSIONS[0],
            Meshopt::Khr => MESHOPT_EXTENSIONS[1],
        }
    }

    /// meshoptimizer's vertex codec version.
    fn vertex_version(self) -> i32 {
        match self {
            Meshopt::Ext => 0,
            Meshopt::Khr => 1,
        }
    }

    /// meshoptimizer's vertex encoder level (0..=3). Version 0 is written at
    /// level 2, as its files always were; version 1 at 3, its tightest, for
    /// a few per cent more encoding time (docs/compression.md).
    fn vertex_level(self) -> i32 {
        match self {
            Meshopt::Ext => 2,
            Meshopt::Khr => 3,
        }
    }
}

/// Unit normals through meshoptimizer's OCTAHEDRAL filter as `encoding`
/// says: what the filter's input holds (the two coordinates and the third
/// component holding 1.0 in that many bits; the fourth is 0) and what the
/// decoder makes of it, the i8 normalized normal a reader gets.
pub fn octahedral(normals: &[[f32; 3]], encoding: NormalEncoding) -> (Vec<[i8; 4]>, Vec<[i8; 4]>) {
    let bits = match encoding {
        NormalEncoding::Rounded => {
            let unit: Vec<[f32; 4]> = normals.iter().map(|n| [n[0], n[1], n[2], 0.0]).collect();
            let oct: Vec<[i8; 4]> = meshopt::encode_filter_oct(&unit, 8);
            let mut decoded = oct.clone();
            meshopt::decode_filter_oct(&mut decoded);
            return (oct, decoded);
        }
        NormalEncoding::Nearest(bits) => bits,
    };
    let one = (1i32 << (bits - 1)) - 1;
    let s = f64::from(one);
    // The four lattice points around each normal's octahedral coordinates
    // (meshoptimizer's mapping: z the hemisphere axis), as filter input.
    let mut candidates: [Vec<[i8; 4]>; 4] = std::array::from_fn(|_| Vec::with_capacity(normals.len()));
    for n in normals {
        let [x, y, z] = n.map(f64::from);
        let l1 = x.abs() + y.abs() + z.abs();
        let (x, y) = if l1 > 0.0 { (x / l1, y / l1) } else { (0.0, 0.0) };
        let (u, v) = if z >= 0.0 { (x, y) } else { ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum()) };
        let (fu, fv) = ((u * s).floor(), (v * s).floor());
        for (c, (du, dv)) in candidates.iter_mut().zip([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]) {
            c.push([(fu + du).clamp(-s, s) as i8, (fv + dv).clamp(-s, s) as i8, one as i8, 0]);
        }
    }
    let decoded: Vec<Vec<[i8; 4]>> = candidates
        .iter()
        .map(|c| {
            let mut d = c.clone();
            meshopt::decode_filter_oct(&mut d);
            d
        })
        .collect();
    let mut oct = Vec::with_capacity(normals.len());
    let mut out = Vec::with_capacity(normals.len());
    for (i, n) in normals.iter().enumerate() {
        let best = (0..4)
            .max_by(|&a, &b| cosine(n, &decoded[a][i]).total_cmp(&cosine(n, &decoded[b][i])).then(b.cmp(&a)))
            .expect("four candidates");
        oct.push(candidates[best][i]);
        out.push(decoded[best][i]);
    }
    (oct, out)
}

/// The cosine of the angle between `n` and an i8 normalized vector.
pub fn cosine(n: &[f32; 3], d: &[i8; 4]) -> f64 {
    let d = [0, 1, 2].map(|k| f64::from(d[k]));
    let dot: f64 = (0..3).map(|k| d[k] * f64::from(n[k])).sum();
    let len = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    dot / (len(d) * len(n.map(f64::from))).max(f64::MIN_POSITIVE)
}

/// Compresses every stream with meshoptimizer (`codec`'s extension): the
/// compressed bytes become the new binary chunk (buffer 0) and the views
/// keep their uncompressed layout in a fallback buffer 1 that holds no
/// data. Returns buffer 1's byte length.
///
/// The views could all start at 0 in buffer 1 (it needs only to be as long
/// as the longest), 40 bytes of JSON less per chunk, but MeshLab (tinygltf)
/// reads a buffer without `uri` as the GLB's binary chunk: it refuses the
/// file only while buffer 1 is longer than that chunk, and with the shorter
/// buffer it read compressed bytes as indices and crashed.
pub fn meshopt_pack(sink: &mut Sink, codec: Meshopt) -> usize {
    let mut packed = Vec::new();
    for s in &sink.streams {
        let view = &mut sink.views[s.view];
        let (offset, length) =
            (view["byteOffset"].as_u64().unwrap_or(0) as usize, view["byteLength"].as_u64().unwrap_or(0) as usize);
        let raw = s.filtered.as_ref().map_or(&sink.bin[offset..offset + length], |(_, f)| f.as_slice());
        let encoded = if s.triangles {
            meshopt::encode_index_buffer(&index_values(raw, s.stride), s.vertices).expect("a triangle list")
        } else {
            encode_vertices(raw, s.stride, codec)
        };
        align4(&mut packed);
        view["buffer"] = 1.into();
        let mut ext = json!({
            "buffer": 0, "byteLength": encoded.len(), "byteStride": s.stride,
            "count": s.count, "mode": if s.triangles { "TRIANGLES" } else { "ATTRIBUTES" },
        });
        if !packed.is_empty() {
            ext["byteOffset"] = packed.len().into();
        }
        if let Some((filter, _)) = &s.filtered {
            ext["filter"] = (*filter).into();
        }
        view["extensions"] = json!({ codec.extension(): ext });
        packed.extend_from_slice(&encoded);
    }
    align4(&mut packed);
    std::mem::replace(&mut sink.bin, packed).len()
}

/// The vertex strides the writer makes and the reader takes: multiples of 4
/// up to 32 bytes (POSITION 8, a morph delta up to 12, three 4-byte
/// texture attributes).
const MAX_STRIDE: usize = 32;

/// meshoptimizer's vertex codec in the version and at the level `codec` uses.
fn encode_vertices(raw: &[u8], stride: usize, codec: Meshopt) -> Vec<u8> {
    encode_vertex_stream(raw, stride, codec.vertex_level(), codec.vertex_version())
        .unwrap_or_else(|e| unreachable!("the writer's vertex strides are multiples of 4 up to {MAX_STRIDE}: {e}"))
}

/// meshoptimizer's vertex codec, `version` 0 or 1 at `level` 0..=3, over
/// elements of `stride` bytes (a multiple of 4 up to 32).
pub fn encode_vertex_stream(raw: &[u8], stride: usize, level: i32, version: i32) -> Result<Vec<u8>, String> {
    fn enc<const N: usize>(raw: &[u8], level: i32, version: i32) -> Result<Vec<u8>, String> {
        let v: Vec<Element<N>> = raw.chunks_exact(N).map(|c| Element(c.try_into().expect("N bytes"))).collect();
        meshopt::encode_vertex_buffer_level(&v, level, Some(version)).map_err(|e| format!("{e:?}"))
    }
    match stride {
        4 => enc::<4>(raw, level, version),
        8 => enc::<8>(raw, level, version),
        12 => enc::<12>(raw, level, version),
        16 => enc::<16>(raw, level, version),
        20 => enc::<20>(raw, level, version),
        24 => enc::<24>(raw, level, version),
        28 => enc::<28>(raw, level, version),
        MAX_STRIDE => enc::<MAX_STRIDE>(raw, level, version),
        _ => Err(format!("stride {stride} is not a multiple of 4 up to {MAX_STRIDE}")),
    }
}

/// One element: `[u8; N]` has no `Default` for every `N`.
#[derive(Clone, Copy)]
#[repr(transparent)]
struct Element<const N: usize>([u8; N]);

impl<const N: usize> Default for Element<N> {
    fn default() -> Self {
        Element([0; N])
    }
}

/// meshoptimizer's vertex decoder for `count` elements of `stride` bytes.
fn decode_vertices(data: &[u8], count: usize, stride: usize) -> Result<Vec<u8>, String> {
    fn dec<const N: usize>(data: &[u8], count: usize) -> Result<Vec<u8>, String> {
        let v = meshopt::decode_vertex_buffer::<Element<N>>(data, count).map_err(|e| format!("{e:?}"))?;
        Ok(v.iter().flat_map(|e| e.0).collect())
    }
    match stride {
        4 => dec::<4>(data, count),
        8 => dec::<8>(data, count),
        12 => dec::<12>(data, count),
        16 => dec::<16>(data, count),
        20 => dec::<20>(data, count),
        24 => dec::<24>(data, count),
        28 => dec::<28>(data, count),
        MAX_STRIDE => dec::<MAX_STRIDE>(data, count),
        _ => Err(format!("stride {stride} is not a multiple of 4 up to {MAX_STRIDE}")),
    }
}

/// How many times its own size a meshopt stream can decode to, with room
/// to spare: a vertex stream of zeros, the densest there is, decodes to
/// 1 023 times its size with codec version 1 (each byte lane of a
/// 256-vertex block costs two control bits), an index stream takes at least
/// a byte per triangle.
const MAX_EXPANSION: usize = 2048;

/// A meshopt-compressed buffer view's bytes, decoded by the codec its
/// `mode` names but not yet by its `filter`: `ext` is the view's
/// `EXT_meshopt_compression` or `KHR_meshopt_compression` object (`count`,
/// `byteStride`, `mode`), `data` its compressed bytes. Indices come out as
/// little-endian u16 or u32, as the stride says.
pub fn decode_stream(ext: &Value, data: &[u8]) -> Result<Vec<u8>, String> {
    let num = |x: &Value| x.as_u64().map_or(0, |n| n as usize);
    let (count, stride) = (num(&ext["count"]), num(&ext["byteStride"]));
    // The decoder allocates what the file claims before it reads a byte: a
    // claim no stream of this size can hold is refused first.
    if count.checked_mul(stride).is_none_or(|n| n > MAX_EXPANSION.saturating_mul(data.len()).saturating_add(65_536)) {
        return Err(format!("{count} elements of {stride} bytes cannot come from {} compressed bytes", data.len()));
    }
    let bad = |e: meshopt::Error| format!("meshopt cannot decode it: {e:?}");
    // meshoptimizer asserts this (an abort, not an error).
    if ext["mode"] == "TRIANGLES" && !count.is_multiple_of(3) {
        return Err(format!("{count} indices are not whole triangles"));
    }
    match (ext["mode"].as_str(), stride) {
        (Some("ATTRIBUTES"), _) => {
            decode_vertices(data, count, stride).map_err(|e| format!("meshopt cannot decode it: {e}"))
        }
        (Some("TRIANGLES"), 2) => Ok(meshopt::decode_index_buffer::<u16>(data, count)
            .map_err(bad)?
            .into_iter()
            .flat_map(u16::to_le_bytes)
            .collect()),
        (Some("TRIANGLES"), 4) => Ok(meshopt::decode_index_buffer::<u32>(data, count)
            .map_err(bad)?
            .into_iter()
            .flat_map(u32::to_le_bytes)
            .collect()),
        (mode, stride) => Err(format!("meshopt mode {mode:?} with stride {stride}")),
    }
}

/// `steps` (a u16 count of 2^-`shift` cells) as one EXPONENTIAL-filter
/// word that decodes to exactly `steps`: the mantissa in 1/256-cell units
/// (`steps` · 2^(8 − shift)), the exponent undoing that. The mantissa is a
/// signed 24-bit number, so it is shifted by at most 7: only a chunk of
/// 32 768 cells or more (step 1 cell) keeps a low bit in its low byte.
pub(super) fn exp_word(steps: u16, shift: u32) -> u32 {
    let up = 8u32.saturating_sub(shift).min(7);
    let mantissa = u32::from(steps) << up;
    ((-(up as i32) as i8 as u8 as u32) << 24) | mantissa
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vertex codec's two ends agree at every stride the writer uses
    /// and in both versions, and a view the reader cannot decode says why.
    #[test]
    fn a_vertex_stream_decodes_to_what_was_encoded() {
        for stride in (4..=MAX_STRIDE).step_by(4) {
            let raw: Vec<u8> = (0..stride * 37).map(|k| (k * 7 % 251) as u8).collect();
            for version in [0, 1] {
                let data = encode_vertex_stream(&raw, stride, 3, version).expect("a stride the writer uses");
                let ext = json!({"count": 37, "byteStride": stride, "mode": "ATTRIBUTES"});
                assert_eq!(decode_stream(&ext, &data).expect("decodes"), raw, "stride {stride}, version {version}");
            }
        }
        assert!(encode_vertex_stream(&[0; 6], 6, 3, 1).unwrap_err().contains("stride 6"));
        let odd = json!({"count": 3, "byteStride": 1, "mode": "TRIANGLES"});
        assert_eq!(decode_stream(&odd, &[]).unwrap_err(), "meshopt mode Some(\"TRIANGLES\") with stride 1");
    }

    /// Every u16 step count at every horizontal step decodes, through
    /// meshoptimizer's own EXPONENTIAL decoder, to itself; a sample of a
    /// chunk up to 32 767 cells wide lands on a mantissa whose low byte is
    /// 0 (what makes the filter worth it); and the mantissa never reaches
    /// the sign bit (the widest chunks' 65 535 steps once would have).
    #[test]
    fn exponential_position_words_decode_exactly() {
        for shift in 0..=8u32 {
            let mut words: Vec<[u32; 1]> = (0..=u16::MAX).map(|v| [exp_word(v, shift)]).collect();
            assert!(words.iter().all(|w| w[0] & 0x0080_0000 == 0), "shift {shift}: a negative mantissa");
            if shift >= 1 {
                let per_cell = 1u32 << shift;
                assert!((0..=u16::MAX).step_by(per_cell as usize).all(|v| exp_word(v, shift) & 0xff == 0));
            }
            meshopt::decode_filter_exp(&mut words);
            for (v, w) in words.iter().enumerate() {
                assert_eq!(f32::from_bits(w[0]), v as f32, "shift {shift}, {v} steps");
            }
        }
    }
}
