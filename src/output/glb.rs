//! What the plain writer ([`super::gltf`]), the quantized writer and the
//! reader ([`super::compress`]) share: the primitive data they take, index
//! widths, the accessor layout table and the GLB container.

use serde_json::Value;

use crate::chunk::Part;
use crate::mesh::decimate::U16_INDEXED;

/// One primitive as the writers take it: a part in vertex-cache order and
/// what the texture adds to it.
pub struct PrimData<'a> {
    /// World positions, morph offsets and triangles.
    pub part: &'a Part,
    /// NORMAL: the part's own, or +y where a normal map carries the shading.
    pub normals: Vec<[f32; 3]>,
    /// TEXCOORD_0, on a textured chunk.
    pub uv: Option<Vec<[f32; 2]>>,
    /// TANGENT (+x), with a normal map.
    pub tangents: Option<Vec<[f32; 4]>>,
    /// TEXCOORD_1, with a normal map whose size differs from the colour tile's.
    pub uv1: Option<Vec<[f32; 2]>>,
}

/// Triangles `idx` as little-endian index bytes and their glTF component
/// type: u16 (5123) while every index is below the restart value 65 535,
/// else u32 (5125). Every writer of index data goes through this.
pub(crate) fn index_bytes(idx: &[u32]) -> (Vec<u8>, u32) {
    if idx.iter().all(|&i| (i as usize) < U16_INDEXED) {
        (idx.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect(), 5123)
    } else {
        (idx.iter().flat_map(|&i| i.to_le_bytes()).collect(), 5125)
    }
}

/// The indices [`index_bytes`] wrote, read back from `raw` at `width` bytes
/// each (2 for u16, 4 for u32).
pub(crate) fn index_values(raw: &[u8], width: usize) -> Vec<u32> {
    match width {
        2 => raw.chunks_exact(2).map(|b| u32::from(u16::from_le_bytes([b[0], b[1]]))).collect(),
        _ => raw.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect(),
    }
}

/// Packs a JSON document and a binary buffer into the GLB container.
pub(crate) fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let (jl, bl) = (json.len() + pad(json.len()), bin.len() + pad(bin.len()));
    let total = 12 + 8 + jl + if bl > 0 { 8 + bl } else { 0 };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(jl as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    if bl > 0 {
        out.extend_from_slice(&(bl as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(out.len() + pad(bin.len()), 0);
    }
    out
}

/// Components per element and bytes per component of an accessor, from
/// its `type` and `componentType`.
pub(crate) fn accessor_layout(acc: &Value) -> Result<(usize, usize), String> {
    let components = match acc["type"].as_str() {
        Some("SCALAR") => 1,
        Some("VEC2") => 2,
        Some("VEC3") => 3,
        Some("VEC4" | "MAT2") => 4,
        Some("MAT3") => 9,
        Some("MAT4") => 16,
        other => return Err(format!("type {other:?}")),
    };
    let size = match acc["componentType"].as_u64() {
        Some(5120 | 5121) => 1,
        Some(5122 | 5123) => 2,
        Some(5125 | 5126) => 4,
        other => return Err(format!("componentType {other:?}")),
    };
    Ok((components, size))
}
