//! Where a tileset's geometry bytes go, per stream: the figures of
//! docs/compression.md.
//!
//!     cargo run --release --example geometry_bytes -- OUT_DIR [--level 0..=3]
//!
//! "Geometry" is every .glb byte less the embedded images. It is divided by
//! the surface vertices of all levels (the surface primitives' POSITION
//! counts) and by the input samples (`grid` in tileset.json). The streams
//! are the surface's positions, morph deltas, normals, texture attributes
//! and indices, everything of the skirt, and the JSON (with the GLB's
//! headers). terrachunk stores surface and skirt in one view per stream and
//! interleaves the vertex attributes (with `meshopt-v1` the skirt's tops
//! are surface vertices: a primitive's own vertices are those its
//! triangles use that no earlier primitive did), so each stream is cut out of its
//! decoded view and, in a meshopt file, encoded again on its own with the
//! codec version the file uses, at `--level` (default: terrachunk's, 2 for
//! version 0 and 3 for version 1); the
//! last row, "sharing and padding", is what the file's actual bytes differ
//! from that sum (negative where one shared stream packs tighter). A last
//! line divides the geometry by every vertex written, surface and skirt
//! (a vertex of a shared set once): Ulrich's "unique output vertex".

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::Value;
use terrachunk::output::compress::{decode_stream, encode_vertex_stream};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args.first().map(PathBuf::from) else {
        eprintln!("usage: geometry_bytes OUT_DIR [--level 0..=3]");
        std::process::exit(2);
    };
    let level: Option<i32> = args.iter().position(|a| a == "--level").map(|i| args[i + 1].parse().expect("a level"));
    let tileset: Value = serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).expect("tileset.json"))
        .expect("tileset.json is JSON");
    let grid = &tileset["extras"]["terrachunk"]["grid"];
    let samples = grid["width"].as_u64().expect("grid width") * grid["height"].as_u64().expect("grid height");
    let mut files = Vec::new();
    glbs(&dir.join("tiles"), &mut files);
    let mut sum = Sizes::default();
    for f in &files {
        let bytes = std::fs::read(f).expect("a readable .glb");
        measure(&bytes, level, &mut sum).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
    }
    let all: u64 = std::fs::read_dir(&dir).map(|_| dir_bytes(&dir)).unwrap_or(0);
    let v = sum.surface_vertices as f64;
    let s = samples as f64;
    println!(
        "{} chunks, {} surface vertices ({:.2} per sample), {} samples",
        files.len(),
        sum.surface_vertices,
        v / s,
        samples
    );
    println!("| stream | bytes | bytes / surface vertex | bytes / sample |");
    println!("|---|---|---|---|");
    let streamed: u64 = sum.streams.values().sum();
    for (name, &b) in &sum.streams {
        println!("| {name} | {b} | {:.2} | {:.2} |", b as f64 / v, b as f64 / s);
    }
    let rest = sum.geometry as i64 - streamed as i64;
    println!("| sharing and padding | {rest} | {:.2} | {:.2} |", rest as f64 / v, rest as f64 / s);
    println!(
        "| **geometry** | {} | **{:.2}** | **{:.2}** |",
        sum.geometry,
        sum.geometry as f64 / v,
        sum.geometry as f64 / s
    );
    println!(
        "{} vertices written, surface and skirt ({:.3} per surface vertex): {:.2} bytes of geometry per written vertex",
        sum.written_vertices,
        sum.written_vertices as f64 / v,
        sum.geometry as f64 / sum.written_vertices as f64
    );
    println!("| images | {} | {:.2} | {:.2} |", sum.images, sum.images as f64 / v, sum.images as f64 / s);
    println!("| all files (tileset.json included) | {all} | {:.2} | {:.2} |", all as f64 / v, all as f64 / s);
}

fn glbs(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).expect("a tiles directory").map(|e| e.unwrap().path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            glbs(&p, out);
        } else if p.extension().is_some_and(|e| e == "glb") {
            out.push(p);
        }
    }
}

fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            if p.is_dir() { dir_bytes(&p) } else { std::fs::metadata(&p).unwrap().len() }
        })
        .sum()
}

#[derive(Default)]
struct Sizes {
    surface_vertices: u64,
    /// Every vertex the files hold, surface and skirt, a shared one once
    /// (Ulrich's "unique output vertex").
    written_vertices: u64,
    geometry: u64,
    images: u64,
    streams: BTreeMap<String, u64>,
}

/// One bufferView as the accessors see it, decoded (before any filter).
struct View {
    bytes: Vec<u8>,
    stride: usize,
    /// meshopt vertex codec version, or None for a view stored as is.
    version: Option<u8>,
}

fn measure(file: &[u8], level: Option<i32>, sum: &mut Sizes) -> Result<(), String> {
    let glb = gltf::Glb::from_slice(file).map_err(|e| e.to_string())?;
    let j: Value = serde_json::from_slice(&glb.json).map_err(|e| e.to_string())?;
    let bin = glb.bin.as_deref().unwrap_or(&[]);
    let num = |x: &Value| x.as_u64().unwrap_or(0) as usize;
    let images: u64 = j["images"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|i| j["bufferViews"][num(&i["bufferView"])]["byteLength"].as_u64().unwrap_or(0))
        .sum();
    sum.images += images;
    sum.geometry += file.len() as u64 - images;
    // GLB header, JSON chunk and the BIN chunk's header.
    *sum.streams.entry("JSON".into()).or_default() += 12 + 8 + glb.json.len() as u64 + 8;

    let mut views = Vec::new();
    for v in j["bufferViews"].as_array().ok_or("no bufferViews")? {
        let m = ["EXT_meshopt_compression", "KHR_meshopt_compression"].iter().find_map(|e| v["extensions"].get(e));
        views.push(match m {
            None => View {
                bytes: bin.get(num(&v["byteOffset"])..).unwrap_or(&[])[..num(&v["byteLength"])].to_vec(),
                stride: v["byteStride"].as_u64().map_or(0, |s| s as usize),
                version: None,
            },
            Some(m) => {
                let data = &bin[num(&m["byteOffset"])..][..num(&m["byteLength"])];
                let stride = num(&m["byteStride"]);
                let bytes = decode_stream(m, data)?;
                View { bytes, stride, version: Some(data[0] & 0x0f) }
            }
        });
    }

    // Which vertices of a shared vertex set (meshopt-v1: the skirt's tops
    // are surface vertices) were counted with an earlier primitive.
    let mut counted: BTreeMap<usize, Vec<bool>> = BTreeMap::new();
    let mut earlier: Vec<u32> = Vec::new();
    for prim in j["meshes"][0]["primitives"].as_array().ok_or("no primitives")? {
        let role = prim["extras"]["role"].as_str().unwrap_or("surface");
        let name = |what: &str| if role == "surface" { format!("surface {what}") } else { "skirt (all)".to_string() };
        let acc = &j["accessors"][num(&prim["indices"])];
        let view = &views[num(&acc["bufferView"])];
        let (offset, count) = (num(&acc["byteOffset"]), num(&acc["count"]));
        let width = if num(&acc["componentType"]) == 5125 { 4 } else { 2 };
        let idx: Vec<u32> = view.bytes[offset..offset + width * count]
            .chunks_exact(width)
            .map(|b| {
                if width == 4 {
                    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
                } else {
                    u32::from(u16::from_le_bytes([b[0], b[1]]))
                }
            })
            .collect();
        // What this primitive's triangles add to the index stream after the
        // primitives before it (the codec carries its state across them).
        let bytes = match view.version {
            None => width * count,
            Some(_) => {
                let encoded = |idx: &[u32]| -> Result<usize, String> {
                    let vertices = idx.iter().max().map_or(0, |&m| m as usize + 1);
                    Ok(meshopt::encode_index_buffer(idx, vertices).map_err(|e| format!("{e:?}"))?.len())
                };
                let before = if earlier.is_empty() { 0 } else { encoded(&earlier)? };
                earlier.extend_from_slice(&idx);
                encoded(&earlier)? - before
            }
        };
        *sum.streams.entry(name("indices")).or_default() += bytes as u64;

        // This primitive's own vertices: those its triangles use that no
        // earlier primitive counted, in vertex order.
        let position = num(&prim["attributes"]["POSITION"]);
        let n = num(&j["accessors"][position]["count"]);
        let taken = counted.entry(position).or_insert_with(|| vec![false; n]);
        let mut used = vec![false; n];
        for &i in &idx {
            used[i as usize] = true;
        }
        let own: Vec<usize> = (0..n).filter(|&v| used[v] && !taken[v]).collect();
        for &v in &own {
            taken[v] = true;
        }
        if role == "surface" {
            sum.surface_vertices += own.len() as u64;
        }
        sum.written_vertices += own.len() as u64;
        let mut attributes: Vec<(String, usize)> =
            prim["attributes"].as_object().ok_or("no attributes")?.iter().map(|(k, a)| (k.clone(), num(a))).collect();
        if let Some(t) = prim["targets"][0]["POSITION"].as_u64() {
            attributes.push(("morph delta".into(), t as usize));
        }
        for (what, a) in attributes {
            let acc = &j["accessors"][a];
            let view = &views[num(&acc["bufferView"])];
            let size: usize = match num(&acc["componentType"]) {
                5120 | 5121 => 1,
                5122 | 5123 => 2,
                _ => 4,
            } * match acc["type"].as_str() {
                Some("VEC2") => 2,
                Some("VEC3") => 3,
                _ => 4,
            };
            let size = size.div_ceil(4) * 4;
            let stride = if view.stride == 0 { size } else { view.stride };
            let offset = num(&acc["byteOffset"]);
            let column: Vec<u8> =
                own.iter().flat_map(|&i| view.bytes[offset + i * stride..][..size].iter().copied()).collect();
            let bytes = match view.version {
                None => column.len(),
                Some(version) => {
                    let level = level.unwrap_or(if version == 0 { 2 } else { 3 });
                    encode_vertex_stream(&column, size, level, i32::from(version))?.len()
                }
            };
            let what = if what == "POSITION" { "positions".to_string() } else { what.to_lowercase() };
            *sum.streams.entry(name(&what)).or_default() += bytes as u64;
        }
    }
    Ok(())
}
