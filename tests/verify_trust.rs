//! `verify` and `inspect` trust nothing: they read only regular files
//! inside the tileset, each checked against a size limit and its GLB
//! header before it is read; they find the DEM by name and content hash,
//! never by a path the tileset gives; and `verify` rejects every damage to
//! the tree, the boxes, the root transform, the normals and the positions,
//! naming the chunk. Every tileset here is built from a generated grid.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{Value, json};
use terrachunk::config::{Compress, Config};
use terrachunk::pipeline::build;
use terrachunk::texture::TextureSource;
use terrachunk::verify::{MAX_TILE_BYTES, VerifyReport, read_tile, verify};

use crate::common::{cli, rewrite_glb, tileset, with_config, write_asc};

/// Rolling ground with a ridge: every level has something to refine.
fn ground(i: usize, j: usize) -> f64 {
    let (x, z) = (j as f64 / 16.0, i as f64 / 16.0);
    300.0 + 40.0 * (x.sin() * z.cos()) + 15.0 * ((x + 2.0 * z) / 3.0).sin() + 5.0 * (x * 3.1).cos()
}

/// An untextured tileset over a generated 129 × 129 grid (128 × 128
/// cells), built in a temporary folder with its DEM beside the tileset's
/// folder: `(tmp, out, dem)`.
fn built(compress: Compress) -> (tempfile::TempDir, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "crop.asc", 129, 129, ground);
    let out = tmp.path().join("out");
    let config = Config { max_error_m: 0.5, leaf_cells: Some(32), compress, ..Config::default() };
    let mut opts = with_config(&dem, &out, config);
    opts.texture = TextureSource::None;
    build(&opts).unwrap();
    (tmp, out, dem)
}

fn report(out: &Path) -> VerifyReport {
    verify(out, None).unwrap_or_else(|e| panic!("verify could not run: {e}"))
}

#[track_caller]
fn fails_naming(out: &Path, chunk: &str, says: &str) {
    let r = report(out);
    assert!(
        r.failures.iter().any(|f| f.contains(chunk) && f.contains(says)),
        "expected a failure naming {chunk} with {says:?}, got {:#?}",
        r.failures
    );
}

fn write_json(out: &Path, ts: &Value) {
    std::fs::write(out.join("tileset.json"), serde_json::to_vec(ts).unwrap()).unwrap();
}

/// The root tile's children in the index, and the index.
fn root_children(out: &Path) -> (Value, Vec<Value>) {
    let ts = tileset(out);
    let kids = ts["root"]["children"].as_array().expect("the root has children").clone();
    (ts, kids)
}

fn key_of(tile: &Value) -> String {
    let t = &tile["extras"]["terrachunk"];
    format!("{}/{}/{}", t["level"], t["x"], t["y"])
}

// ------------------------------------------------------------ reading files

#[test]
fn a_tile_linked_to_a_device_is_refused_without_reading_it() {
    let (_t, out, _) = built(Compress::None);
    assert!(report(&out).failures.is_empty(), "{:?}", report(&out).failures);
    let victim = out.join("tiles/1/0/0.glb");
    std::fs::remove_file(&victim).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &victim).unwrap();
    fails_naming(&out, "1/0/0", "symbolic link");
    // A link to a real chunk of the same tileset is refused alike.
    std::fs::remove_file(&victim).unwrap();
    std::os::unix::fs::symlink(out.join("tiles/1/1/0.glb"), &victim).unwrap();
    fails_naming(&out, "1/0/0", "symbolic link");
    // And a linked folder on the way to a chunk.
    std::fs::rename(out.join("tiles/2"), out.join("elsewhere")).unwrap();
    std::os::unix::fs::symlink(out.join("elsewhere"), out.join("tiles/2")).unwrap();
    fails_naming(&out, "2/0/0", "symbolic link");
}

#[test]
fn a_padded_tile_is_refused_by_its_glb_header() {
    let (_t, out, _) = built(Compress::None);
    let victim = out.join("tiles/1/1/1.glb");
    let mut bytes = std::fs::read(&victim).unwrap();
    let declared = bytes.len();
    bytes.extend(std::iter::repeat_n(0u8, 1 << 20));
    std::fs::write(&victim, &bytes).unwrap();
    let padded = bytes.len();
    fails_naming(&out, "1/1/1", &format!("not a GLB of {padded} bytes: its header declares {declared}"));
    // `inspect` refuses it alike, exit 2.
    let o = cli(&["inspect", victim.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("its header declares"));
}

#[test]
fn read_tile_takes_only_relative_paths_to_regular_files_inside_the_tileset() {
    let (_t, out, _) = built(Compress::None);
    let bytes = read_tile(&out, "tiles/0/0/0.glb").unwrap();
    assert_eq!(bytes, std::fs::read(out.join("tiles/0/0/0.glb")).unwrap());
    for uri in ["", "/etc/passwd", "../crop.asc", "tiles/../tileset.json", "./tileset.json", "tiles//0/0/0.glb"] {
        let e = read_tile(&out, uri).expect_err(uri).to_string();
        assert!(e.contains("not a relative path inside the tileset"), "{uri}: {e}");
    }
    let e = read_tile(&out, "tiles/0").unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
    // A chunk over the size limit is refused from its length alone.
    let big = out.join("tiles/0/0/0.glb");
    std::fs::File::options().append(true).open(&big).unwrap().set_len(MAX_TILE_BYTES + 1).unwrap();
    let e = read_tile(&out, "tiles/0/0/0.glb").unwrap_err().to_string();
    assert!(e.contains(&format!("over the {MAX_TILE_BYTES}-byte limit")), "{e}");
}

#[test]
fn inspect_refuses_devices_and_fifos_and_names_them() {
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("pipe.glb");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    for path in [Path::new("/dev/zero"), fifo.as_path()] {
        let o = cli(&["inspect", path.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(2), "{}", path.display());
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(&*path.to_string_lossy()) && e.contains("not a regular file"), "{e}");
    }
}

#[test]
fn inspect_counts_nan_positions_instead_of_printing_finite_bounds() {
    let (_t, out, _) = built(Compress::None);
    let victim = out.join("tiles/1/0/1.glb");
    poison_positions(&victim, 0, f32::NAN);
    let o = cli(&["inspect", victim.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    // The surface's 188 positions are counted; the bounds are the skirt's
    // alone, and say so.
    let surface: usize =
        text.lines().find_map(|l| l.strip_prefix("surface    ")?.split(' ').next()?.parse().ok()).unwrap();
    assert!(text.contains(&format!("NOT FINITE {surface} positions (NaN or infinite)")), "{text}");
    assert!(text.contains("(m) of the finite positions"), "{text}");
    fails_naming(&out, "1/0/1", "positions are not finite");
}

/// Sets every component of the POSITION accessor of primitive `prim` of
/// the (uncompressed) chunk at `path` to `value`.
fn poison_positions(path: &Path, prim: usize, value: f32) {
    rewrite_glb(path, |j, bin| {
        let acc =
            &j["accessors"][j["meshes"][0]["primitives"][prim]["attributes"]["POSITION"].as_u64().unwrap() as usize];
        let view = &j["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let start =
            view["byteOffset"].as_u64().unwrap_or(0) as usize + acc["byteOffset"].as_u64().unwrap_or(0) as usize;
        let stride = view["byteStride"].as_u64().unwrap_or(12) as usize;
        for v in 0..acc["count"].as_u64().unwrap() as usize {
            for c in 0..3 {
                let at = start + v * stride + 4 * c;
                bin[at..at + 4].copy_from_slice(&value.to_le_bytes());
            }
        }
    });
}

/// Negates or replaces every NORMAL of the surface of the chunk at `path`.
fn edit_normals(path: &Path, f: impl Fn([f32; 3]) -> [f32; 3]) {
    rewrite_glb(path, |j, bin| {
        let acc = &j["accessors"][j["meshes"][0]["primitives"][0]["attributes"]["NORMAL"].as_u64().unwrap() as usize];
        let view = &j["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let start =
            view["byteOffset"].as_u64().unwrap_or(0) as usize + acc["byteOffset"].as_u64().unwrap_or(0) as usize;
        let stride = view["byteStride"].as_u64().unwrap_or(12) as usize;
        for v in 0..acc["count"].as_u64().unwrap() as usize {
            let at = start + v * stride;
            let read = |c: usize| f32::from_le_bytes(bin[at + 4 * c..at + 4 * c + 4].try_into().unwrap());
            let n = f([read(0), read(1), read(2)]);
            for (c, x) in n.iter().enumerate() {
                bin[at + 4 * c..at + 4 * c + 4].copy_from_slice(&x.to_le_bytes());
            }
        }
    });
}

// ------------------------------------------------------------- the source

#[test]
fn the_source_is_recorded_by_name_and_hash_and_any_folder_gives_the_same_bytes() {
    use sha2::Digest;
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "hill.asc", 65, 65, ground);
    let other = tmp.path().join("deep/er/folder");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(&dem, other.join("hill.asc")).unwrap();
    let mut index = Vec::new();
    for (input, out) in [(dem.clone(), tmp.path().join("a")), (other.join("hill.asc"), other.join("b"))] {
        let mut opts = with_config(&input, &out, Config { max_error_m: 1.0, ..Config::default() });
        opts.texture = TextureSource::None;
        build(&opts).unwrap();
        index.push(std::fs::read(out.join("tileset.json")).unwrap());
    }
    assert!(index[0] == index[1], "the same DEM from two folders gave different tileset.json bytes");
    let text = String::from_utf8_lossy(&index[0]);
    assert!(!text.contains(&*tmp.path().to_string_lossy()), "the index holds a local path");
    let bytes = std::fs::read(&dem).unwrap();
    let sha = format!("{:x}", sha2::Sha256::digest(&bytes));
    let ts: Value = serde_json::from_slice(&index[0]).unwrap();
    assert_eq!(
        ts["extras"]["terrachunk"]["source"],
        json!([{"name": "hill.asc", "bytes": bytes.len(), "sha256": sha}])
    );
}

#[test]
fn verify_uses_the_dem_beside_the_tileset_only_when_its_content_matches() {
    let (tmp, out, dem) = built(Compress::None);
    assert!(report(&out).failures.is_empty());
    // Found in the tileset's own folder as well.
    std::fs::rename(&dem, out.join("crop.asc")).unwrap();
    assert!(report(&out).failures.is_empty());
    std::fs::rename(out.join("crop.asc"), &dem).unwrap();
    let original = std::fs::read(&dem).unwrap();
    // One height changed, same length: the hash tells.
    let mut changed = original.clone();
    let at = changed.len() - 3;
    changed[at] = if changed[at] == b'1' { b'2' } else { b'1' };
    std::fs::write(&dem, &changed).unwrap();
    let e = verify(&out, None).unwrap_err().to_string();
    assert!(e.contains("crop.asc") && e.contains("its content differs") && e.contains("--dem"), "{e}");
    // `--dem` still takes the user's file as given.
    assert!(verify(&out, Some(std::slice::from_ref(&dem))).is_ok());
    // Missing, a FIFO (no hang), a link to another file: each says why.
    std::fs::remove_file(&dem).unwrap();
    let e = verify(&out, None).unwrap_err().to_string();
    assert!(e.contains("not found there") && e.contains("--dem"), "{e}");
    assert!(Command::new("mkfifo").arg(&dem).status().unwrap().success());
    let e = verify(&out, None).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
    std::fs::remove_file(&dem).unwrap();
    std::fs::write(tmp.path().join("real.asc"), &original).unwrap();
    std::os::unix::fs::symlink(tmp.path().join("real.asc"), &dem).unwrap();
    let e = verify(&out, None).unwrap_err().to_string();
    assert!(e.contains("symbolic link"), "{e}");
}

#[test]
fn a_source_naming_a_path_outside_is_never_opened() {
    let (_t, out, _) = built(Compress::None);
    let mut ts = tileset(&out);
    for name in ["../../../../../../etc/passwd", "/etc/passwd", "..", "a/b.asc"] {
        ts["extras"]["terrachunk"]["source"][0]["name"] = json!(name);
        write_json(&out, &ts);
        let e = verify(&out, None).unwrap_err().to_string();
        assert!(e.contains("not a plain file name") && !e.contains("root:"), "{name}: {e}");
    }
    // A plain name that is a large file of another length is not read.
    ts["extras"]["terrachunk"]["source"][0]["name"] = json!("big.bin");
    write_json(&out, &ts);
    let big = std::fs::File::create(out.join("..").join("big.bin")).unwrap();
    big.set_len(3 << 30).unwrap(); // sparse: no disk, and never read
    let e = verify(&out, None).unwrap_err().to_string();
    assert!(e.contains("is 3221225472 bytes, not"), "{e}");
}

// --------------------------------------------------- damage to the contract

#[test]
fn verify_rejects_a_root_child_deleted_or_replaced_by_a_copy_of_another() {
    let (_t, out, _) = built(Compress::None);
    let (mut ts, kids) = root_children(&out);
    assert_eq!(kids.len(), 4);
    let gone = key_of(&kids[0]);
    ts["root"]["children"] = json!(kids[1..]);
    write_json(&out, &ts);
    fails_naming(&out, "0/0/0", "no child covers columns 0..=64, rows 0..=64");
    // Replaced by a copy of its sibling: listed twice, and the quarter missing.
    let mut copied = kids.clone();
    copied[0] = kids[1].clone();
    ts["root"]["children"] = json!(copied);
    write_json(&out, &ts);
    fails_naming(&out, &key_of(&kids[1]), "listed 2 times");
    fails_naming(&out, "0/0/0", "no child covers");
    assert_eq!(gone, "1/0/0");
}

#[test]
fn verify_rejects_two_thousand_duplicated_children() {
    let (_t, out, _) = built(Compress::None);
    let (mut ts, kids) = root_children(&out);
    let many: Vec<Value> = (0..2000).map(|k| kids[k % kids.len()].clone()).collect();
    ts["root"]["children"] = json!(many);
    write_json(&out, &ts);
    for k in &kids {
        fails_naming(&out, &key_of(k), "listed 500 times");
    }
}

#[test]
fn verify_rejects_a_childs_box_shrunk_or_moved() {
    let (_t, out, _) = built(Compress::None);
    let (ts, kids) = root_children(&out);
    let name = key_of(&kids[2]);
    let set_box = |edit: &dyn Fn(&mut Vec<Value>)| {
        let mut ts = ts.clone();
        let bx = ts["root"]["children"][2]["boundingVolume"]["box"].as_array_mut().unwrap();
        edit(bx);
        write_json(&out, &ts);
    };
    set_box(&|b| {
        for a in [3, 7, 11] {
            b[a] = json!(0.5); // a box 1 m across
        }
        for a in [4, 5, 6, 8, 9, 10] {
            b[a] = json!(0.0);
        }
    });
    fails_naming(&out, &name, "outside the tile's bounding box");
    set_box(&|b| b[0] = json!(b[0].as_f64().unwrap() + 1e6));
    fails_naming(&out, &name, "outside the tile's bounding box");
    fails_naming(&out, &name, "bounding box reaches outside the box of its parent 0/0/0");
    set_box(&|b| b[3] = json!(0.0));
    fails_naming(&out, &name, "half-axis of length 0");
}

#[test]
fn verify_rejects_a_root_transform_zeroed_or_moved() {
    // A georeferenced grid: the St Helens fixture's tags on a generated one
    // would need a TIFF writer; the fixture itself, cropped by the build's
    // own grid, is small enough.
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("helens.tif");
    std::fs::copy(crate::common::fixture("mount_st_helens_30m.tif"), &dem).unwrap();
    let out = tmp.path().join("out");
    let mut opts = with_config(&dem, &out, Config { max_error_m: 20.0, ..Config::default() });
    opts.texture = TextureSource::None;
    build(&opts).unwrap();
    assert!(report(&out).failures.is_empty(), "{:?}", report(&out).failures);
    let ts = tileset(&out);
    let good = ts["root"]["transform"].clone();
    assert!(good.is_array());
    for bad in [json!(vec![0.0; 16]), {
        let mut t = good.clone();
        t[12] = json!(t[12].as_f64().unwrap() + 1e6);
        t
    }] {
        let mut ts = ts.clone();
        ts["root"]["transform"] = bad;
        write_json(&out, &ts);
        fails_naming(&out, "root tile's transform", "is not the one the DEM's georeference gives");
    }
    let mut ts = ts.clone();
    ts["root"]["transform"].take();
    ts["root"].as_object_mut().unwrap().remove("transform");
    write_json(&out, &ts);
    fails_naming(&out, "root tile has no transform", "georeference gives one");
}

#[test]
fn verify_rejects_normals_that_are_nan_or_negated() {
    let (_t, out, _) = built(Compress::None);
    let victim = out.join("tiles/2/3/1.glb");
    let original = std::fs::read(&victim).unwrap();
    edit_normals(&victim, |_| [f32::NAN; 3]);
    fails_naming(&out, "2/3/1", "normals are not finite unit vectors");
    std::fs::write(&victim, &original).unwrap();
    edit_normals(&victim, |n| n.map(|c| -c));
    fails_naming(&out, "2/3/1", "normals point down");
    std::fs::write(&victim, &original).unwrap();
    edit_normals(&victim, |n| n.map(|c| 2.0 * c));
    fails_naming(&out, "2/3/1", "normals are not finite unit vectors");
}

#[test]
fn verify_rejects_a_normal_mapped_chunk_whose_normals_are_not_the_ground_up() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "hill.asc", 65, 65, ground);
    let out = tmp.path().join("out");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--normal-map", "--max-error", "0.5"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    crate::common::verified(&out);
    // Tilted 10° east: the map's relief would be lit 10° off.
    let (s, c) = 10f32.to_radians().sin_cos();
    edit_normals(&out.join("tiles/0/0/0.glb"), |n| [n[0] * c + n[1] * s, n[1] * c - n[0] * s, n[2]]);
    fails_naming(&out, "0/0/0", "normals are not the ground's up");
}

#[test]
fn verify_rejects_positions_that_are_not_finite() {
    let (_t, out, _) = built(Compress::None);
    poison_positions(&out.join("tiles/1/1/0.glb"), 1, f32::INFINITY);
    fails_naming(&out, "1/1/0", "skirt: ");
    fails_naming(&out, "1/1/0", "positions are not finite");
}

/// The quantized modes write positions rounded to their grid; the boxes in
/// the index hold them (they were up to 2.3 cm short of them).
#[test]
fn boxes_hold_their_content_in_every_output_mode() {
    for compress in [Compress::Quantize, Compress::Meshopt, Compress::MeshoptV1] {
        let (_t, out, _) = built(compress);
        let r = report(&out);
        assert!(r.failures.is_empty(), "{compress:?}: {:#?}", r.failures);
    }
}

// ------------------------------------------------------------- fuzz harness

/// The `tileset` fuzz target's harness, run here so that `cargo test`
/// exercises it without a nightly toolchain.
#[allow(dead_code)]
#[path = "../fuzz/src/lib.rs"]
mod harness;

#[test]
fn the_tileset_fuzz_harness_verifies_the_template_and_survives_damage() {
    // No record: the template verifies clean (asserted inside).
    let clean = harness::verify_tileset_bytes(&[]).expect("verify runs");
    assert!(clean.failures.is_empty());
    // Junk over the index: an error, not a panic.
    let mut junk = vec![0u8, 5, 0];
    junk.extend_from_slice(b"{\"a\"");
    assert!(harness::verify_tileset_bytes(&junk).is_none());
    // A chunk cut to its first 40 bytes: verify runs and names it.
    let mut cut = vec![1u8, 40, 0];
    cut.extend(std::iter::repeat_n(7u8, 40));
    let r = harness::verify_tileset_bytes(&cut).expect("verify runs");
    assert!(!r.failures.is_empty());
    // Every file replaced by a few bytes of the one before it.
    let mut all = Vec::new();
    for f in 0..20u8 {
        all.extend_from_slice(&[f, 3, 0, b'g', b'l', b'T']);
    }
    harness::verify_tileset_bytes(&all);
}

/// [`built`] with at most five tiles an index file: `tileset.json` over
/// external tilesets.
fn built_split() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "crop.asc", 129, 129, ground);
    let out = tmp.path().join("out");
    let config = Config { max_error_m: 0.5, leaf_cells: Some(32), index_tiles: 5, ..Config::default() };
    let mut opts = with_config(&dem, &out, config);
    opts.texture = TextureSource::None;
    build(&opts).unwrap();
    (tmp, out)
}

/// The external tilesets beside `tileset.json`, by name.
fn external_files(out: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.starts_with("tileset-") && n.ends_with(".json"))
        .collect();
    names.sort();
    names
}

/// Tiles with chunk content in a parsed index file.
fn chunk_tiles(tile: &Value) -> usize {
    let own = usize::from(tile["content"]["uri"].as_str().is_some_and(|u| u.ends_with(".glb")));
    own + tile["children"].as_array().map_or(0, |k| k.iter().map(chunk_tiles).sum())
}

#[test]
fn an_index_over_index_tiles_is_external_tilesets_that_read_back_as_the_one_file_index() {
    let (_a, one, _) = built(Compress::None);
    let (_b, split) = built_split();
    assert!(external_files(&one).is_empty(), "21 tiles fit the default index file");
    let names = external_files(&split);
    assert_eq!(names, ["tileset-1-0-0.json", "tileset-1-0-1.json", "tileset-1-1-0.json", "tileset-1-1-1.json"]);
    for name in &names {
        let ext: Value = serde_json::from_slice(&std::fs::read(split.join(name)).unwrap()).unwrap();
        assert_eq!(ext["asset"]["version"], "1.1");
        let n = chunk_tiles(&ext["root"]);
        assert!((1..=5).contains(&n), "{name}: {n} tiles");
        // The referring tile's error is the parent's δ, the root's its own.
        assert!(ext["geometricError"].as_f64() > ext["root"]["geometricError"].as_f64(), "{name}");
    }
    // The root index refers to them from childless tiles, and holds level 0.
    let root = tileset(&split);
    assert_eq!(chunk_tiles(&root["root"]), 1);
    for kid in root["root"]["children"].as_array().unwrap() {
        assert!(kid["children"].is_null() && kid["content"]["uri"].as_str().unwrap().ends_with(".json"));
    }
    // Read back whole, the same index as one file; the chunks are the same bytes.
    let read = terrachunk::verify::read_tileset(&split).unwrap();
    assert!(read == tileset(&one), "the external tilesets read back as another tree");
    let glbs = |dir: &Path| {
        crate::common::all_files(dir)
            .into_iter()
            .filter(|(p, _)| p.extension().is_some_and(|e| e == "glb"))
            .collect::<Vec<_>>()
    };
    assert!(glbs(&one) == glbs(&split), "the chunks differ with the index split");
    let r = report(&split);
    assert!(r.failures.is_empty(), "{:#?}", r.failures);
}

#[test]
fn verify_rejects_an_external_tileset_missing_moved_or_under_a_tile_with_children() {
    let (_t, out) = built_split();
    let keep = |name: &str| std::fs::read(out.join(name)).unwrap();
    let (ts, ext) = (keep("tileset.json"), keep("tileset-1-1-0.json"));
    let restore = || {
        std::fs::write(out.join("tileset.json"), &ts).unwrap();
        std::fs::write(out.join("tileset-1-1-0.json"), &ext).unwrap();
    };
    std::fs::remove_file(out.join("tileset-1-1-0.json")).unwrap();
    fails_naming(&out, "tileset-1-1-0.json", "cannot read");
    restore();
    // Its root's box moved out of the referring tile's.
    let mut moved: Value = serde_json::from_slice(&ext).unwrap();
    let b = &mut moved["root"]["boundingVolume"]["box"];
    b[0] = json!(b[0].as_f64().unwrap() + 1e4);
    std::fs::write(out.join("tileset-1-1-0.json"), serde_json::to_vec(&moved).unwrap()).unwrap();
    fails_naming(&out, "tileset-1-1-0.json", "not inside the referring tile's");
    restore();
    // A referring tile with children, and one naming a file in a folder.
    let mut index: Value = serde_json::from_slice(&ts).unwrap();
    let kids = index["root"]["children"].clone();
    index["root"]["children"][0]["children"] = json!([kids[1].clone()]);
    write_json(&out, &index);
    fails_naming(&out, "tileset-1-0-0.json", "has children");
    let mut index: Value = serde_json::from_slice(&ts).unwrap();
    index["root"]["children"][2]["content"]["uri"] = json!("tiles/tileset-1-1-0.json");
    write_json(&out, &index);
    fails_naming(&out, "tiles/tileset-1-1-0.json", "beside tileset.json");
    // Referred to twice.
    let mut index: Value = serde_json::from_slice(&ts).unwrap();
    index["root"]["children"][3] = kids[0].clone();
    write_json(&out, &index);
    fails_naming(&out, "tileset-1-0-0.json", "not the first to refer to it");
    restore();
    let r = report(&out);
    assert!(r.failures.is_empty(), "{:#?}", r.failures);
}
