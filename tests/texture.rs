//! Texture tiles end to end: the texel bound at every level (from the files,
//! not from the builder's word), border texels of neighbours equal, images
//! placed where they belong (stretched and georeferenced), the Khronos
//! validator, determinism across thread counts, untextured output unchanged,
//! the cap stated honestly, verify catching tampered tiles, and bad texture
//! files refused.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use terrachunk::config::{Config, Mesher, TextureFormat, Thin};
use terrachunk::pipeline::{BuildOptions, Report, build};
use terrachunk::texture::TextureSource;
use terrachunk::verify::verify;

use crate::common::{
    Mangler, all_files, dem_of, fixture, khronos_validate, mangle_rounds, rewrite_glb, tileset, verified, write_asc,
};

fn build_with(dem: &Path, out: &Path, config: Config, texture: TextureSource) -> Report {
    let opts = BuildOptions {
        inputs: vec![dem.to_path_buf()],
        out: out.to_path_buf(),
        force: false,
        config,
        texture,
        progress: false,
        geoid: None,
    };
    build(&opts).unwrap_or_else(|e| panic!("{}: {e}", dem.display()))
}

/// One chunk file read back for texture checks: level/x/y, footprint,
/// spacing, and its decoded images (colour first, then the normal map).
struct Tile {
    key: [u32; 3],
    footprint: [u32; 4],
    spacing: [f64; 2],
    delta_m: f64,
    images: Vec<image::RgbImage>,
    json: Value,
}

fn tiles(out: &Path) -> BTreeMap<[u32; 3], Tile> {
    let mut map = BTreeMap::new();
    for (path, bytes) in all_files(out).into_iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")) {
        let glb = gltf::Glb::from_slice(&bytes).unwrap();
        let json: Value = serde_json::from_slice(&glb.json).unwrap();
        let (_, _, images) = gltf::import_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let tc = &json["nodes"][0]["extras"]["terrachunk"];
        let u = |v: &Value| v.as_u64().unwrap() as u32;
        let fp = &tc["footprint"];
        let images = images
            .into_iter()
            .map(|d| {
                assert_eq!(d.format, gltf::image::Format::R8G8B8, "{}", path.display());
                image::RgbImage::from_raw(d.width, d.height, d.pixels).unwrap()
            })
            .collect();
        let key = [u(&tc["level"]), u(&tc["x"]), u(&tc["y"])];
        map.insert(
            key,
            Tile {
                key,
                footprint: [u(&fp["x0"]), u(&fp["x1"]), u(&fp["z0"]), u(&fp["z1"])],
                spacing: [tc["spacing_m"][0].as_f64().unwrap(), tc["spacing_m"][1].as_f64().unwrap()],
                delta_m: tc["delta_m"].as_f64().unwrap(),
                images,
                json,
            },
        );
    }
    map
}

/// T_g of a tile's image along x and z, from its size and footprint alone.
fn texel_m(t: &Tile, img: &image::RgbImage) -> [f64; 2] {
    let [x0, x1, z0, z1] = t.footprint;
    [
        f64::from(x1 - x0) * t.spacing[0] / f64::from(img.width() - 1),
        f64::from(z1 - z0) * t.spacing[1] / f64::from(img.height() - 1),
    ]
}

// ------------------------------------------------------------ the bound

#[test]
fn generated_hillshade_keeps_the_texel_bound_at_every_level() {
    // Jacksboro at 1 m spacing, leaf δ 2 m, τ_max 2 px: T_g ≤ δ/τ_max is
    // 1 m at the leaves, exactly the source's resolution, so it can hold
    // everywhere.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let cfg = Config { max_error_m: 2.0, ..Config::default() };
    let report = build_with(&fixture("jacksboro_fault_u16.png"), &out, cfg, TextureSource::Generated);
    let v = verified(&out);
    khronos_validate(&out);
    let tiles = tiles(&out);
    assert!(tiles.len() > 10);
    for t in tiles.values() {
        assert_eq!(t.images.len(), 1, "{:?}: one colour image", t.key);
        let bound = t.delta_m / 2.0;
        for (a, g) in texel_m(t, &t.images[0]).into_iter().enumerate() {
            assert!(g <= bound * (1.0 + 1e-12), "{:?} axis {a}: T_g {g} > δ/τ {bound}", t.key);
            assert!(g >= 1.0 - 1e-12, "{:?} axis {a}: T_g {g} finer than the 1 m source", t.key);
        }
    }
    for l in &report.levels {
        let t = l.texture.as_ref().unwrap();
        assert_eq!(t.over_bound, 0, "level {}", l.level);
        assert!(t.texel_m <= t.bound_m);
        assert!(t.texture_bytes > 0 && t.texture_bytes < l.bytes);
    }
    let vt = v.texture.unwrap();
    assert!(vt.levels.values().all(|l| l.at_source == 0 && l.capped == 0 && l.texel_m <= l.bound_m));
    let ex = &tileset(&out)["extras"]["terrachunk"]["texture"];
    assert!(ex["levels"].as_array().unwrap().iter().all(|l| l["bound_holds"] == true), "{ex}");
    assert_eq!(ex["source_texel_m"], serde_json::json!([1.0, 1.0]));
}

#[test]
fn a_source_coarser_than_the_bound_gives_tiles_at_source_resolution_and_says_so() {
    // Mount St Helens: 30 m samples against δ/τ_max of 2 m and finer: no
    // tile can honestly be finer than 30 m, and every level reports that.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    // The flat frame: the curved one's deeper tree (chord sag) lifts the
    // root's δ/τ_max above the source's 30 m.
    let config = Config { frame: terrachunk::config::Frame::Flat, ..Config::default() };
    let report = build_with(&fixture("mount_st_helens_30m.tif"), &out, config, TextureSource::Generated);
    let v = verified(&out);
    for l in &report.levels {
        let t = l.texture.as_ref().unwrap();
        assert_eq!((t.limited_by_source, t.limited_by_cap), (l.chunks, 0), "level {}", l.level);
        assert_eq!(t.over_bound, l.chunks);
        assert!((t.texel_m - 30.0).abs() < 1e-9, "one texel per sample: {}", t.texel_m);
    }
    let vt = v.texture.unwrap();
    for (l, c) in &vt.levels {
        assert_eq!(c.at_source, c.chunks, "level {l}");
    }
    let ex = &tileset(&out)["extras"]["terrachunk"]["texture"];
    for l in ex["levels"].as_array().unwrap() {
        assert_eq!((l["limit"].as_str(), l["bound_holds"].as_bool()), (Some("source"), Some(false)), "{l}");
    }
}

#[test]
fn a_capped_level_is_reported_and_verify_counts_it_as_the_stated_exception() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let cfg = Config { max_error_m: 2.0, max_texture_px: 64, leaf_cells: Some(200), ..Config::default() };
    let report = build_with(&fixture("jacksboro_fault_u16.png"), &out, cfg, TextureSource::Generated);
    let top = report.levels[0].texture.as_ref().unwrap();
    assert_eq!(top.limited_by_cap, 1);
    assert_eq!(top.over_bound, 1);
    assert_eq!(top.largest, [64, 64]);
    let v = verified(&out);
    let vt = v.texture.unwrap();
    assert_eq!(vt.levels[&0].capped, 1);
    assert!(vt.levels[&0].texel_m > vt.levels[&0].bound_m);
    let ex = &tileset(&out)["extras"]["terrachunk"]["texture"]["levels"][0];
    assert_eq!((ex["limit"].as_str(), ex["bound_holds"].as_bool()), (Some("max_texture_px"), Some(false)));
    // The command line says it too.
    let out2 = tmp.path().join("cli");
    let o = cli(&[
        "build",
        fixture("jacksboro_fault_u16.png").to_str().unwrap(),
        "-o",
        out2.to_str().unwrap(),
        "--max-error",
        "2",
        "--max-texture-px",
        "16",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && text.contains("max_texture_px caps them") && text.contains("T_g"), "{text}");
}

// ------------------------------------------------------------ seams

#[test]
fn neighbouring_tiles_share_their_border_texels_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let cfg = Config { max_error_m: 1.0, normal_map: true, ..Config::default() };
    build_with(&fixture("jacksboro_fault_u16.png"), &out, cfg, TextureSource::Generated);
    verified(&out);
    let tiles = tiles(&out);
    let mut compared = 0;
    for t in tiles.values() {
        let [l, x, y] = t.key;
        assert_eq!(t.images.len(), 2, "colour and normal map");
        for (east, n) in [(true, tiles.get(&[l, x + 1, y])), (false, tiles.get(&[l, x, y + 1]))] {
            let Some(n) = n else { continue };
            for (a, b) in t.images.iter().zip(&n.images) {
                let (line_a, line_b): (Vec<_>, Vec<_>) = if east {
                    assert_eq!(a.height(), b.height(), "{:?}: texels along the shared edge", t.key);
                    (
                        (0..a.height()).map(|i| a[(a.width() - 1, i)]).collect(),
                        (0..b.height()).map(|i| b[(0, i)]).collect(),
                    )
                } else {
                    assert_eq!(a.width(), b.width(), "{:?}", t.key);
                    (
                        (0..a.width()).map(|j| a[(j, a.height() - 1)]).collect(),
                        (0..b.width()).map(|j| b[(j, 0)]).collect(),
                    )
                };
                assert!(line_a == line_b, "{:?} and {:?}: border texels differ", t.key, n.key);
                compared += 1;
            }
        }
    }
    assert!(compared > 40, "{compared}");
}

#[test]
fn jpeg_tiles_are_smaller_and_match_within_the_compression_error() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("salish_sea_topobathy_f32.tif");
    let (png, jpg) = (tmp.path().join("png"), tmp.path().join("jpg"));
    let base = Config { max_error_m: 5.0, leaf_cells: Some(30), ..Config::default() };
    let rp = build_with(&dem, &png, base.clone(), TextureSource::Generated);
    let cfg = Config { texture_format: TextureFormat::Jpeg, jpeg_quality: 80, ..base };
    let rj = build_with(&dem, &jpg, cfg, TextureSource::Generated);
    let tex = |r: &Report| r.levels.iter().map(|l| l.texture.as_ref().unwrap().texture_bytes).sum::<u64>();
    assert!(tex(&rj) < tex(&rp), "jpeg {} vs png {}", tex(&rj), tex(&rp));
    let v = verified(&jpg);
    let t = v.texture.unwrap();
    assert!(t.seams_checked > 10 && t.max_seam_diff > 0 && t.max_seam_diff <= t.seam_tolerance, "{t:?}");
    khronos_validate(&jpg);
    let j = &tiles(&jpg)[&[0, 0, 0]].json;
    assert_eq!(j["images"][0]["mimeType"], "image/jpeg");
}

// ------------------------------------------------------------ placement

/// A colour that says where it is: pixel (c, r) of an image.
fn marker(c: u32, r: u32) -> image::Rgb<u8> {
    let h = c.wrapping_mul(2_654_435_761) ^ r.wrapping_mul(40_503).rotate_left(7);
    image::Rgb([(h >> 3) as u8, (h >> 11) as u8, (h >> 19) as u8])
}

#[test]
fn an_image_of_the_dem_size_lands_texel_for_sample() {
    // A 65 × 65 DEM and a 65 × 65 image of position-coded colours: stretched
    // over the DEM, pixel (c, r) sits on sample (c, r). Wherever a tile is as
    // fine as the source, its texel (k, l) must be exactly the pixel at its
    // sample, whichever chunk and level it belongs to.
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "hill.asc", 65, 65, |i, j| (i as f64 / 9.0).sin() * (j as f64 / 7.0).cos() * 40.0);
    let img = image::RgbImage::from_fn(65, 65, marker);
    let png = tmp.path().join("photo.png");
    img.save(&png).unwrap();
    let out = tmp.path().join("out");
    let cfg = Config { max_error_m: 0.25, leaf_cells: Some(16), ..Config::default() };
    build_with(&dem, &out, cfg, TextureSource::Image(png));
    verified(&out);
    khronos_validate(&out);
    let ex = &tileset(&out)["extras"]["terrachunk"]["texture"];
    assert_eq!(ex["source"], "photo.png");
    assert!(ex["placement"].as_str().unwrap().starts_with("stretched"));
    let mut exact = 0;
    for t in tiles(&out).values() {
        let [x0, x1, z0, z1] = t.footprint;
        let im = &t.images[0];
        if (im.width(), im.height()) != (x1 - x0 + 1, z1 - z0 + 1) {
            continue;
        }
        for l in 0..im.height() {
            for k in 0..im.width() {
                assert_eq!(im[(k, l)], img[(x0 + k, z0 + l)], "{:?} texel ({k}, {l})", t.key);
            }
        }
        exact += 1;
    }
    assert!(exact >= 16, "{exact} tiles at source resolution");
}

fn geotiff_keys(epsg: u16) -> [u16; 16] {
    // Projected, PixelIsArea, ProjectedCSType = epsg.
    [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, epsg]
}

/// A projected float DEM: `w × h` samples of 10 m, north-west corner at (x, y).
fn write_dem_tif(path: &Path, w: u32, h: u32, corner: [f64; 2], epsg: u16) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let data: Vec<f32> = (0..w * h).map(|k| 100.0 + ((k % w) as f32 * 0.3).sin() * 20.0 + (k / w) as f32).collect();
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(w, h).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[10.0, 10.0, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, corner[0], corner[1], 0.0][..]).unwrap();
    e.write_tag(Tag::GeoKeyDirectoryTag, &geotiff_keys(epsg)[..]).unwrap();
    img.write_data(&data).unwrap();
}

/// An RGB GeoTIFF of `pixel_m` pixels whose red is its column and green its row.
fn write_photo_tif(path: &Path, w: u32, h: u32, corner: [f64; 2], epsg: u16, pixel_m: f64) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let data: Vec<u8> = (0..w * h).flat_map(|k| [(k % w) as u8, (k / w) as u8, 90]).collect();
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::RGB8>(w, h).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[pixel_m, pixel_m, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, corner[0], corner[1], 0.0][..]).unwrap();
    e.write_tag(Tag::GeoKeyDirectoryTag, &geotiff_keys(epsg)[..]).unwrap();
    img.rows_per_strip(7).unwrap();
    img.write_data(&data).unwrap();
}

#[test]
fn a_georeferenced_geotiff_lands_at_its_coordinates() {
    // DEM: 41 × 41 samples of 10 m, corner (500 000, 5 000 000), UTM 10N.
    // Photo: 5 m pixels from 100 m further west and north, 122 × 122.
    // Sample (j, i) is at x = 500 005 + 10 j; the photo's column there is
    // (x − 499 902.5) / 5 = 20.5 + 2 j, its row 20.5 + 2 i.
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    write_dem_tif(&dem, 41, 41, [500_000.0, 5_000_000.0], 32610);
    let photo = tmp.path().join("photo.tif");
    write_photo_tif(&photo, 122, 122, [499_900.0, 5_000_100.0], 32610, 5.0);
    let out = tmp.path().join("out");
    // With a normal map from the 10 m DEM: its tiles differ in size from the
    // 5 m photo's, so it gets its own TEXCOORD_1.
    let cfg = Config { max_error_m: 0.5, leaf_cells: Some(10), normal_map: true, ..Config::default() };
    build_with(&dem, &out, cfg, TextureSource::Image(photo.clone()));
    verified(&out);
    khronos_validate(&out);
    let ex = &tileset(&out)["extras"]["terrachunk"]["texture"];
    assert_eq!(ex["placement"], "georeferenced (EPSG:32610)");
    assert_eq!(ex["source_texel_m"], serde_json::json!([5.0, 5.0]));
    let (mut checked, mut own_uv) = (0, 0);
    for t in tiles(&out).values() {
        if t.images[0].dimensions() != t.images[1].dimensions() {
            own_uv += 1;
            assert_eq!(t.json["materials"][0]["normalTexture"]["texCoord"], 1, "{:?}", t.key);
            assert!(t.json["meshes"][0]["primitives"][0]["attributes"].get("TEXCOORD_1").is_some());
        }
        let [x0, x1, z0, z1] = t.footprint;
        let im = &t.images[0];
        for l in 0..im.height() {
            for k in 0..im.width() {
                let j = f64::from(x0) + f64::from(k) * f64::from(x1 - x0) / f64::from(im.width() - 1);
                let i = f64::from(z0) + f64::from(l) * f64::from(z1 - z0) / f64::from(im.height() - 1);
                let p = im[(k, l)];
                // Averaged in linear light: a smooth ramp stays within a level or two.
                assert!((f64::from(p[0]) - (20.5 + 2.0 * j)).abs() <= 2.0, "{:?} ({k}, {l}): {p:?} at j {j}", t.key);
                assert!((f64::from(p[1]) - (20.5 + 2.0 * i)).abs() <= 2.0, "{:?} ({k}, {l}): {p:?} at i {i}", t.key);
                checked += 1;
            }
        }
    }
    assert!(checked > 5000, "{checked}");
    assert!(own_uv > 0);

    // Another zone, or a photo that stops short of the DEM: refused, named.
    let wrong = tmp.path().join("zone11.tif");
    write_photo_tif(&wrong, 122, 122, [499_900.0, 5_000_100.0], 32611, 5.0);
    let short = tmp.path().join("short.tif");
    write_photo_tif(&short, 60, 122, [499_900.0, 5_000_100.0], 32610, 5.0);
    for (img, says) in [(&wrong, "EPSG:32611 but the DEM is in EPSG:32610"), (&short, "does not cover the DEM")] {
        let out = tmp.path().join("bad");
        let opts = BuildOptions {
            inputs: vec![dem.clone()],
            out: out.clone(),
            force: false,
            config: Config::default(),
            texture: TextureSource::Image(img.clone()),
            progress: false,
            geoid: None,
        };
        let e = build(&opts).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains(img.file_name().unwrap().to_str().unwrap()) && msg.contains(says), "{msg}");
        assert_eq!(e.exit_code(), 2);
        assert!(!out.exists());
    }
}

/// A photo whose GeoTIFF pixel size is NaN or infinite was placed with NaN
/// texel coordinates and the build exited 0; one of size 0 was refused as
/// not covering the DEM at columns "inf..inf". Each now names the file and
/// its unusable georeference, exits 2 and writes nothing.
#[test]
fn a_texture_with_an_unusable_georeference_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    write_dem_tif(&dem, 41, 41, [500_000.0, 5_000_000.0], 32610);
    let out = tmp.path().join("out");
    for (name, scale) in [("nan.tif", f64::NAN), ("inf.tif", f64::INFINITY), ("zero.tif", 0.0)] {
        let photo = tmp.path().join(name);
        write_photo_tif(&photo, 122, 122, [500_000.0, 5_000_000.0], 32610, scale);
        let o =
            cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", photo.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(err.contains(name) && err.contains("georeference places the first sample"), "{name}: {err}");
        assert!(!out.exists(), "{name}: output written");
    }
}

/// Cut and flip bytes of a PNG, a JPEG and a georeferenced RGB GeoTIFF
/// texture: loading each must return, never panic (the texture side of
/// `dem::mangled_fixtures_never_panic`; `fuzz/` has the `texture` target).
/// The intact images load and land georeferenced or stretched, so the
/// mutants start from files the loader takes. `TERRACHUNK_TEXTURE_SEEDS=DIR`
/// also copies them there, as the `texture` fuzz target's seeds.
#[test]
fn mangled_texture_images_never_panic() {
    use terrachunk::texture::source::load_image;
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    write_dem_tif(&dem, 41, 41, [500_000.0, 5_000_000.0], 32610);
    let hf = terrachunk::dem::load(&[dem], &Default::default()).unwrap();
    let photo = tmp.path().join("photo.tif");
    write_photo_tif(&photo, 122, 122, [499_900.0, 5_000_100.0], 32610, 5.0);
    let img = image::RgbImage::from_fn(60, 50, |c, r| image::Rgb([(c * 4) as u8, (r * 5) as u8, 90]));
    let (png, jpg) = (tmp.path().join("photo.png"), tmp.path().join("photo.jpg"));
    img.save(&png).unwrap();
    img.save(&jpg).unwrap();
    let mut mangler = Mangler::new(0x9e37_79b9_7f4a_7c15);
    // The fuzz target's seeds (fuzz/README.md): these intact images.
    let seeds = std::env::var_os("TERRACHUNK_TEXTURE_SEEDS").map(PathBuf::from);
    for (path, placement) in [(photo, "georeferenced"), (png, "stretched"), (jpg, "stretched")] {
        if let Some(dir) = &seeds {
            std::fs::copy(&path, dir.join(path.file_name().unwrap())).unwrap();
        }
        let source = load_image(&path, &hf).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(source.placement.starts_with(placement), "{}: {}", path.display(), source.placement);
        assert_eq!(source.rgb.len(), source.width * source.height * 3);
        let bytes = std::fs::read(&path).unwrap();
        let mangled = path.with_file_name(format!("mangled.{}", path.extension().unwrap().to_str().unwrap()));
        for k in 0..mangle_rounds() {
            let b = mangler.mangle(&bytes, k);
            std::fs::write(&mangled, &b).unwrap();
            if let Ok(s) = load_image(&mangled, &hf) {
                assert_eq!(s.rgb.len(), s.width * s.height * 3, "{} round {k}", path.display());
            }
        }
    }
}

// ------------------------------------------------------------ normal map

#[test]
fn the_normal_map_holds_the_dem_normals_in_the_vertex_frame() {
    // A plane rising 0.3 m per metre eastward (10 m cells): every normal is
    // (−0.3, 1, 0)/|·|, i.e. facing west: red below the middle grey.
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc(tmp.path(), "plane.asc", 33, 33, |_, j| j as f64 * 3.0);
    let out = tmp.path().join("out");
    let cfg = Config { normal_map: true, max_error_m: 0.1, ..Config::default() };
    build_with(&dem, &out, cfg, TextureSource::Generated);
    verified(&out);
    khronos_validate(&out);
    let n = [-0.3f64, 1.0, 0.0];
    let len = (n[0] * n[0] + n[1] * n[1]).sqrt();
    let want = [n[0] / len, -n[2] / len, n[1] / len].map(|c| ((c + 1.0) * 127.5).round() as u8);
    for t in tiles(&out).values() {
        let nm = &t.images[1];
        assert!(nm.pixels().all(|p| p.0 == want), "{:?}: {:?} vs {want:?}", t.key, nm.get_pixel(1, 1));
        let m = &t.json["materials"][0];
        assert_eq!(m["normalTexture"]["index"], 1);
        let a = &t.json["meshes"][0]["primitives"][0]["attributes"];
        assert!(a.get("TANGENT").is_some(), "{a}");
    }
}

// ------------------------------------------------------------ determinism

#[test]
fn textured_output_is_byte_identical_with_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("jacksboro_fault_u16.png");
    let mut runs = Vec::new();
    for threads in [1, 2] {
        for format in [TextureFormat::Png, TextureFormat::Jpeg] {
            let out = tmp.path().join(format!("{threads}-{format:?}"));
            let cfg =
                Config { max_error_m: 0.1, threads, normal_map: true, texture_format: format, ..Config::default() };
            build_with(&dem, &out, cfg, TextureSource::Generated);
            runs.push(all_files(&out));
        }
    }
    assert!(runs[0].len() > 10);
    for (a, b) in [(&runs[0], &runs[2]), (&runs[1], &runs[3])] {
        assert_eq!(a.len(), b.len());
        for ((pa, da), (pb, db)) in a.iter().zip(b) {
            assert_eq!(pa, pb);
            assert!(da == db, "{} differs between 1 and 2 threads", pa.display());
        }
    }
}

/// FNV-1a, 64 bits: a dependency-free fingerprint for golden files.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

#[test]
fn untextured_output_is_byte_identical_to_before_textures() {
    // The fingerprints of `--texture none` output were taken with the
    // commit before textures existed (49a02dd). A deliberate change to the
    // mesh or its encoding regenerates them: TERRACHUNK_UPDATE_GOLDEN=1.
    // Thinning (step 5 of the mesher) came later and changes the leaves;
    // with `thin = "none"` the files are still those bytes.
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("g.asc");
    std::fs::copy(golden.join("wave_33x33.asc"), &dem).unwrap();
    let out = tmp.path().join("out");
    let cfg = Config {
        max_error_m: 0.5,
        leaf_cells: Some(8),
        threads: 1,
        thin: Thin::None,
        mesher: Mesher::Tin,
        ..Config::default()
    };
    build_with(&dem, &out, cfg, TextureSource::None);
    let mut lines = Vec::new();
    // The index names its DEM by file name and hash, so it is the same
    // bytes wherever the test runs.
    for (p, bytes) in all_files(&out) {
        lines.push(format!("{} {} {:016x}", p.display(), bytes.len(), fnv1a(&bytes)));
    }
    let text = lines.join("\n") + "\n";
    let path = golden.join("wave_33x33_untextured.fnv");
    if std::env::var_os("TERRACHUNK_UPDATE_GOLDEN").is_some() {
        std::fs::write(&path, &text).unwrap();
    }
    assert_eq!(text, std::fs::read_to_string(&path).unwrap(), "untextured bytes changed");
    let j: Value = serde_json::from_str(&std::fs::read_to_string(out.join("tileset.json")).unwrap()).unwrap();
    assert!(j["extras"]["terrachunk"].get("texture").is_none());
}

// ------------------------------------------------------------ verify bites

#[test]
fn verify_catches_coarse_texels_moved_texcoords_and_mismatched_borders() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let cfg = Config { max_error_m: 2.0, ..Config::default() };
    build_with(&fixture("jacksboro_fault_u16.png"), &out, cfg, TextureSource::Generated);
    verified(&out);
    let failures = |what: &str| {
        let r = verify(&out, Some(&dem_of(&out))).unwrap();
        assert!(r.failures.iter().any(|f| f.contains(what)), "expected {what:?} in {:?}", r.failures);
    };

    // A tileset that claims a larger τ_max: the same tiles are now too coarse.
    let ts_path = out.join("tileset.json");
    let original = std::fs::read_to_string(&ts_path).unwrap();
    let mut ts: Value = serde_json::from_str(&original).unwrap();
    ts["extras"]["terrachunk"]["tau_max_px"] = serde_json::json!(8.0);
    std::fs::write(&ts_path, serde_json::to_vec(&ts).unwrap()).unwrap();
    failures("exceeds δ/τ_max");
    std::fs::write(&ts_path, &original).unwrap();

    // One vertex's u moved by a hundredth.
    let victim = out.join("tiles/1/0/0.glb");
    let saved = std::fs::read(&victim).unwrap();
    rewrite_glb(&victim, |j, bin| {
        let acc =
            &j["accessors"][j["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"].as_u64().unwrap() as usize];
        let view = &j["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let at = view["byteOffset"].as_u64().unwrap() as usize;
        let u = f32::from_le_bytes(bin[at..at + 4].try_into().unwrap()) + 0.01;
        bin[at..at + 4].copy_from_slice(&u.to_le_bytes());
    });
    failures("TEXCOORD_0");
    std::fs::write(&victim, &saved).unwrap();

    // Its image with the east column darkened: the seam with 1/1/0 breaks.
    rewrite_glb(&victim, |j, bin| {
        let view_i = j["images"][0]["bufferView"].as_u64().unwrap() as usize;
        let view = &j["bufferViews"][view_i];
        let (at, len) = (view["byteOffset"].as_u64().unwrap() as usize, view["byteLength"].as_u64().unwrap() as usize);
        let mut img = image::load_from_memory(&bin[at..at + len]).unwrap().to_rgb8();
        let w = img.width();
        for i in 0..img.height() {
            img[(w - 1, i)].0[0] /= 2;
        }
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        assert!(bin.len() - (at + len) < 4, "the image is the last thing in the buffer");
        bin.truncate(at);
        bin.extend_from_slice(&png);
        j["bufferViews"][view_i]["byteLength"] = serde_json::json!(png.len());
    });
    failures("border texels differ");
}

// ------------------------------------------------------------ bad input

fn cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_terrachunk")).args(args).output().unwrap()
}

#[test]
fn bad_texture_files_and_settings_exit_2_name_the_problem_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("west_bijou_gully_3m.asc");
    let out = tmp.path().join("out");
    let cases: Vec<(PathBuf, &str)> = {
        let text = tmp.path().join("notes.png");
        std::fs::write(&text, "not an image").unwrap();
        let cut = tmp.path().join("cut.png");
        let mut png = Vec::new();
        image::RgbImage::from_pixel(40, 40, image::Rgb([1, 2, 3]))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        std::fs::write(&cut, &png[..png.len() / 2]).unwrap();
        let deep = tmp.path().join("deep.tif");
        let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(&deep).unwrap()).unwrap();
        enc.write_image::<tiff::encoder::colortype::RGB16>(4, 4, &[7u16; 48]).unwrap();
        vec![
            (tmp.path().join("missing.png"), "cannot read"),
            (text, "not a PNG, JPEG or TIFF image"),
            (cut, "cannot decode"),
            (deep, "textures need 8 bits"),
        ]
    };
    for (img, says) in &cases {
        let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", img.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{}: {err}", img.display());
        let name = img.file_name().unwrap().to_str().unwrap();
        assert!(err.contains(name) && err.contains(says), "{name}: expected {says:?} in {err}");
        assert!(!out.exists());
    }
    for (flag, value, key) in [
        ("--max-texture-px", "1", "max_texture_px"),
        ("--jpeg-quality", "0", "jpeg_quality"),
        ("--max-texture-px", "100000", "max_texture_px"),
    ] {
        let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), flag, value]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(key), "{err}");
        assert!(!out.exists());
    }
    let cfg = tmp.path().join("sun.toml");
    std::fs::write(&cfg, "sun_elevation_deg = 0.0\n").unwrap();
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--config", cfg.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("sun_elevation_deg"));
}

#[test]
fn texture_none_and_the_texture_flags_on_the_command_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("kattegat_crop_u8.png");
    let d = dem.to_str().unwrap();
    let (a, b) = (tmp.path().join("none"), tmp.path().join("jpeg"));
    let o = cli(&["build", d, "-o", a.to_str().unwrap(), "--texture", "none"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!String::from_utf8_lossy(&o.stdout).contains("T_g"));
    let j = &tiles(&a)[&[0, 0, 0]].json;
    assert!(j.get("images").is_none() && j["materials"][0]["pbrMetallicRoughness"].get("baseColorTexture").is_none());
    let o = cli(&[
        "build",
        d,
        "-o",
        b.to_str().unwrap(),
        "--texture-format",
        "jpeg",
        "--jpeg-quality",
        "60",
        "--normal-map",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ex = &tileset(&b)["extras"]["terrachunk"]["texture"];
    assert_eq!((ex["format"].as_str(), ex["jpeg_quality"].as_u64()), (Some("jpeg"), Some(60)));
    assert!(ex["normal_map"].is_string() && ex["hillshade"]["sun_azimuth_deg"] == 315.0);
    let o = cli(&["inspect", b.join("tiles/0/0/0.glb").to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("texture") && text.contains("image/jpeg") && text.contains("normal map"), "{text}");
    let dem = dem_of(&b);
    let o = cli(&["verify", b.to_str().unwrap(), "--dem", dem[0].to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && text.contains("texture seams compared") && text.contains("OK"), "{text}");
}
