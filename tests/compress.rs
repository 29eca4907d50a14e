//! `compress = "quantize" | "meshopt" | "meshopt-v1"`: each mode builds,
//! passes the Khronos validator (the meshopt modes with no more than the
//! infos an unknown extension brings) and `verify` (which decodes the files
//! and re-measures δ, borders and morph targets); quantized borders agree
//! exactly across neighbours; meshopt decodes byte for byte to what
//! quantize writes in the same triangle order, meshopt-v1 (whose skirt tops
//! are surface vertices) to the same surface (with the same normal
//! encoding) and the same skirt triangles from fewer vertices; both are
//! smaller (under 10 and 9 bytes per surface vertex on St Helens), and the
//! same at any thread count; the
//! octahedral normal encodings keep their angle bounds; a relief u16 cannot
//! hold at a step small against δ is refused.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::Value;
use terrachunk::config::NormalEncoding;
use terrachunk::config::{Compress, Config, Mesher, NORMAL_BITS_V1, VertexCache};
use terrachunk::output::compress::{cosine, decompress, octahedral};
use terrachunk::pipeline::{BuildOptions, Report, build};
use terrachunk::texture::TextureSource;

use crate::common::{
    all_files, assert_bad_input, cli, dem_of, fixture, khronos_validate, verified, with_config, write_asc,
};

fn build_mode(dem: &Path, out: &Path, compress: Compress, texture: TextureSource, threads: usize) -> Report {
    let config = Config { max_error_m: 1.0, threads, compress, ..Config::default() };
    let opts = BuildOptions { texture, ..with_config(dem, out, config) };
    build(&opts).unwrap_or_else(|e| panic!("{compress:?}: {e}"))
}

fn glb_bytes(out: &Path) -> u64 {
    all_files(out).iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")).map(|(_, b)| b.len() as u64).sum()
}

fn glb_json(bytes: &[u8]) -> Value {
    serde_json::from_slice(&gltf::Glb::from_slice(bytes).unwrap().json).unwrap()
}

/// The validator's infos, each allowed: the images' non-power-of-two sizes
/// in any mode, and in a meshopt mode that it cannot check the extension
/// (once per file, by name) and so sees nothing use the binary chunk.
#[track_caller]
fn assert_validator_infos(report: &Value, compress: Compress) {
    assert_eq!(report["warnings"], 0, "{report}");
    let files = report["files"].as_u64().unwrap();
    let unknown = compress.meshopt().map(|m| format!("UNSUPPORTED_EXTENSION {}", m.extension()));
    for (info, n) in report["infos"].as_object().unwrap() {
        let allowed = info.starts_with("IMAGE_NPOT_DIMENSIONS /images/")
            || (unknown.is_some() && info == "UNUSED_OBJECT /buffers/0")
            || Some(info) == unknown.as_ref();
        assert!(allowed, "{compress:?}: validator info {info} ({n} files)");
    }
    if let Some(u) = unknown {
        assert_eq!(report["infos"][&u], files, "{compress:?}: {report}");
    }
}

#[test]
fn every_compress_mode_verifies_and_passes_the_khronos_validator() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("jacksboro_fault_u16.png");
    for (name, compress, normal_map) in [
        ("none", Compress::None, false),
        ("quantize", Compress::Quantize, false),
        ("meshopt", Compress::Meshopt, false),
        ("meshopt-normal-map", Compress::Meshopt, true),
        ("meshopt-v1", Compress::MeshoptV1, false),
        ("meshopt-v1-normal-map", Compress::MeshoptV1, true),
    ] {
        let out = tmp.path().join(name);
        let config = Config { max_error_m: 1.0, compress, normal_map, ..Config::default() };
        build(&with_config(&dem, &out, config)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let v = verified(&out);
        for (l, lv) in &v.levels {
            assert!(lv.max_error_m <= lv.delta_m, "{name} level {l}: {} > δ {}", lv.max_error_m, lv.delta_m);
        }
        assert!(v.borders_checked > 0, "{name}: no borders compared");
        let report = khronos_validate(&out);
        assert!(report["files"].as_u64().unwrap() > 10, "{name}: {report}");
        assert_validator_infos(&report, compress);
        let (_, first) = all_files(&out).into_iter().find(|(p, _)| p.ends_with("tiles/0/0/0.glb")).unwrap();
        let j = glb_json(&first);
        let required = j["extensionsRequired"].clone();
        match compress {
            Compress::None => assert!(required.is_null() && j["nodes"][0]["scale"].is_null(), "{name}: {j}"),
            Compress::Quantize => assert_eq!(required, serde_json::json!(["KHR_mesh_quantization"])),
            Compress::Meshopt => {
                assert_eq!(required, serde_json::json!(["KHR_mesh_quantization", "EXT_meshopt_compression"]));
                assert_eq!(j["buffers"][1]["extensions"]["EXT_meshopt_compression"]["fallback"], true);
                assert!(j["nodes"][0]["name"].is_string(), "{name}: meshopt files stay as they were");
            }
            Compress::MeshoptV1 => {
                assert_eq!(required, serde_json::json!(["KHR_mesh_quantization", "KHR_meshopt_compression"]));
                assert_eq!(j["buffers"][1]["extensions"]["KHR_meshopt_compression"]["fallback"], true);
                // The lean JSON: no names, no default roughness.
                for object in ["nodes", "meshes", "materials"] {
                    assert!(j[object][0]["name"].is_null(), "{name}: {j}");
                }
                assert!(j["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"].is_null(), "{name}: {j}");
            }
        }
    }
}

#[test]
fn meshopt_over_nodata_and_below_sea_level_verifies_and_validates() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, max_error_m, compress) in [
        ("west_bijou_gully_3m.asc", 0.25, Compress::Meshopt),
        ("salish_sea_topobathy_f32.tif", 5.0, Compress::Meshopt),
        ("west_bijou_gully_3m.asc", 0.25, Compress::MeshoptV1),
        ("salish_sea_topobathy_f32.tif", 5.0, Compress::MeshoptV1),
    ] {
        let out = tmp.path().join(format!("{name}-{compress:?}"));
        let config = Config { max_error_m, compress, ..Config::default() };
        build(&with_config(&fixture(name), &out, config)).unwrap_or_else(|e| panic!("{name}: {e}"));
        verified(&out);
        assert_validator_infos(&khronos_validate(&out), compress);
    }
}

/// One meshopt attribute stream decoded by meshoptimizer, `T` being one element.
fn attribute_bytes<T: Clone + Default + AsRef<[u8]>>(data: &[u8], count: usize) -> Vec<u8> {
    meshopt::decode_vertex_buffer::<T>(data, count).unwrap().iter().flat_map(|e| e.as_ref().to_vec()).collect()
}

/// Every bufferView of a .glb as a reader gets it: EXT_ and
/// KHR_meshopt_compression views decoded by meshoptimizer itself (the
/// OCTAHEDRAL filter undone), the others as stored.
fn decoded_views(bytes: &[u8]) -> Vec<Vec<u8>> {
    let glb = gltf::Glb::from_slice(bytes).unwrap();
    let j: Value = serde_json::from_slice(&glb.json).unwrap();
    let bin = glb.bin.unwrap_or_default();
    let num = |x: &Value| x.as_u64().unwrap_or(0) as usize;
    let mut out = Vec::new();
    for v in j["bufferViews"].as_array().unwrap() {
        let ext = ["EXT_meshopt_compression", "KHR_meshopt_compression"].iter().find_map(|e| v["extensions"].get(e));
        let Some(m) = ext else {
            out.push(bin[num(&v["byteOffset"])..][..num(&v["byteLength"])].to_vec());
            continue;
        };
        let data = &bin[num(&m["byteOffset"])..][..num(&m["byteLength"])];
        let (count, stride) = (num(&m["count"]), num(&m["byteStride"]));
        out.push(match (m["mode"].as_str().unwrap(), stride, m["filter"].as_str()) {
            ("TRIANGLES", 2, None) => meshopt::decode_index_buffer::<u16>(data, count)
                .unwrap()
                .into_iter()
                .flat_map(u16::to_le_bytes)
                .collect(),
            ("ATTRIBUTES", 4, Some("OCTAHEDRAL")) => {
                let mut oct = meshopt::decode_vertex_buffer::<[i8; 4]>(data, count).unwrap();
                meshopt::decode_filter_oct(&mut oct);
                oct.iter().flat_map(|e| e.map(|c| c as u8)).collect()
            }
            ("ATTRIBUTES", 12, None) => attribute_bytes::<[u8; 12]>(data, count),
            ("ATTRIBUTES", 16, None) => attribute_bytes::<[u8; 16]>(data, count),
            ("ATTRIBUTES", 20, None) => attribute_bytes::<[u8; 20]>(data, count),
            other => panic!("a meshopt view terrachunk does not write: {other:?}"),
        });
    }
    out
}

/// The document without what compression changes: where the bytes are.
/// meshopt-v1's lean JSON also drops the names and the default roughness,
/// so those are left out of the comparison too.
fn layout(bytes: &[u8]) -> Value {
    let mut j = glb_json(bytes);
    for key in ["buffers", "extensionsUsed", "extensionsRequired"] {
        j.as_object_mut().unwrap().remove(key);
    }
    for v in j["bufferViews"].as_array_mut().unwrap() {
        v.as_object_mut().unwrap().remove("buffer");
        v.as_object_mut().unwrap().remove("extensions");
    }
    for object in ["nodes", "meshes", "materials"] {
        j[object][0].as_object_mut().unwrap().remove("name");
    }
    j["materials"][0]["pbrMetallicRoughness"].as_object_mut().unwrap().remove("roughnessFactor");
    j
}

/// A decoded (plain f32) chunk's accessors, views and binary chunk: its
/// geometry, whatever the names around it.
fn geometry(glb: &[u8]) -> (Value, Value, Vec<u8>) {
    let g = gltf::Glb::from_slice(glb).unwrap();
    let j: Value = serde_json::from_slice(&g.json).unwrap();
    (j["accessors"].clone(), j["bufferViews"].clone(), g.bin.unwrap().into_owned())
}

/// One corner of a decoded triangle: POSITION, NORMAL and the morph delta,
/// as f32 bits.
type Corner = [u32; 9];

/// Each primitive of a decoded (plain f32) chunk: its role and its
/// triangles, each corner with its attributes, in the file's order.
fn triangles(glb: &[u8]) -> Vec<(String, Vec<[Corner; 3]>)> {
    let g = gltf::Glb::from_slice(glb).unwrap();
    let j: Value = serde_json::from_slice(&g.json).unwrap();
    let bin = g.bin.unwrap();
    let num = |x: &Value| x.as_u64().unwrap_or(0) as usize;
    let words = |a: usize| -> Vec<u32> {
        let acc = &j["accessors"][a];
        let view = &j["bufferViews"][num(&acc["bufferView"])];
        let start = num(&view["byteOffset"]) + num(&acc["byteOffset"]);
        let n = num(&acc["count"]) * if acc["type"] == "SCALAR" { 1 } else { 3 };
        bin[start..start + 4 * n].chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
    };
    j["meshes"][0]["primitives"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let (pos, nor) = (words(num(&p["attributes"]["POSITION"])), words(num(&p["attributes"]["NORMAL"])));
            let dy = words(num(&p["targets"][0]["POSITION"]));
            let corner = |v: u32| -> Corner {
                let v = v as usize;
                let mut c = [0; 9];
                c[..3].copy_from_slice(&pos[3 * v..3 * v + 3]);
                c[3..6].copy_from_slice(&nor[3 * v..3 * v + 3]);
                c[6..].copy_from_slice(&dy[3 * v..3 * v + 3]);
                c
            };
            let t = words(num(&p["indices"])).chunks_exact(3).map(|t| [t[0], t[1], t[2]].map(corner)).collect();
            (p["extras"]["role"].as_str().unwrap().to_string(), t)
        })
        .collect()
}

/// Triangles as a sorted list, each turned to start at its least corner
/// (the index codec may rotate a triangle's corners).
fn canonical(t: &[[Corner; 3]]) -> Vec<[Corner; 3]> {
    let mut out: Vec<[Corner; 3]> = t
        .iter()
        .map(|&[a, b, c]| {
            let m = a.min(b).min(c);
            if m == a {
                [a, b, c]
            } else if m == b {
                [b, c, a]
            } else {
                [c, a, b]
            }
        })
        .collect();
    out.sort_unstable();
    out
}

/// The vertices a compressed chunk stores: its POSITION accessors' counts,
/// each accessor once.
fn vertex_count(bytes: &[u8]) -> usize {
    let j = glb_json(bytes);
    let used: std::collections::BTreeSet<u64> = j["meshes"][0]["primitives"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["attributes"]["POSITION"].as_u64().unwrap())
        .collect();
    used.iter().map(|&a| j["accessors"][a as usize]["count"].as_u64().unwrap() as usize).sum()
}

#[test]
fn meshopt_modes_decode_to_what_quantize_writes_and_pack_under_ten_bytes_per_vertex() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("mount_st_helens_30m.tif");
    assert_eq!(Config { compress: Compress::Meshopt, ..Config::default() }.triangle_order(), VertexCache::Strip);
    assert_eq!(Config { compress: Compress::MeshoptV1, ..Config::default() }.triangle_order(), VertexCache::Strip);
    assert_eq!(Config { compress: Compress::Quantize, ..Config::default() }.triangle_order(), VertexCache::Fast);
    let v1 = Config { compress: Compress::MeshoptV1, ..Config::default() };
    assert_eq!(v1.normal_encoding(), NormalEncoding::Nearest(NORMAL_BITS_V1));
    assert_eq!(Config { compress: Compress::Meshopt, ..Config::default() }.normal_encoding(), NormalEncoding::Rounded);
    let mut bytes = BTreeMap::new();
    let mut surface_vertices = 0;
    // quantize in the meshopt modes' triangle order (and, for meshopt-v1, its
    // normal encoding), so that each pair holds the same data.
    for (name, compress, order, normal_bits) in [
        ("none", Compress::None, None, None),
        ("quantize", Compress::Quantize, Some(VertexCache::Strip), None),
        ("meshopt", Compress::Meshopt, None, None),
        ("quantize-nearest", Compress::Quantize, Some(VertexCache::Strip), Some(NORMAL_BITS_V1)),
        ("meshopt-v1", Compress::MeshoptV1, None, None),
    ] {
        let config = Config { max_error_m: 1.0, compress, vertex_cache: order, normal_bits, ..Config::default() };
        let opts = BuildOptions { texture: TextureSource::None, ..with_config(&dem, &tmp.path().join(name), config) };
        let report = build(&opts).unwrap_or_else(|e| panic!("{name}: {e}"));
        surface_vertices = report.levels.iter().map(|l| l.vertices).sum::<usize>();
        bytes.insert(name, glb_bytes(&tmp.path().join(name)));
    }
    assert!(bytes["quantize"] < bytes["none"], "{bytes:?}");
    assert!(bytes["meshopt"] < bytes["quantize"], "{bytes:?}");
    assert!(bytes["meshopt-v1"] < bytes["meshopt"], "{bytes:?}");
    // Every .glb byte (no images here) per surface vertex: meshopt gave
    // 11.6 before the strip order, the three shared views and i8 morph
    // deltas, and gives 9.59 now; meshopt-v1 9.01 before its skirt shared
    // the surface's vertices, 8.89 since.
    for (name, limit) in [("meshopt", 10.0), ("meshopt-v1", 9.0)] {
        let per_vertex = bytes[name] as f64 / surface_vertices as f64;
        assert!(per_vertex < limit, "{name}: {per_vertex:.2} bytes per surface vertex");
    }
    let (q, m) = (all_files(&tmp.path().join("quantize-nearest")), all_files(&tmp.path().join("meshopt-v1")));
    assert_eq!(q.len(), m.len(), "quantize and meshopt-v1 make the same chunks");
    let (mut written, mut shared) = (0, 0);
    for ((pq, dq), (pm, dm)) in q.iter().zip(&m) {
        assert_eq!(pq, pm);
        if pq.extension().is_some_and(|e| e == "glb") {
            // meshopt-v1's skirt tops are the surface's vertices: the same
            // surface, the same skirt triangles, fewer vertices.
            let (a, b) = (decompress(dq).unwrap().unwrap(), decompress(dm).unwrap().unwrap());
            let (ta, tb) = (triangles(&a.glb), triangles(&b.glb));
            assert_eq!(ta[0].0, "surface");
            assert!(ta[0] == tb[0], "{}: meshopt-v1 decodes to another surface", pq.display());
            assert_eq!(ta.len(), tb.len(), "{}", pq.display());
            if let (Some(sa), Some(sb)) = (ta.get(1), tb.get(1)) {
                assert_eq!(sa.0, "skirt");
                assert!(canonical(&sa.1) == canonical(&sb.1), "{}: meshopt-v1 decodes to another skirt", pq.display());
            }
            assert_eq!(a.step_m, b.step_m);
            written += vertex_count(dq);
            shared += vertex_count(dm);
        }
    }
    assert!(shared < written, "meshopt-v1 stores {shared} vertices, quantize {written}");
    // Chunks over 255 cells wide (this grid's top levels) write POSITION
    // through the EXPONENTIAL filter, in 1/256-cell mantissas; the
    // comparison above shows they decode to quantize's surface. Narrower
    // chunks keep u16 positions.
    let exponential = |bytes: &[u8]| {
        glb_json(bytes)["bufferViews"]
            .as_array()
            .unwrap()
            .iter()
            .any(|v| v["extensions"]["KHR_meshopt_compression"]["filter"] == "EXPONENTIAL")
    };
    let glbs: Vec<&Vec<u8>> =
        m.iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")).map(|(_, d)| d).collect();
    let wide = glbs.iter().filter(|d| exponential(d)).count();
    assert!(wide > 0 && wide < glbs.len(), "{wide} of {} chunks with EXPONENTIAL positions", glbs.len());
    // meshopt decodes to exactly the bytes quantize writes, in the same layout.
    let (q, m) = (all_files(&tmp.path().join("quantize")), all_files(&tmp.path().join("meshopt")));
    assert_eq!(q.len(), m.len(), "quantize and meshopt make the same chunks");
    for ((pq, dq), (pm, dm)) in q.iter().zip(&m) {
        assert_eq!(pq, pm);
        if pq.extension().is_some_and(|e| e == "glb") {
            let (views, decoded) = (decoded_views(dq), decoded_views(dm));
            assert_eq!(views.len(), 3, "{}: vertices, normals, triangles", pq.display());
            assert!(views == decoded, "{}: meshopt decodes to other bytes than quantize writes", pq.display());
            assert_eq!(layout(dq), layout(dm), "{}", pq.display());
            let (a, b) = (decompress(dq).unwrap().unwrap(), decompress(dm).unwrap().unwrap());
            assert!(geometry(&a.glb) == geometry(&b.glb), "{}: meshopt decodes to other geometry", pq.display());
            assert_eq!(a.step_m, b.step_m);
        }
    }
    // The two normal encodings differ (else this test would not tell them apart).
    let (q, n) = (all_files(&tmp.path().join("quantize")), all_files(&tmp.path().join("quantize-nearest")));
    let glb = |p: &std::path::Path| p.extension().is_some_and(|e| e == "glb");
    assert!(
        q.iter()
            .zip(&n)
            .filter(|((p, _), _)| glb(p))
            .any(|((_, a), (_, b))| decoded_views(a)[1] != decoded_views(b)[1])
    );
}

/// Half a horizontal step moves a cut point (off the sample grid) along its
/// dividing line, which on a steep triangle tilts the written surface past
/// the mesher's 2 % margin next to cut points: these waves, 10 m apart at
/// 1 m, came out at 8.020 m in a chunk of δ 8 m and 2.045 m at δ 2 m
/// (Provence at 1 m: 8.058 m in a chunk of δ 8 m, on the Verdon gorge),
/// and `verify` failed the build. The mesher now places cut points on the
/// grid (merging those that land on one point), so it measures the surface
/// as written; the check of each chunk as written and the meshing again
/// with a wider margin stay behind it, and the report would count them.
#[test]
fn cut_points_rounded_to_the_quantize_grid_keep_delta_on_steep_ground() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "steep.asc", 1025, 1025, |i, j| {
        let (i, j) = (i as f64, j as f64);
        400.0 * (0.031 * j + 0.017 * i).sin() * (0.023 * i - 0.011 * j).cos() + 30.0 * (0.9 * j).sin() * (0.7 * i).sin()
    });
    let out = tmp.path().join("out");
    // Cut points are the greedy TIN's (the bintree's vertices are samples).
    let config = Config { max_error_m: 1.0, compress: Compress::Quantize, mesher: Mesher::Tin, ..Config::default() };
    let report = build(&with_config(&dem, &out, config)).unwrap();
    // Cut points placed on the grid while meshing: the mesher measured what
    // is written, and no chunk needs meshing again (before: 8.020 m at δ 8
    // as written, then chunks meshed again with wider margins).
    assert_eq!(report.remeshed_for_cut_points, 0);
    assert!(report.over_delta_as_written.is_empty(), "{:?}", report.over_delta_as_written);
    let v = verified(&out);
    for (l, lv) in &v.levels {
        assert!(lv.max_error_m <= lv.delta_m, "level {l}: {} > δ {}", lv.max_error_m, lv.delta_m);
    }
}

/// A cut point the mesher leaves off the quantize grid is written on it,
/// and its texture coordinate maps that written position. It used to map
/// the point before rounding, up to half a step away: on 32-cell leaves
/// the step is 1/256 of a cell (the cap), more than the 1/65 535 of the
/// footprint `verify` then allowed for it. Mount St Helens here, at 5 m,
/// wrote 5 such coordinates; Sierra 3 × 3 at 5 m with 32-cell leaves in
/// `meshopt-v1` failed `verify`. `verify` now allows only the coordinate's
/// own u16 rounding, which this build passes.
#[test]
fn texture_coordinates_map_cut_points_where_the_file_puts_them() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let config = Config {
        max_error_m: 5.0,
        leaf_cells: Some(32),
        compress: Compress::Quantize,
        mesher: Mesher::Tin,
        ..Config::default()
    };
    let opts = BuildOptions {
        texture: TextureSource::Generated,
        ..with_config(&fixture("mount_st_helens_30m.tif"), &out, config)
    };
    build(&opts).unwrap();
    let v = verified(&out);
    let textured: usize = v.texture.expect("textured").levels.values().map(|l| l.chunks).sum();
    assert!(textured > 100, "{textured} textured chunks checked");
}

#[test]
fn normal_bits_outside_2_to_8_are_refused() {
    for (bits, ok) in [(1, false), (2, true), (8, true), (9, false)] {
        let config = Config { normal_bits: Some(bits), ..Config::default() };
        assert_eq!(config.validate().is_ok(), ok, "normal_bits = {bits}");
    }
}

/// The worst angle, degrees, between unit vectors and what `encoding`
/// decodes them to.
fn worst_angle_deg(normals: &[[f32; 3]], encoding: NormalEncoding) -> f64 {
    let (_, decoded) = octahedral(normals, encoding);
    normals.iter().zip(&decoded).map(|(n, d)| cosine(n, d).clamp(-1.0, 1.0).acos().to_degrees()).fold(0.0, f64::max)
}

#[test]
fn octahedral_normals_keep_their_angle_bounds() {
    // 200 000 directions spread evenly over the whole sphere (a Fibonacci
    // lattice), not only the upper half terrain normals lie in.
    let n = 200_000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let dirs: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (f64::from(i) + 0.5) / f64::from(n);
            let r = (1.0 - y * y).sqrt();
            let a = golden * f64::from(i);
            [(r * a.cos()) as f32, y as f32, (r * a.sin()) as f32]
        })
        .collect();
    let rounded = worst_angle_deg(&dirs, NormalEncoding::Rounded);
    let nearest: Vec<f64> = (6..=8).map(|b| worst_angle_deg(&dirs, NormalEncoding::Nearest(b))).collect();
    println!("worst angle: rounded 8 bits {rounded:.3}°, nearest 6/7/8 bits {nearest:.3?}°");
    // meshopt-v1's bound, and the nearest lattice point is never the worse choice.
    assert!(nearest[2] <= 1.0, "{nearest:?}");
    assert!(nearest[2] < rounded && nearest[1] < nearest[0], "{rounded} {nearest:?}");
    let (_, r) = octahedral(&dirs, NormalEncoding::Rounded);
    let (_, m) = octahedral(&dirs, NormalEncoding::Nearest(8));
    for ((d, a), b) in dirs.iter().zip(&r).zip(&m) {
        assert!(cosine(d, b) >= cosine(d, a), "{d:?}: nearest {b:?} is further than rounded {a:?}");
    }
    // A tiny exact case: straight up is exact in both, the third component
    // holds 1.0 in the filter's bits.
    let (oct, decoded) = octahedral(&[[0.0, 1.0, 0.0]], NormalEncoding::Nearest(6));
    assert_eq!((oct[0], decoded[0]), ([0, 31, 31, 0], [0, 127, 0, 0]));
}

/// Surface vertices of a `quantize` chunk in world metres, computed in f64
/// from the raw u16 steps: translation + scale · steps.
fn quantized_surface(bytes: &[u8]) -> Vec<[f64; 3]> {
    let glb = gltf::Glb::from_slice(bytes).unwrap();
    let j: Value = serde_json::from_slice(&glb.json).unwrap();
    let bin = glb.bin.unwrap();
    let node = &j["nodes"][0];
    let t: Vec<f64> = node["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let s: Vec<f64> = node["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let prim =
        j["meshes"][0]["primitives"].as_array().unwrap().iter().find(|p| p["extras"]["role"] == "surface").unwrap();
    let acc = &j["accessors"][prim["attributes"]["POSITION"].as_u64().unwrap() as usize];
    assert_eq!(acc["componentType"], 5123, "u16 positions");
    let view = &j["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
    let offset =
        [&view["byteOffset"], &acc["byteOffset"]].iter().map(|o| o.as_u64().unwrap_or(0) as usize).sum::<usize>();
    let stride = view["byteStride"].as_u64().unwrap() as usize;
    (0..acc["count"].as_u64().unwrap() as usize)
        .map(|i| {
            let b = &bin[offset + i * stride..];
            [0, 1, 2].map(|a| t[a] + s[a] * f64::from(u16::from_le_bytes([b[2 * a], b[2 * a + 1]])))
        })
        .collect()
}

#[test]
fn border_vertices_agree_across_neighbours_after_quantisation() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("q");
    let report = build_mode(&fixture("jacksboro_fault_u16.png"), &out, Compress::Quantize, TextureSource::None, 0);
    let spacing = report.spacing_m;
    let files: BTreeMap<(u32, u32, u32), Vec<[f64; 3]>> = all_files(&out)
        .into_iter()
        .filter(|(p, _)| p.extension().is_some_and(|e| e == "glb"))
        .map(|(p, b)| {
            let k: Vec<u32> =
                p.with_extension("").iter().skip(1).map(|c| c.to_str().unwrap().parse().unwrap()).collect();
            ((k[0], k[1], k[2]), quantized_surface(&b))
        })
        .collect();
    let ts: Value = serde_json::from_str(&std::fs::read_to_string(out.join("tileset.json")).unwrap()).unwrap();
    let mut footprints = BTreeMap::new();
    for (p, b) in all_files(&out).iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")) {
        let k: Vec<u32> = p.with_extension("").iter().skip(1).map(|c| c.to_str().unwrap().parse().unwrap()).collect();
        let fp = glb_json(b)["nodes"][0]["extras"]["terrachunk"]["footprint"].clone();
        footprints.insert((k[0], k[1], k[2]), [fp["x1"].as_u64().unwrap(), fp["z1"].as_u64().unwrap()]);
    }
    assert!(ts["root"].is_object());
    let mut compared = 0;
    for (&(l, x, y), verts) in &files {
        for (east, nk) in [(true, (l, x + 1, y)), (false, (l, x, y + 1))] {
            let Some(other) = files.get(&nk) else { continue };
            let (axis, along) = if east { (0, 2) } else { (2, 0) };
            let line = footprints[&(l, x, y)][usize::from(!east)] as f64 * spacing[axis / 2];
            let on = |v: &Vec<[f64; 3]>| {
                let mut s: Vec<[f64; 2]> = v
                    .iter()
                    .filter(|p| (p[axis] - line).abs() < 1e-9 * line.max(1.0))
                    .map(|p| [p[along], p[1]])
                    .collect();
                s.sort_by(|a, b| a[0].total_cmp(&b[0]));
                s
            };
            let (a, b) = (on(verts), on(other));
            assert!(!a.is_empty(), "{l}/{x}/{y}: no vertex on its border");
            assert_eq!(a.len(), b.len(), "{l}/{x}/{y} and {nk:?}: different border vertex counts");
            for (p, q) in a.iter().zip(&b) {
                assert!((p[0] - q[0]).abs() <= 1e-9 * p[0].abs().max(1.0), "{l}/{x}/{y} vs {nk:?}: {p:?} / {q:?}");
                assert_eq!(p[1], q[1], "{l}/{x}/{y} vs {nk:?}: border heights differ after quantisation");
            }
            compared += 1;
        }
    }
    assert!(compared > 10, "only {compared} borders compared");
}

#[test]
fn meshopt_output_is_byte_identical_twice_and_with_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("jacksboro_fault_u16.png");
    for compress in [Compress::Meshopt, Compress::MeshoptV1] {
        let runs = [("a", 1), ("b", 2), ("c", 2)];
        let dir = |name: &str| tmp.path().join(format!("{compress:?}-{name}"));
        for (name, threads) in runs {
            build_mode(&dem, &dir(name), compress, TextureSource::Generated, threads);
        }
        let a = all_files(&dir("a"));
        assert!(a.len() > 10);
        for (name, _) in &runs[1..] {
            let b = all_files(&dir(name));
            assert_eq!(a.len(), b.len());
            for ((pa, da), (pb, db)) in a.iter().zip(&b) {
                assert_eq!(pa, pb);
                assert!(da == db, "{compress:?}: {} differs between runs", pa.display());
            }
        }
    }
}

#[test]
fn inspect_reads_meshopt_chunks_and_the_flag_reaches_the_build() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("dfw_texas_srtm3.tif");
    for (mode, extension) in [("meshopt", "EXT_meshopt_compression"), ("meshopt-v1", "KHR_meshopt_compression")] {
        let out = tmp.path().join(mode);
        let o = cli(&[
            "build",
            dem.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--compress",
            mode,
            "--texture",
            "none",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let glb = out.join("tiles/0/0/0.glb");
        assert!(glb_json(&std::fs::read(&glb).unwrap())["extensionsUsed"].to_string().contains(extension), "{mode}");
        let o = cli(&["inspect", glb.to_str().unwrap()]);
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success() && text.contains("surface") && text.contains("vertices"), "{mode}: {text}");
        let dem = dem_of(&out);
        let o = cli(&["verify", out.to_str().unwrap(), "--dem", dem[0].to_str().unwrap()]);
        assert!(o.status.success(), "{mode}: {}", String::from_utf8_lossy(&o.stdout));
    }
}

#[test]
fn a_relief_too_tall_for_u16_heights_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    // 100 km of relief against 5 cm: a u16 height would need 1.5 m steps.
    let dem = write_asc(tmp.path(), "tall.asc", 9, 9, |i, j| if i == 4 && j == 4 { 100_000.0 } else { 0.0 });
    let out = tmp.path().join("out");
    let args =
        ["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--max-error", "0.05", "--compress", "quantize"];
    assert_bad_input(&args, &out, "needs a height step");
}

/// On a DEM of whole metres (SRTM, most integer GeoTIFFs) every sample
/// height is a multiple of the quantize step, so a triangle of samples is
/// written exactly and keeps all of δ; only triangles with a cut-point
/// corner (whose height, a line's profile, rounds) leave room for half a
/// step. Meshing every triangle to δ − step/2 instead cost California at
/// 1 m 4.8 % more surface vertices than `none`: many integer samples are
/// exactly δ off.
#[test]
fn whole_metre_heights_keep_all_of_delta_when_quantized() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "whole.asc", 257, 257, |i, j| {
        let (i, j) = (i as f64, j as f64);
        (300.0 * (0.05 * j + 0.03 * i).sin() * (0.04 * i - 0.02 * j).cos() + 20.0 * (0.5 * j).sin() * (0.3 * i).sin())
            .round()
    });
    let mut vertices = Vec::new();
    for (name, compress) in [("none", Compress::None), ("quantize", Compress::Quantize)] {
        let out = tmp.path().join(name);
        let report = build_mode(&dem, &out, compress, TextureSource::None, 0);
        let v = verified(&out);
        for (l, lv) in &v.levels {
            assert!(lv.max_error_m <= lv.delta_m, "{name} level {l}: {} > δ {}", lv.max_error_m, lv.delta_m);
        }
        vertices.push(report.levels.iter().map(|l| l.vertices).sum::<usize>() as f64);
    }
    let ratio = vertices[1] / vertices[0];
    assert!(ratio < 1.01, "quantize has {ratio:.4}× the surface vertices of none");
}

/// Was a bug in `verify`: it read a quantized file's positions through the
/// f32 form the file is decoded into, which rounds a step count times a
/// step that is no power of two (73.194 m spacing) by up to half an ulp;
/// on California at 1 m with wide top chunks that moved a cut point enough
/// to put a sample exactly δ off 2·10⁻⁵ m beyond it, and 8 chunks failed.
/// Every position `read_chunk` gives is now a whole number of steps from
/// the translation, in every quantized mode, wide top chunks included.
#[test]
fn verify_reads_quantized_positions_as_whole_steps() {
    let tmp = tempfile::tempdir().unwrap();
    let hills = |i: usize, j: usize| {
        let (x, z) = (j as f64, i as f64);
        300.0 + 120.0 * (x / 23.0).sin() * (z / 31.0).cos() + 40.0 * ((x + 2.0 * z) / 11.0).sin()
    };
    let dem = write_asc(tmp.path(), "hills.asc", 301, 301, hills);
    for compress in [Compress::Quantize, Compress::Meshopt, Compress::MeshoptV1] {
        let out = tmp.path().join(format!("{compress:?}"));
        let config = Config { compress, spacing_m: Some([73.194, 92.497]), leaf_cells: Some(64), ..Config::default() };
        build(&with_config(&dem, &out, config)).unwrap();
        for (path, _) in all_files(&out).into_iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")) {
            let c = terrachunk::verify::read_chunk(&out.join(&path)).unwrap();
            let step = c.quantization_m.expect("a quantized chunk");
            for p in &c.surface.positions {
                for a in 0..3 {
                    let steps = (p[a] - c.translation[a]) / step[a];
                    assert!((steps - steps.round()).abs() < 1e-6, "{compress:?} {}: {steps} steps", path.display());
                }
            }
        }
        verified(&out);
    }
}
