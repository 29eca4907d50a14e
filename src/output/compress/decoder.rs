//! The reader: any `quantize`, `meshopt` or `meshopt-v1` .glb back into
//! the plain f32 glTF that `verify`, `inspect` and the viewer read, each
//! bufferView decoded and each accessor checked against its data.

use std::collections::BTreeMap;

use serde_json::{Value, json};

use super::codecs::{MESHOPT_EXTENSIONS, decode_stream};
use super::layout::bounds;
use super::sink::{Sink, align4};
use crate::output::glb::{self, accessor_layout};

/// A compressed chunk as plain glTF, and the grid it was quantized to.
pub struct Decoded {
    /// The same chunk as a .glb with f32 vertex data, u32 indices and no
    /// node scale (folded into POSITION and the morph targets), which any
    /// glTF reader (the `gltf` crate included) opens.
    pub glb: Vec<u8>,
    /// The node scale: the quantization step per axis, metres.
    pub step_m: [f64; 3],
}

/// Decodes a `quantize`, `meshopt` or `meshopt-v1` .glb into plain glTF;
/// `None` for a file that uses none of their extensions.
pub fn decompress(bytes: &[u8]) -> Result<Option<Decoded>, String> {
    let file = gltf::Glb::from_slice(bytes).map_err(|e| format!("not a GLB: {e}"))?;
    let mut json: Value = serde_json::from_slice(&file.json).map_err(|e| format!("bad JSON: {e}"))?;
    let used: Vec<&str> = json["extensionsUsed"].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
    if !used.iter().any(|e| *e == "KHR_mesh_quantization" || MESHOPT_EXTENSIONS.contains(e)) {
        return Ok(None);
    }
    let bin: &[u8] = file.bin.as_deref().unwrap_or(&[]);
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
    for prim in primitives(&json) {
        let attributes = prim["attributes"].as_object().into_iter().flat_map(|o| o.values());
        let targets =
            prim["targets"].as_array().into_iter().flatten().flat_map(|t| t.as_object()).flat_map(|o| o.values());
        for a in attributes.chain(targets).chain(prim.get("indices")) {
            if a.as_u64().is_none_or(|a| a as usize >= accessors.len()) {
                return Err(format!("a primitive refers to accessor {a}, of {}", accessors.len()));
            }
        }
    }
    let mut plain: Vec<(Vec<f64>, usize)> = Vec::with_capacity(accessors.len());
    // The file's accessor each of `plain` comes from (itself, or the one a
    // primitive's own copy was cut from).
    let mut source: Vec<usize> = (0..accessors.len()).collect();
    for (a, acc) in accessors.iter().enumerate() {
        let (mut values, n) = read_accessor(&json, acc, bin, &mut cache).map_err(|e| format!("accessor {a}: {e}"))?;
        if positions.contains(&(a as u64)) && n == 3 {
            for (i, v) in values.iter_mut().enumerate() {
                *v *= scale[i % 3];
            }
        }
        plain.push((values, n));
    }
    // A primitive's vertices are those its triangles use: where primitives
    // share a vertex set (meshopt-v1's skirt tops are surface vertices),
    // each gets its own accessors holding only those, in vertex order.
    let mut users: BTreeMap<u64, usize> = BTreeMap::new();
    for prim in primitives(&json) {
        for a in prim["attributes"].as_object().into_iter().flat_map(|o| o.values().filter_map(Value::as_u64)) {
            *users.entry(a).or_default() += 1;
        }
    }
    let mut primitive_accessors = Vec::new();
    for prim in primitives(&json) {
        let own = prim["attributes"].as_object().into_iter().flat_map(|o| o.values().filter_map(Value::as_u64));
        if !own.clone().any(|a| users[&a] > 1) {
            primitive_accessors.push(None);
            continue;
        }
        let i = prim["indices"].as_u64().ok_or("a primitive sharing vertices has no indices")? as usize;
        let idx = plain.get(i).ok_or_else(|| format!("accessor {i} does not exist"))?.0.clone();
        let targets = prim["targets"].as_array().into_iter().flatten().flat_map(|t| t["POSITION"].as_u64());
        let count = own
            .clone()
            .chain(targets.clone())
            .map(|a| plain.get(a as usize).map_or(0, |(v, n)| v.len() / n))
            .min()
            .unwrap_or(0);
        let mut remap = vec![None; count];
        for &v in &idx {
            *remap.get_mut(v as usize).ok_or("an index past the vertices")? = Some(0.0);
        }
        let mut next = 0.0;
        let kept: Vec<usize> = (0..count).filter(|&v| remap[v].is_some()).collect();
        for &v in &kept {
            remap[v] = Some(next);
            next += 1.0;
        }
        let mut map = BTreeMap::new();
        for a in own.chain(targets) {
            let (values, n) = plain.get(a as usize).ok_or_else(|| format!("accessor {a} does not exist"))?;
            let vals = kept.iter().flat_map(|&v| values[v * n..(v + 1) * n].iter().copied()).collect();
            map.insert(a, plain.len());
            plain.push((vals, *n));
            source.push(a as usize);
        }
        map.insert(i as u64, plain.len());
        plain.push((idx.iter().map(|&v| remap[v as usize].expect("marked above")).collect(), 1));
        source.push(i);
        primitive_accessors.push(Some(map));
    }
    for (a, (values, n)) in plain.iter().enumerate() {
        let acc = &accessors[source[a]];
        align4(&mut out.bin);
        let offset = out.bin.len();
        let count = values.len() / n.max(&1);
        if indices.contains(&(source[a] as u64)) {
            for v in values {
                out.bin.extend_from_slice(&(*v as u32).to_le_bytes());
            }
            out.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4, "target": 34963}));
            out.accessors.push(
                json!({"bufferView": out.views.len() - 1, "componentType": 5125, "count": count, "type": "SCALAR"}),
            );
            continue;
        }
        let scaled = positions.contains(&(source[a] as u64)) && *n == 3;
        let f: Vec<f32> = values.iter().map(|&v| v as f32).collect();
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
    for (p, map) in primitive_accessors.iter().enumerate() {
        let Some(map) = map else { continue };
        let prim = primitive_mut(&mut json, p);
        for slot in prim["attributes"].as_object_mut().into_iter().flat_map(|o| o.values_mut()) {
            *slot = map[&slot.as_u64().expect("read above")].into();
        }
        for t in prim["targets"].as_array_mut().into_iter().flatten().filter_map(Value::as_object_mut) {
            if let Some(slot) = t.get_mut("POSITION") {
                *slot = map[&slot.as_u64().expect("checked above")].into();
            }
        }
        prim["indices"] = map[&prim["indices"].as_u64().expect("read above")].into();
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
    if let Some(node) = json.get_mut("nodes").and_then(|n| n.get_mut(0)).and_then(Value::as_object_mut) {
        node.remove("scale");
    }
    json["accessors"] = out.accessors.into();
    json["bufferViews"] = out.views.into();
    json["buffers"] = json!([{"byteLength": out.bin.len()}]);
    let text = serde_json::to_vec(&json).expect("JSON of plain values");
    Ok(Some(Decoded { glb: glb::glb(&text, &out.bin), step_m: scale }))
}

/// Every primitive of every mesh, in order.
fn primitives(json: &Value) -> impl Iterator<Item = &Value> {
    json["meshes"].as_array().into_iter().flatten().flat_map(|m| m["primitives"].as_array().into_iter().flatten())
}

/// The `p`-th primitive of [`primitives`], to rewrite.
fn primitive_mut(json: &mut Value, p: usize) -> &mut Value {
    json["meshes"]
        .as_array_mut()
        .into_iter()
        .flatten()
        .flat_map(|m| m["primitives"].as_array_mut().into_iter().flatten())
        .nth(p)
        .expect("counted by primitives()")
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
            off.checked_add(len)
                .and_then(|end| bin.get(off..end))
                .ok_or_else(|| format!("bufferView {v} lies outside the binary chunk"))
        };
        let bytes = match MESHOPT_EXTENSIONS.iter().find_map(|e| view["extensions"].get(e)) {
            Some(m) => {
                if num(&m["buffer"]) != Some(0) {
                    return Err(format!("bufferView {v}: compressed data outside the binary chunk"));
                }
                let filter = m["filter"].as_str().unwrap_or("NONE");
                if !["NONE", "OCTAHEDRAL", "EXPONENTIAL"].contains(&filter) {
                    return Err(format!("bufferView {v}: meshopt filter {filter} is not supported"));
                }
                let stride = num(&m["byteStride"]).unwrap_or(0);
                let data = slice(num(&m["byteOffset"]).unwrap_or(0), num(&m["byteLength"]).unwrap_or(0))?;
                let decoded = decode_stream(m, data).map_err(|e| format!("bufferView {v}: {e}"))?;
                match (filter, stride) {
                    ("OCTAHEDRAL", 4) => {
                        let mut oct: Vec<[i8; 4]> =
                            decoded.chunks_exact(4).map(|c| [0, 1, 2, 3].map(|k| c[k] as i8)).collect();
                        meshopt::decode_filter_oct(&mut oct);
                        oct.iter().flat_map(|v| v.map(|c| c as u8)).collect()
                    }
                    ("OCTAHEDRAL", _) => return Err(format!("bufferView {v}: OCTAHEDRAL filter with stride {stride}")),
                    ("EXPONENTIAL", _) if stride.is_multiple_of(4) => {
                        let mut words: Vec<[u32; 1]> =
                            decoded.chunks_exact(4).map(|c| [u32::from_le_bytes([c[0], c[1], c[2], c[3]])]).collect();
                        meshopt::decode_filter_exp(&mut words);
                        words.iter().flat_map(|w| w[0].to_le_bytes()).collect()
                    }
                    ("EXPONENTIAL", _) => {
                        return Err(format!("bufferView {v}: EXPONENTIAL filter with stride {stride}"));
                    }
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
    let (n, size) = accessor_layout(acc)?;
    // Matrices hold nothing terrachunk writes (and a MAT2 of byte
    // components, four to the layout table, pads its columns).
    if acc["type"].as_str().is_some_and(|t| t.starts_with("MAT")) {
        return Err(format!("type {}", acc["type"]));
    }
    let ctype = acc["componentType"].as_u64().unwrap_or(0);
    let count = acc["count"].as_u64().ok_or("no count")? as usize;
    let normalized = acc["normalized"].as_bool().unwrap_or(false);
    let v = acc["bufferView"].as_u64().ok_or("no bufferView")? as usize;
    let stride = json["bufferViews"][v]["byteStride"].as_u64().map_or(n * size, |s| s as usize);
    if stride < n * size {
        return Err(format!("byteStride {stride} is shorter than its {}-byte elements", n * size));
    }
    let offset = acc["byteOffset"].as_u64().unwrap_or(0) as usize;
    let data = view_bytes(json, v, bin, cache)?;
    let end = (count.max(1) - 1)
        .checked_mul(stride)
        .and_then(|e| e.checked_add(offset))
        .and_then(|e| e.checked_add(n * size));
    if count > 0 && end.is_none_or(|e| e > data.len()) {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Matrix accessors are refused, as before the layout table was shared:
    /// to that table a MAT2 has four components, like a VEC4.
    #[test]
    fn a_matrix_accessor_is_refused() {
        let json = serde_json::json!({"bufferViews": [{"buffer": 0, "byteLength": 16}]});
        let bin = [0u8; 16];
        let acc = |ty: &str| serde_json::json!({"bufferView": 0, "componentType": 5126, "count": 1, "type": ty});
        let read = |ty: &str| read_accessor(&json, &acc(ty), &bin, &mut [None]);
        assert_eq!(read("VEC4").unwrap(), (vec![0.0; 4], 4));
        let e = read("MAT2").unwrap_err();
        assert!(e.contains("MAT2"), "{e}");
    }
}
