//! DEM loaders: the real fixtures (with the numbers from shared/dem/README.md),
//! small real-derived fixtures for every other format, tiny exact cases, and
//! every kind of bad input a user can hand us.
//!
//! The fixtures under `fixtures/` are either copies of files in
//! `shared/dem` or crops of them written by `regenerate_fixtures` (ignored:
//! it needs `shared/dem`); everything else a test needs it writes into a
//! temporary directory.

use std::path::{Path, PathBuf};

use terrachunk::dem::{DemError, LoadOptions, load};
use terrachunk::heightfield::{Crs, Heightfield};

use crate::common::{Mangler, fixture, mangle_rounds};

// ---------------------------------------------------------------- helpers

fn load1(path: &Path) -> Result<Heightfield, DemError> {
    load(&[path.to_path_buf()], &LoadOptions::default())
}

fn ok(path: &Path) -> Heightfield {
    load1(path).unwrap_or_else(|e| panic!("{e}"))
}

/// (min, max, nodata count) over the grid; min/max skip nodata.
fn stats(hf: &Heightfield) -> (f32, f32, usize) {
    let mut min = f32::INFINITY;
    let mut max = f32::NEG_INFINITY;
    let mut nodata = 0;
    for &h in &hf.heights {
        if h.is_nan() {
            nodata += 1;
        } else {
            min = min.min(h);
            max = max.max(h);
        }
    }
    (min, max, nodata)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[track_caller]
fn assert_close(a: f64, b: f64, tol: f64) {
    assert!(close(a, b, tol), "{a} is not within {tol} of {b}");
}

/// Which variant an error is, for assertions.
fn kind(e: &DemError) -> &'static str {
    match e {
        DemError::Io { .. } => "Io",
        DemError::Unsupported { .. } => "Unsupported",
        DemError::Corrupt { .. } => "Corrupt",
        DemError::Invalid { .. } => "Invalid",
    }
}

/// The load must fail with `variant`, and the message must name the file
/// (`names`) and say what is wrong (`says`).
#[track_caller]
fn assert_fails(r: Result<Heightfield, DemError>, variant: &str, names: &str, says: &str) {
    let e = match r {
        Ok(hf) => panic!("expected {variant} error, loaded {} × {}", hf.width, hf.height),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert_eq!(kind(&e), variant, "wrong variant for: {msg}");
    assert!(msg.contains(names), "message does not name {names:?}: {msg}");
    assert!(msg.contains(says), "message does not say {says:?}: {msg}");
}

fn copy_to(dir: &Path, src: &Path) -> PathBuf {
    let dst = dir.join(src.file_name().unwrap());
    std::fs::copy(src, &dst).unwrap();
    dst
}

fn write_asc(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// A 16-bit grayscale PNG of `w × h` heights.
fn write_png16(path: &Path, w: u32, h: u32, data: &[u16]) {
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, data.to_vec()).unwrap();
    img.save(path).unwrap();
}

/// A one-channel EXR per named channel, float32 samples.
fn write_exr(path: &Path, w: usize, h: usize, channels: Vec<(&str, exr::prelude::FlatSamples)>) {
    use exr::prelude::*;
    let list: Vec<AnyChannel<FlatSamples>> = channels.into_iter().map(|(name, s)| AnyChannel::new(name, s)).collect();
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    Image::from_layer(layer).write().to_file(path).unwrap();
}

/// VTP BT 1.3 bytes from a north-up, row-major grid (`bytes`/`float` pick
/// the sample type: 2/false int16, 4/false int32, 4/true float32).
#[allow(clippy::too_many_arguments)]
fn bt_bytes(
    w: usize,
    h: usize,
    bytes: i16,
    float: bool,
    units: i16,
    zone: i16,
    datum: i16,
    edges: [f64; 4],
    vscale: f32,
    data: &[f64],
) -> Vec<u8> {
    let mut out = vec![0u8; 256];
    out[..10].copy_from_slice(b"binterr1.3");
    out[10..14].copy_from_slice(&(w as i32).to_le_bytes());
    out[14..18].copy_from_slice(&(h as i32).to_le_bytes());
    out[18..20].copy_from_slice(&bytes.to_le_bytes());
    out[20..22].copy_from_slice(&i16::from(float).to_le_bytes());
    out[22..24].copy_from_slice(&units.to_le_bytes());
    out[24..26].copy_from_slice(&zone.to_le_bytes());
    out[26..28].copy_from_slice(&datum.to_le_bytes());
    for (k, v) in edges.iter().enumerate() {
        out[28 + 8 * k..36 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
    out[62..66].copy_from_slice(&vscale.to_le_bytes());
    for col in 0..w {
        for row in (0..h).rev() {
            let v = data[row * w + col];
            match (bytes, float) {
                (2, false) => out.extend((v as i16).to_le_bytes()),
                (4, false) => out.extend((v as i32).to_le_bytes()),
                _ => out.extend((v as f32).to_le_bytes()),
            }
        }
    }
    out
}

/// The real DEMs of `shared/dem` (beside the repository, or
/// `$TERRACHUNK_DEM_DIR`), or `None` when they are not there.
fn shared_dem() -> Option<PathBuf> {
    let dir = std::env::var_os("TERRACHUNK_DEM_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/dem"));
    dir.is_dir().then_some(dir)
}

// ------------------------------------------- real fixtures (copied as is)

#[test]
fn asc_west_bijou_gully_matches_readme() {
    let hf = ok(&fixture("west_bijou_gully_3m.asc"));
    assert_eq!((hf.width, hf.height), (43, 89));
    let (min, max, nodata) = stats(&hf);
    assert_close(f64::from(min), 1680.78, 0.005);
    assert_close(f64::from(max), 1725.43, 0.005);
    assert_eq!(nodata, 2739, "NODATA_value 0 becomes NaN");
    assert_eq!(hf.spacing_m, [3.0, 3.0]);
    assert_eq!(hf.georef.crs, Crs::Projected { epsg: None });
    // xllcorner 559705, yllcorner 4380220: the NW sample centre is half a
    // cell in from the corner, 89 rows up.
    assert_eq!(hf.georef.origin, [559_706.5, 4_380_220.0 + 89.0 * 3.0 - 1.5]);
    assert_eq!(hf.source, "west_bijou_gully_3m.asc");
}

#[test]
fn geotiff_float32_salish_sea_topobathy_matches_readme() {
    let hf = ok(&fixture("salish_sea_topobathy_f32.tif"));
    assert_eq!((hf.width, hf.height), (120, 91));
    assert_eq!(stats(&hf), (-1437.0, 2205.0, 0));
    assert_eq!(hf.georef.crs, Crs::Projected { epsg: Some(3857) });
    assert_close(hf.georef.step[0], 3710.65, 0.01);
    // Web Mercator units are not ground metres: 3710.65 × cos(49°) ≈ 2430 m.
    assert_close(hf.spacing_m[0], 2430.0, 10.0);
    assert_eq!(hf.spacing_m[0], hf.spacing_m[1]);
}

#[test]
fn geotiff_tiled_dfw_texas_matches_readme() {
    let hf = ok(&fixture("dfw_texas_srtm3.tif"));
    assert_eq!((hf.width, hf.height), (367, 359));
    // int16 with GDAL_NODATA -32768 declared but absent: no NaN at all.
    assert_eq!(stats(&hf), (147.0, 298.0, 0));
    assert_eq!(hf.georef.crs, Crs::Geographic { epsg: Some(4326) });
    // 3″ on the WGS 84 ellipsoid at 32.7°N (the README's ≈77.9 × 92.6 is
    // for a sphere of 30.87 m per second of arc).
    let [sx, sz] = hf.spacing_m;
    assert_close(sx, 77.9, 0.5);
    assert_close(sz, 92.6, 0.5);
    assert_close(hf.georef.step[0], 1.0 / 1200.0, 1e-9);
    let lt = hf.georef.local_tangent.as_ref().expect("geographic → local tangent");
    assert_close(lt.lat0_deg, 32.67, 0.01);
    assert_close(lt.lon0_deg, -97.33, 0.01);
}

#[test]
fn geotiff_pixel_is_point_mount_st_helens_matches_readme() {
    let hf = ok(&fixture("mount_st_helens_30m.tif"));
    assert_eq!((hf.width, hf.height), (327, 468));
    // GDAL_NODATA -32767 (not the usual -32768) becomes NaN.
    assert_eq!(stats(&hf), (682.0, 2543.0, 4151));
    assert_eq!(hf.spacing_m, [30.0, 30.0]);
    assert_eq!(hf.georef.crs, Crs::Projected { epsg: Some(26710) });
    // PixelIsPoint: the tie point is the centre of sample (0, 0), no shift.
    assert_eq!(hf.georef.origin, [557_820.0, 5_121_990.0]);
    assert_eq!(hf.georef.step, [30.0, -30.0]);
}

#[test]
fn png_16bit_jacksboro_fault_matches_readme() {
    let hf = ok(&fixture("jacksboro_fault_u16.png"));
    assert_eq!((hf.width, hf.height), (403, 344));
    assert_eq!(stats(&hf), (236.0, 1076.0, 0));
    // No georeference in a PNG: 1 m until the user says otherwise.
    assert_eq!(hf.spacing_m, [1.0, 1.0]);
    assert_eq!(hf.georef.crs, Crs::Unknown);
    let opts = LoadOptions { spacing_m: Some([74.4, 92.6]), ..Default::default() };
    let hf = load(&[fixture("jacksboro_fault_u16.png")], &opts).unwrap();
    assert_eq!(hf.spacing_m, [74.4, 92.6]);
}

// ----------------------------------- real-derived fixtures (crops, re-encoded)

#[test]
fn geotiff_deflate_predictor_california_crop() {
    // Death Valley, cut from california_srtm3_8401x4801.tif at rows 4500..,
    // columns 5050.., written as DEFLATE + horizontal predictor, 16-row strips.
    let hf = ok(&fixture("california_crop_deflate.tif"));
    assert_eq!((hf.width, hf.height), (64, 48));
    assert_eq!(stats(&hf), (-84.0, 1261.0, 0));
    assert_eq!(hf.georef.crs, Crs::Geographic { epsg: Some(4326) });
    assert_close(hf.georef.origin[0], -121.0 + 5050.0 / 1200.0, 1e-9);
    assert_close(hf.georef.origin[1], 40.0 - 4500.0 / 1200.0, 1e-9);
    assert_close(hf.spacing_m[1], 92.5, 0.2);
}

/// The two Sierra 3 × 3 crops the greedy TIN's Sierra cases build from:
/// 451 × 451 blocks of the mosaic (39…36° N, 119…116° W, 3″) in place,
/// so their spacing in metres is the mosaic's at their own latitude.
#[test]
fn geotiff_sierra_crops() {
    for (name, c0, r0, (lo, hi)) in [
        ("sierra_n38w118_crop_i16.tif", 1350, 450, (1490.0, 2454.0)),
        ("sierra_n37w117_crop_i16.tif", 2700, 2250, (824.0, 2260.0)),
    ] {
        let hf = ok(&fixture(name));
        assert_eq!((hf.width, hf.height), (451, 451), "{name}");
        assert_eq!(stats(&hf), (lo, hi, 0), "{name}");
        assert_eq!(hf.georef.crs, Crs::Geographic { epsg: Some(4326) });
        assert_close(hf.georef.origin[0], -119.0 + f64::from(c0) / 1200.0, 1e-9);
        assert_close(hf.georef.origin[1], 39.0 - f64::from(r0) / 1200.0, 1e-9);
        assert_close(hf.spacing_m[1], 92.5, 0.2);
    }
    // The mosaic itself, its south-east quadrant's ground in place and the
    // rest flat at 1291 m.
    let hf = ok(&fixture("sierra_se_quadrant_i16.tif"));
    assert_eq!((hf.width, hf.height), (3601, 3601));
    assert_eq!(stats(&hf), (-85.0, 3359.0, 0));
    assert_close(hf.georef.origin[0], -119.0, 1e-9);
    assert_close(hf.georef.origin[1], 39.0, 1e-9);
    assert_eq!(hf.get(1799, 1799), 1291.0);
    assert_eq!(hf.get(0, 3600), 1291.0);
}

#[test]
fn hgt_single_tile() {
    let hf = ok(&fixture("hgt_mosaic/N01E000.hgt"));
    assert_eq!((hf.width, hf.height), (11, 11));
    assert_eq!(hf.georef.crs, Crs::Geographic { epsg: Some(4326) });
    // N01E000: 1…2°N, 0…1°E, samples on the grid lines, 0.1° apart.
    assert_eq!(hf.georef.origin, [0.0, 2.0]);
    assert_close(hf.georef.step[0], 0.1, 1e-12);
    assert_close(hf.georef.step[1], -0.1, 1e-12);
    let lt = hf.georef.local_tangent.as_ref().unwrap();
    assert_close(lt.lat0_deg, 1.5, 1e-9);
    // 0.1° of latitude ≈ 11.06 km, of longitude at 1.5°N ≈ 11.13 km.
    assert_close(hf.spacing_m[0], 11_128.0, 5.0);
    assert_close(hf.spacing_m[1], 11_057.0, 5.0);
    // Two SRTM voids of N43E007 fall on this tile's south edge.
    assert_eq!(stats(&hf).2, 2);
    assert_eq!(hf.source, "N01E000.hgt");
}

/// The four fixture tiles, NW NE SW SE.
const TILES: [&str; 4] = ["N01E000.hgt", "N01E001.hgt", "N00E000.hgt", "N00E001.hgt"];

#[test]
fn hgt_mosaic_folder_takes_shared_edges_once() {
    let hf = ok(&fixture("hgt_mosaic"));
    assert_eq!((hf.width, hf.height), (21, 21), "2 tiles of 11 → 21");
    assert_eq!(hf.source, "hgt_mosaic");
    assert_eq!(hf.georef.origin, [0.0, 2.0]);
    // Every tile sits at (10·row, 10·col) and every one of its samples,
    // shared edges included, is found there once.
    for (k, name) in TILES.iter().enumerate() {
        let tile = ok(&fixture(&format!("hgt_mosaic/{name}")));
        let (r0, c0) = ((k / 2) * 10, (k % 2) * 10);
        for i in 0..11 {
            for j in 0..11 {
                let (a, b) = (tile.get(i, j), hf.get(r0 + i, c0 + j));
                assert!(a == b || (a.is_nan() && b.is_nan()), "{name} ({i}, {j})");
            }
        }
    }
    // The three voids of N43E007 at row 405, columns 251..253 lie on the
    // mosaic's middle row, one of them on the corner all four tiles share.
    assert_eq!(stats(&hf).2, 3);
    assert!(hf.get(10, 10).is_nan());
}

#[test]
fn hgt_mosaic_list_equals_folder() {
    let paths: Vec<PathBuf> = TILES.iter().rev().map(|n| fixture(&format!("hgt_mosaic/{n}"))).collect();
    let list = load(&paths, &LoadOptions::default()).unwrap();
    let folder = ok(&fixture("hgt_mosaic"));
    assert_eq!(list.source, "N00E000.hgt+N00E001.hgt+N01E000.hgt+N01E001.hgt");
    assert_eq!(format!("{:?}", list.heights), format!("{:?}", folder.heights));
    assert_eq!(list.spacing_m, folder.spacing_m);
}

#[test]
fn hgt_mosaic_of_two_tiles_is_21_wide() {
    let paths = [fixture("hgt_mosaic/N00E001.hgt"), fixture("hgt_mosaic/N00E000.hgt")];
    let hf = load(&paths, &LoadOptions::default()).unwrap();
    assert_eq!((hf.width, hf.height), (21, 11));
    assert_eq!(hf.georef.origin, [0.0, 1.0]);
}

#[test]
fn hgt_mosaic_disagreeing_edge_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let west = copy_to(dir.path(), &fixture("hgt_mosaic/N00E000.hgt"));
    let east = copy_to(dir.path(), &fixture("hgt_mosaic/N00E001.hgt"));
    // Make the east tile's west column (the shared edge) disagree: +1000 m.
    let mut bytes = std::fs::read(&east).unwrap();
    for r in 0..11 {
        let o = r * 22;
        let v = i16::from_be_bytes([bytes[o], bytes[o + 1]]);
        if v != i16::MIN {
            bytes[o..o + 2].copy_from_slice(&(v + 1000).to_be_bytes());
        }
    }
    std::fs::write(&east, &bytes).unwrap();
    let a = load(&[west.clone(), east.clone()], &LoadOptions::default()).unwrap();
    let b = load(&[east.clone(), west.clone()], &LoadOptions::default()).unwrap();
    assert_eq!(format!("{:?}", a.heights), format!("{:?}", b.heights));
    // The western tile wins on the shared column, wherever it has data.
    let w = ok(&west);
    let e = ok(&east);
    let mut disagree = 0;
    for i in 0..11 {
        if !w.get(i, 10).is_nan() {
            assert_eq!(a.get(i, 10), w.get(i, 10));
            disagree += usize::from(w.get(i, 10) != e.get(i, 0));
        }
    }
    assert!(disagree > 0);
}

#[test]
fn bt_int16_kilauea_crop() {
    // Kīlauea's south coast (Hilina Pali), rows 688.., columns 256.. of
    // kilauea_30m.bt; the sea is nodata.
    let hf = ok(&fixture("kilauea_crop_i16.bt"));
    assert_eq!((hf.width, hf.height), (64, 48));
    assert_eq!(stats(&hf), (0.0, 318.0, 450));
    assert_eq!(hf.spacing_m, [30.0, 30.0]);
    assert_eq!(hf.georef.crs, Crs::Projected { epsg: Some(32605) });
    assert_eq!(hf.georef.step, [30.0, -30.0]);
}

#[test]
fn bt_int32_float32_and_vertical_scale() {
    let base = ok(&fixture("kilauea_crop_i16.bt"));
    let data: Vec<f64> = base.heights.iter().map(|&h| if h.is_nan() { -32768.0 } else { f64::from(h) }).collect();
    let dir = tempfile::tempdir().unwrap();
    let edges = [0.0, 64.0 * 30.0, 0.0, 48.0 * 30.0];
    for (bytes, float) in [(4, false), (4, true)] {
        let p = dir.path().join(format!("k{bytes}{float}.bt"));
        std::fs::write(&p, bt_bytes(64, 48, bytes, float, 1, 5, 6326, edges, 1.0, &data)).unwrap();
        let hf = ok(&p);
        assert_eq!(format!("{:?}", hf.heights), format!("{:?}", base.heights));
    }
    // Vertical scale @62 multiplies; a float NaN stays nodata.
    let mut halved = data.clone();
    halved[0] = f64::NAN;
    let p = dir.path().join("half.bt");
    std::fs::write(&p, bt_bytes(64, 48, 4, true, 1, 5, 6326, edges, 0.5, &halved)).unwrap();
    let hf = ok(&p);
    assert!(hf.heights[0].is_nan());
    assert_eq!(stats(&hf), (0.0, 159.0, 450 + usize::from(!base.heights[0].is_nan())));
    // Degrees (units 0) make a geographic grid on the local tangent plane.
    let p = dir.path().join("deg.bt");
    let edges = [6.0, 6.0 + 64.0 / 1200.0, 43.0, 43.0 + 48.0 / 1200.0];
    std::fs::write(&p, bt_bytes(64, 48, 2, false, 0, 0, 6326, edges, 1.0, &data)).unwrap();
    let hf = ok(&p);
    assert_eq!(hf.georef.crs, Crs::Geographic { epsg: Some(4326) });
    assert_close(hf.spacing_m[1], 92.6, 0.2);
    assert_close(hf.georef.origin[0], 6.0 + 0.5 / 1200.0, 1e-12);
}

#[test]
fn exr_float32_seamount_crop_keeps_nan_as_nodata() {
    // The edge of the NaN hole in seamount_holes_f32.tif.
    let hf = ok(&fixture("seamount_crop_f32.exr"));
    assert_eq!((hf.width, hf.height), (64, 48));
    let (min, max, nodata) = stats(&hf);
    assert_eq!(nodata, 1656);
    assert_eq!((min, max), (-4518.0, -4101.0));
    assert_eq!(hf.spacing_m, [1.0, 1.0]);
}

#[test]
fn exr_half_float_and_channel_choice() {
    use exr::prelude::{FlatSamples, f16};
    let dir = tempfile::tempdir().unwrap();
    let data: Vec<f32> = (0..12).map(|k| k as f32 * 1.5 - 3.0).collect();
    let half = || FlatSamples::F16(data.iter().map(|&v| f16::from_f32(v)).collect());

    let p = dir.path().join("half.exr");
    write_exr(&p, 4, 3, vec![("elevation", half())]);
    assert_eq!(ok(&p).heights, data, "the only channel, whatever its name");

    let p = dir.path().join("rgb.exr");
    let zeros = || FlatSamples::F32(vec![0.0; 12]);
    write_exr(&p, 4, 3, vec![("B", zeros()), ("G", zeros()), ("R", half())]);
    assert_eq!(ok(&p).heights, data, "R is preferred over G and B");

    let p = dir.path().join("uv.exr");
    write_exr(&p, 4, 3, vec![("U", zeros()), ("V", zeros())]);
    assert_fails(load1(&p), "Unsupported", "uv.exr", "2 channels (U, V)");
}

#[test]
fn png_8bit_kattegat_crop() {
    // Gothenburg archipelago (N57E011.hgt rows 96.., columns 864..): land up
    // to 117 m and sea at exactly 0, as 8-bit grayscale.
    let hf = ok(&fixture("kattegat_crop_u8.png"));
    assert_eq!((hf.width, hf.height), (64, 48));
    assert_eq!(stats(&hf), (0.0, 117.0, 0));
    assert_eq!(hf.heights.iter().filter(|&&h| h == 0.0).count(), 903);
}

#[test]
fn png_terrain_rgb_fuji_crop() {
    // Mt Fuji's summit, cut from fuji_terrainrgb.png with its RGBA bytes
    // untouched: h = −10000 + (R·65536 + G·256 + B)·0.1.
    let hf = ok(&fixture("fuji_crop_terrainrgb.png"));
    assert_eq!((hf.width, hf.height), (64, 48));
    let (min, max, nodata) = stats(&hf);
    assert_eq!(nodata, 0);
    assert_close(f64::from(max), 3751.0, 0.05);
    assert_close(f64::from(min), 2231.0, 0.05);
    for &h in &hf.heights {
        let steps = (f64::from(h) + 10_000.0) * 10.0;
        assert_close(steps, steps.round(), 0.01);
    }
}

#[test]
fn vertical_scale_multiplies_heights() {
    let opts = LoadOptions { vertical_scale: Some(0.3048), ..Default::default() };
    let hf = load(&[fixture("dfw_texas_srtm3.tif")], &opts).unwrap();
    let (min, max, _) = stats(&hf);
    assert_close(f64::from(min), 147.0 * 0.3048, 1e-3);
    assert_close(f64::from(max), 298.0 * 0.3048, 1e-3);
}

#[test]
fn magic_bytes_win_over_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("really_a_png.tif");
    std::fs::copy(fixture("kattegat_crop_u8.png"), &p).unwrap();
    assert_eq!((ok(&p).width, ok(&p).height), (64, 48));
}

#[test]
fn tiny_exact_asc_grid() {
    // A 3 × 2 grid with xllcenter/yllcenter and a NODATA_value.
    let dir = tempfile::tempdir().unwrap();
    let p = write_asc(
        dir.path(),
        "tiny.asc",
        "NCOLS 3\nNROWS 2\nXLLCENTER 100\nYLLCENTER 200\nCELLSIZE 10\nNODATA_VALUE -9999\n\
         1 2 3\n4 -9999 6.5\n",
    );
    let hf = ok(&p);
    assert_eq!((hf.width, hf.height), (3, 2));
    assert_eq!(hf.heights[..4], [1.0, 2.0, 3.0, 4.0]);
    assert!(hf.heights[4].is_nan());
    assert_eq!(hf.heights[5], 6.5);
    assert_eq!(hf.georef.origin, [100.0, 210.0]);
    assert_eq!(hf.spacing_m, [10.0, 10.0]);
}

// --------------------------------------------------------------- bad input

#[test]
fn missing_file_is_io_error_naming_it() {
    for name in ["nope.tif", "nope.hgt", "nope.asc", "nope.bt", "nope.png", "nope.exr"] {
        assert_fails(load1(&fixture(name)), "Io", name, "cannot read");
    }
    let r = load(&[fixture("hgt_mosaic/N00E000.hgt"), fixture("N05E005.hgt")], &LoadOptions::default());
    assert_fails(r, "Io", "N05E005.hgt", "cannot read");
}

#[test]
fn no_input_and_unknown_format() {
    assert_fails(load(&[], &LoadOptions::default()), "Invalid", "", "no input file");
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("heights.xyz");
    std::fs::write(&p, b"1 2 3\n4 5 6\n").unwrap();
    assert_fails(load1(&p), "Unsupported", "heights.xyz", "not a recognised DEM");
}

#[test]
fn hgt_of_wrong_size_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read(fixture("hgt_mosaic/N00E000.hgt")).unwrap();
    // Truncated by one byte, by one sample, and a single sample.
    for (len, name) in [(good.len() - 1, "N10E010.hgt"), (good.len() - 2, "N11E011.hgt"), (2, "N12E012.hgt")] {
        let p = dir.path().join(name);
        std::fs::write(&p, &good[..len]).unwrap();
        let says = format!("{len} bytes is not a square grid of int16");
        assert_fails(load1(&p), "Corrupt", name, &says);
    }
}

#[test]
fn hgt_without_position_in_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("verdon.hgt");
    std::fs::copy(fixture("hgt_mosaic/N00E000.hgt"), &p).unwrap();
    assert_fails(load1(&p), "Invalid", "verdon.hgt", "N43E006.hgt");
    // With the spacing given it loads as a plain grid.
    let opts = LoadOptions { spacing_m: Some([90.0, 90.0]), ..Default::default() };
    let hf = load(&[p], &opts).unwrap();
    assert_eq!((hf.width, hf.height, hf.georef.crs), (11, 11, Crs::Unknown));
}

#[test]
fn truncated_tif_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["mount_st_helens_30m.tif", "dfw_texas_srtm3.tif", "california_crop_deflate.tif"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let p = dir.path().join(name);
        std::fs::write(&p, &bytes[..bytes.len() * 3 / 4]).unwrap();
        let e = load1(&p).unwrap_err();
        assert_eq!(kind(&e), "Corrupt", "{e}");
        assert!(e.to_string().contains(name), "{e}");
    }
    // A GDAL-written file cut inside its samples says how much is missing.
    let bytes = std::fs::read(fixture("mount_st_helens_30m.tif")).unwrap();
    let p = dir.path().join("cut.tif");
    std::fs::write(&p, &bytes[..bytes.len() - 1000]).unwrap();
    assert_fails(load1(&p), "Corrupt", "cut.tif", "expected 306072 bytes of samples, found 305072");
}

#[test]
fn truncated_bt_png_exr_asc_are_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("kilauea_crop_i16.bt", "expected 6144 bytes of samples, found 3072"),
        ("kattegat_crop_u8.png", "PNG ends early"),
        ("seamount_crop_f32.exr", "OpenEXR"),
        ("west_bijou_gully_3m.asc", "values, expected ncols × nrows = 43 × 89 = 3827"),
    ];
    for (name, says) in cases {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let keep = if name.ends_with(".bt") { 256 + 3072 } else { bytes.len() / 2 };
        let p = dir.path().join(name);
        std::fs::write(&p, &bytes[..keep]).unwrap();
        assert_fails(load1(&p), "Corrupt", name, says);
    }
    let p = dir.path().join("header.bt");
    std::fs::write(&p, b"binterr1.3").unwrap();
    assert_fails(load1(&p), "Corrupt", "header.bt", "shorter than the 256-byte BT header");
}

#[test]
fn infinite_heights_are_invalid() {
    use exr::prelude::FlatSamples;
    let dir = tempfile::tempdir().unwrap();
    let mut data = vec![10.0f32; 12];
    data[3] = f32::INFINITY;
    data[7] = f32::NEG_INFINITY;
    let p = dir.path().join("inf.exr");
    write_exr(&p, 4, 3, vec![("Y", FlatSamples::F32(data.clone()))]);
    assert_fails(load1(&p), "Invalid", "inf.exr", "2 samples are infinite");

    let p = dir.path().join("inf.tif");
    let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(4, 3, &data).unwrap();
    assert_fails(load1(&p), "Invalid", "inf.tif", "2 samples are infinite");

    let p = write_asc(dir.path(), "inf.asc", "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 inf\n3 4\n");
    assert_fails(load1(&p), "Invalid", "inf.asc", "1 samples are infinite");

    // A vertical scale that overflows f32 is caught too, and says so.
    let opts = LoadOptions { vertical_scale: Some(1e38), ..Default::default() };
    let r = load(&[fixture("dfw_texas_srtm3.tif")], &opts);
    assert_fails(r, "Invalid", "dfw_texas_srtm3.tif", "is beyond the range of a 32-bit float height");
}

/// Heights are held as f32. Far from 0 a value finer than f32 can hold
/// there (1e6 m with centimetre relief: f32 steps are 6.25 cm) used to be
/// flattened without a word; now the load says which value and why.
#[test]
fn heights_f32_cannot_hold_within_a_millimetre_are_refused() {
    use tiff::encoder::{TiffEncoder, colortype};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let head = "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    let p = write_asc(d, "offset.asc", &format!("{head}1000000 1000000.01\n1000000 1000000\n"));
    assert_fails(load1(&p), "Invalid", "offset.asc", "line 6: 1000000.01 would be stored as 1000000");
    let p = write_asc(d, "huge.asc", &format!("{head}1 1e39\n3 4\n"));
    assert_fails(load1(&p), "Invalid", "huge.asc", "line 6: 1e39 is beyond the range of a 32-bit float height");
    // What f32 does hold passes: Mars' highest peak to the centimetre, and
    // 1e6 m in f32's own 1/16 m steps.
    let p = write_asc(d, "mars.asc", &format!("{head}21229.51 -8200.33\n1000000.0625 1000000\n"));
    assert_eq!(ok(&p).heights, vec![21229.51, -8200.33, 1_000_000.06, 1_000_000.0]);

    let p = d.join("f64.tif");
    let data = [1e6, 1e6, 1e6, 1e6 + 0.01, 1e6, 1e6];
    TiffEncoder::new(std::fs::File::create(&p).unwrap())
        .unwrap()
        .write_image::<colortype::Gray64Float>(3, 2, &data)
        .unwrap();
    assert_fails(load1(&p), "Invalid", "f64.tif", "sample (row 1, column 0): 1000000.01 would be stored as 1000000");
    let p = d.join("i32.tif");
    let data = [0, 16_777_216, -16_777_216, 20_000_001];
    TiffEncoder::new(std::fs::File::create(&p).unwrap())
        .unwrap()
        .write_image::<colortype::GrayI32>(2, 2, &data)
        .unwrap();
    assert_fails(load1(&p), "Invalid", "i32.tif", "sample (row 1, column 1): 20000001 would be stored as 20000000");

    let edges = [0.0, 2.0, 0.0, 2.0];
    let p = d.join("i32.bt");
    std::fs::write(&p, bt_bytes(2, 2, 4, false, 1, 0, 6326, edges, 1.0, &[1.0, 2.0, 3.0, 20_000_001.0])).unwrap();
    assert_fails(load1(&p), "Invalid", "i32.bt", "sample (row 1, column 1): 20000001 would be stored as 20000000");
}

/// A text grid declares its nodata value; a NaN anywhere else is a broken
/// export and is refused, not turned into a hole.
#[test]
fn asc_nan_is_nodata_only_when_declared() {
    let dir = tempfile::tempdir().unwrap();
    let head = "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    let p = write_asc(dir.path(), "a.asc", &format!("{head}NODATA_value -9999\n1 2\nnan 4\n"));
    assert_fails(load1(&p), "Invalid", "a.asc", "line 8: \"nan\" is not a height (NODATA_value is -9999)");
    let p = write_asc(dir.path(), "b.asc", &format!("{head}1 NaN\n3 4\n"));
    assert_fails(load1(&p), "Invalid", "b.asc", "line 6: \"NaN\" is not a height (NODATA_value is not declared)");
    let p = write_asc(dir.path(), "c.asc", &format!("{head}NODATA_value nan\n1 2\nnan 4\n"));
    let hf = ok(&p);
    assert!(hf.heights[2].is_nan() && hf.valid_count() == 3);
}

#[test]
fn all_nodata_is_invalid() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("N20E020.hgt");
    std::fs::write(&p, i16::MIN.to_be_bytes().repeat(121)).unwrap();
    assert_fails(load1(&p), "Invalid", "N20E020.hgt", "all 121 samples are nodata");

    let p = write_asc(
        dir.path(),
        "void.asc",
        "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nnodata_value 0\n0 0\n0 0\n",
    );
    assert_fails(load1(&p), "Invalid", "void.asc", "all 4 samples are nodata");

    let p = dir.path().join("nan.exr");
    write_exr(&p, 2, 2, vec![("Y", exr::prelude::FlatSamples::F32(vec![f32::NAN; 4]))]);
    assert_fails(load1(&p), "Invalid", "nan.exr", "all 4 samples are nodata");
}

#[test]
fn one_by_n_grid_is_invalid() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ridge.png");
    write_png16(&p, 1, 600, &[100; 600]);
    assert_fails(load1(&p), "Invalid", "ridge.png", "grid is 1 × 600 samples; need at least 2 × 2");
    let p = write_asc(dir.path(), "row.asc", "ncols 3\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n");
    assert_fails(load1(&p), "Invalid", "row.asc", "grid is 3 × 1 samples");
}

#[test]
fn zero_or_negative_spacing_is_invalid() {
    let dfw = fixture("dfw_texas_srtm3.tif");
    for spacing in [[0.0, 30.0], [30.0, -1.0], [f64::NAN, 30.0], [f64::INFINITY, 1.0]] {
        let opts = LoadOptions { spacing_m: Some(spacing), ..Default::default() };
        assert_fails(load(std::slice::from_ref(&dfw), &opts), "Invalid", "dfw_texas_srtm3.tif", "spacing override");
    }
    // A file that says its cells are 0 or −3 m wide.
    let dir = tempfile::tempdir().unwrap();
    for (name, cs) in [("zero.asc", "0"), ("negative.asc", "-3")] {
        let p = write_asc(
            dir.path(),
            name,
            &format!("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize {cs}\n1 2\n3 4\n"),
        );
        assert_fails(load1(&p), "Invalid", name, &format!("sample spacing {cs} × {cs} m"));
    }
}

/// A 3 × 3 float GeoTIFF whose first pixel's corner is `corner` and whose
/// pixels are `pixel` wide, in EPSG `epsg` (4326 geographic, else projected).
fn write_georef_tif(path: &Path, corner: [f64; 2], pixel: f64, epsg: u16) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(3, 3).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[pixel, pixel, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, corner[0], corner[1], 0.0][..]).unwrap();
    // GTModelType (1 projected, 2 geographic) and its ProjectedCSType or GeographicType.
    let (model, key) = if epsg == 4326 { (2, 2048) } else { (1, 3072) };
    e.write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 2, 1024, 0, 1, model, key, 0, 1, epsg][..]).unwrap();
    img.write_data(&[1.0f32; 9]).unwrap();
}

/// A georeference that places nothing: before this was refused, a GeoTIFF
/// whose tie point is NaN built with `null` coordinates in tileset.json.
#[test]
fn a_georeference_with_a_non_finite_corner_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    for (name, corner) in [("nan.tif", f64::NAN), ("inf.tif", f64::INFINITY)] {
        let p = dir.path().join(name);
        write_georef_tif(&p, [corner, 5_000_000.0], 10.0, 32610);
        assert_fails(load1(&p), "Corrupt", name, &format!("georeference places the first sample at ({corner}"));
    }
    let p = write_asc(dir.path(), "nan.asc", "ncols 2\nnrows 2\nxllcorner nan\nyllcorner 0\ncellsize 1\n1 2\n3 4\n");
    assert_fails(load1(&p), "Corrupt", "nan.asc", "georeference places the first sample at (NaN");
}

/// A geographic grid whose rows lie beyond a pole (here the tie point
/// written as latitude, longitude: 120° "north") was refused for a sample
/// spacing of −55.8 m, which does not say why (and one beyond 270° built,
/// placed nowhere on the globe); now the latitude is named, with a hint.
#[test]
fn a_geographic_grid_beyond_a_pole_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, lon: f64, lat: f64| {
        let p = dir.path().join(name);
        write_georef_tif(&p, [lon, lat], 0.001, 4326);
        p
    };
    let swapped = write("swapped.tif", 35.0, 120.0);
    assert_fails(load1(&swapped), "Corrupt", "swapped.tif", "beyond ±90° (are longitude and latitude swapped?)");
    // The same tie point the right way round, and a grid whose rows end at a pole, load.
    assert!(matches!(ok(&write("right.tif", 120.0, 35.0)).georef.crs, Crs::Geographic { .. }));
    ok(&write("pole.tif", 10.0, 90.0));
}

#[test]
fn bad_vertical_scale_is_invalid() {
    for s in [0.0, f64::NAN, f64::INFINITY] {
        let opts = LoadOptions { vertical_scale: Some(s), ..Default::default() };
        let r = load(&[fixture("dfw_texas_srtm3.tif")], &opts);
        assert_fails(r, "Invalid", "dfw_texas_srtm3.tif", "vertical scale");
    }
}

#[test]
fn mismatched_mosaic_tiles_are_invalid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Tiles of different sizes: a 2 × 2 tile beside an 11 × 11 one.
    let west = copy_to(d, &fixture("hgt_mosaic/N00E000.hgt"));
    let small = d.join("N00E001.hgt");
    std::fs::write(&small, [0u8, 1, 0, 2, 0, 3, 0, 4]).unwrap();
    let r = load(&[west.clone(), small], &LoadOptions::default());
    assert_fails(
        r,
        "Invalid",
        "N00E000.hgt",
        "mismatched mosaic tiles: N00E000.hgt is 11 × 11 samples but N00E001.hgt is 2 × 2",
    );

    // The same tile twice, under two spellings.
    let dup = d.join("n00e000.hgt");
    std::fs::copy(&west, &dup).unwrap();
    let r = load(&[west.clone(), dup], &LoadOptions::default());
    assert_fails(r, "Invalid", "N00E000.hgt", "are the same tile (N00E000)");

    // Three of four tiles: not a rectangle.
    let three: Vec<PathBuf> = TILES[..3].iter().map(|n| fixture(&format!("hgt_mosaic/{n}"))).collect();
    let r = load(&three, &LoadOptions::default());
    assert_fails(
        r,
        "Invalid",
        "N00E000.hgt",
        "mismatched mosaic tiles: 3 tiles do not form a full rectangle of 2 × 2; missing N00E001",
    );

    // A tile whose name gives no position.
    let nameless = d.join("tile.hgt");
    std::fs::copy(&west, &nameless).unwrap();
    let r = load(&[west.clone(), nameless], &LoadOptions::default());
    assert_fails(r, "Invalid", "tile.hgt", "mismatched mosaic tiles");

    // Another format in the list.
    let r = load(&[west, fixture("dfw_texas_srtm3.tif")], &LoadOptions::default());
    assert_fails(r, "Unsupported", "dfw_texas_srtm3.tif", "only SRTM .hgt tiles");

    // A folder without tiles.
    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    assert_fails(load1(&empty), "Invalid", "empty", "no .hgt tiles");
}

#[test]
fn unsupported_tiff_layouts_say_what_they_are() {
    use tiff::encoder::{TiffEncoder, colortype};
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("photo.tif");
    let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
    enc.write_image::<colortype::RGB8>(4, 3, &[7u8; 36]).unwrap();
    assert_fails(load1(&p), "Unsupported", "photo.tif", "3 samples per pixel (RGB); a DEM needs one band");

    let p = dir.path().join("rgba.tif");
    let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
    enc.write_image::<colortype::RGBA16>(4, 3, &[7u16; 48]).unwrap();
    assert_fails(load1(&p), "Unsupported", "rgba.tif", "4 samples per pixel (RGBA)");

    // A palette image: an 8-bit grayscale TIFF relabelled as RGB palette.
    let p = dir.path().join("palette.tif");
    let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray8>(4, 3).unwrap();
    img.encoder().write_tag(tiff::tags::Tag::PhotometricInterpretation, 3u16).unwrap();
    img.write_data(&[1u8; 12]).unwrap();
    assert_fails(load1(&p), "Unsupported", "palette.tif", "8-bit palette");
}

#[test]
fn other_tiff_encodings_load_the_same_heights() {
    use tiff::encoder::{Compression, DeflateLevel, TiffEncoder, colortype};
    let base = ok(&fixture("california_crop_deflate.tif"));
    let data: Vec<i16> = base.heights.iter().map(|&h| h as i16).collect();
    let dir = tempfile::tempdir().unwrap();
    for (name, compression) in [
        ("lzw.tif", Compression::Lzw),
        ("packbits.tif", Compression::Packbits),
        ("plain.tif", Compression::Uncompressed),
        ("deflate.tif", Compression::Deflate(DeflateLevel::Fast)),
    ] {
        let p = dir.path().join(name);
        let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap().with_compression(compression);
        enc.write_image::<colortype::GrayI16>(64, 48, &data).unwrap();
        let hf = ok(&p);
        assert_eq!(hf.heights, base.heights, "{name}");
        assert_eq!(hf.georef.crs, Crs::Unknown, "no GeoKeys");
        assert_eq!(hf.spacing_m, [1.0, 1.0]);
    }
    // float64 and uint16 as well.
    let p = dir.path().join("f64.tif");
    let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
    let f: Vec<f64> = base.heights.iter().map(|&h| f64::from(h)).collect();
    enc.write_image::<colortype::Gray64Float>(64, 48, &f).unwrap();
    assert_eq!(ok(&p).heights, base.heights);
}

#[test]
fn corrupt_ascii_token_names_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_asc(
        dir.path(),
        "typo.asc",
        "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n1 2 3\n4 5x 6\n",
    );
    assert_fails(load1(&p), "Corrupt", "typo.asc", "line 8: \"5x\" is not a number");
    let p = write_asc(dir.path(), "short.asc", "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n4 5\n");
    assert_fails(load1(&p), "Corrupt", "short.asc", "found 5 values, expected ncols × nrows = 3 × 2 = 6");
    let p = write_asc(dir.path(), "nohead.asc", "nrows 2\ncellsize 1\n1 2\n3 4\n");
    assert_fails(load1(&p), "Corrupt", "nohead.asc", "no ncols");
}

/// Cut and flip bytes of every fixture: each load must return, never panic.
/// `TERRACHUNK_FUZZ_ROUNDS` (default 24) sets the mutations per fixture.
#[test]
fn mangled_fixtures_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let names = [
        "west_bijou_gully_3m.asc",
        "salish_sea_topobathy_f32.tif",
        "dfw_texas_srtm3.tif",
        "california_crop_deflate.tif",
        "jacksboro_fault_u16.png",
        "kilauea_crop_i16.bt",
        "seamount_crop_f32.exr",
        "kattegat_crop_u8.png",
        "fuji_crop_terrainrgb.png",
        "hgt_mosaic/N00E000.hgt",
    ];
    let mut mangler = Mangler::new(0x2545_f491_4f6c_dd1d);
    for name in names {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let p = dir.path().join(Path::new(name).file_name().unwrap());
        for k in 0..mangle_rounds() {
            let b = mangler.mangle(&bytes, k);
            std::fs::write(&p, &b).unwrap();
            let _ = load1(&p);
        }
    }
}

// ------------------------------------------------ the real corpus (ignored)

/// Every raster in shared/dem/README.md: (file, width, height, min, max,
/// nodata count, tolerance on min/max).
const CORPUS: &[(&str, usize, usize, f64, f64, usize, f64)] = &[
    ("benelux_gtopo30.tif", 720, 480, -6.0, 817.0, 91761, 0.0),
    ("bigtujunga_30m_utm11.tif", 1197, 643, 315.0, 2295.0, 0, 0.0),
    ("california_srtm3_8401x4801.tif", 8401, 4801, -85.0, 4404.0, 0, 0.0),
    ("dfw_texas_srtm3.tif", 367, 359, 147.0, 298.0, 0, 0.0),
    ("france_italy_etopo2.tif", 780, 510, -5035.0, 4086.0, 0, 0.0),
    ("fuji_terrainrgb.png", 512, 512, 13.7, 3751.0, 0, 0.05),
    ("jacksboro_fault_u16.png", 403, 344, 236.0, 1076.0, 0, 0.0),
    ("kilauea_30m.bt", 857, 793, 0.0, 1505.0, 20656, 0.0),
    ("mount_st_helens_30m.tif", 327, 468, 682.0, 2543.0, 4151, 0.0),
    ("salish_sea_topobathy_f32.tif", 120, 91, -1437.0, 2205.0, 0, 0.5),
    ("seamount_holes_f32.tif", 1000, 800, -4719.0, -4100.0, 410661, 0.5),
    ("srtm3_kattegat/N57E011.hgt", 1201, 1201, -6.0, 163.0, 0, 0.0),
    ("srtm3_provence/N43E006.hgt", 1201, 1201, -12.0, 1923.0, 0, 0.0),
    ("srtm3_provence/N43E007.hgt", 1201, 1201, -16.0, 2060.0, 4, 0.0),
    ("srtm3_sierra_3x3/N36W117.hgt", 1201, 1201, -85.0, 2165.0, 0, 0.0),
    ("srtm3_sierra_3x3/N36W118.hgt", 1201, 1201, -80.0, 3372.0, 0, 0.0),
    ("srtm3_sierra_3x3/N36W119.hgt", 1201, 1201, 140.0, 4404.0, 0, 0.0),
    ("srtm3_sierra_3x3/N37W117.hgt", 1201, 1201, 1108.0, 2859.0, 0, 0.0),
    ("srtm3_sierra_3x3/N37W118.hgt", 1201, 1201, 605.0, 3175.0, 0, 0.0),
    ("srtm3_sierra_3x3/N37W119.hgt", 1201, 1201, 1165.0, 4333.0, 0, 0.0),
    ("srtm3_sierra_3x3/N38W117.hgt", 1201, 1201, 1477.0, 3635.0, 0, 0.0),
    ("srtm3_sierra_3x3/N38W118.hgt", 1201, 1201, 1372.0, 3573.0, 0, 0.0),
    ("srtm3_sierra_3x3/N38W119.hgt", 1201, 1201, 1206.0, 3416.0, 0, 0.0),
    ("west_bijou_gully_3m.asc", 43, 89, 1680.78, 1725.43, 2739, 0.005),
];

#[test]
#[ignore = "needs shared/dem; run in release: cargo test --release -- --ignored"]
fn real_corpus_matches_readme() {
    // Run on purpose (it is ignored), it must not pass without its data.
    let dir = shared_dem().expect("needs shared/dem beside the repository, or TERRACHUNK_DEM_DIR");
    for &(name, w, h, min, max, nodata, tol) in CORPUS {
        let t = std::time::Instant::now();
        let hf = ok(&dir.join(name));
        let elapsed = t.elapsed();
        let (lo, hi, nd) = stats(&hf);
        println!(
            "{name}: {} × {}, {lo} … {hi}, {nd} nodata, spacing {:.2?} m, {elapsed:.2?}",
            hf.width, hf.height, hf.spacing_m
        );
        assert_eq!((hf.width, hf.height), (w, h), "{name}");
        assert!(close(f64::from(lo), min, tol), "{name}: min {lo} ≠ {min}");
        assert!(close(f64::from(hi), max, tol), "{name}: max {hi} ≠ {max}");
        assert_eq!(nd, nodata, "{name}");
        assert!(hf.spacing_m.iter().all(|s| s.is_finite() && *s > 0.0));
    }

    // Mosaics: provence 2 tiles side by side, sierra 3 × 3.
    let provence = ok(&dir.join("srtm3_provence"));
    assert_eq!((provence.width, provence.height), (2401, 1201));
    assert_eq!(stats(&provence), (-16.0, 2060.0, 4));
    let sierra = ok(&dir.join("srtm3_sierra_3x3"));
    assert_eq!((sierra.width, sierra.height), (3601, 3601));
    assert_eq!(stats(&sierra), (-85.0, 4404.0, 0));

    // Two independent decoders agree: the 3 × 3 .hgt mosaic (39…36°N,
    // 119…116°W) is the block of the DEFLATE California GeoTIFF that starts
    // 1200 rows below 40°N and 2400 columns east of 121°W.
    let cal = ok(&dir.join("california_srtm3_8401x4801.tif"));
    assert_close(cal.georef.origin[0], -121.0, 1e-9);
    assert_close(cal.georef.origin[1], 40.0, 1e-9);
    // Where the void-filled tiles disagree on a shared edge, both mosaics
    // take the northern / western tile; only the outer border differs, where
    // California took its neighbours outside the 3 × 3 set.
    let mut border_diffs = 0;
    for i in 0..3601 {
        for j in 0..3601 {
            let (a, b) = (sierra.get(i, j), cal.get(1200 + i, 2400 + j));
            if a != b {
                let outer = i == 0 || j == 0 || i == 3600 || j == 3600;
                assert!(outer, "({i}, {j}): .hgt mosaic {a} ≠ GeoTIFF {b}");
                border_diffs += 1;
            }
        }
    }
    println!("sierra vs california: {border_diffs} differences, all on the outer border");
}

// -------------------------------------------------- fixture generator (ignored)

/// Write the real-derived fixtures from shared/dem. Run once; the files are
/// committed. Deterministic: running it again gives the same bytes.
#[test]
#[ignore = "writes fixtures/ from shared/dem"]
fn regenerate_fixtures() {
    let dem = shared_dem().expect("needs shared/dem beside the repository, or TERRACHUNK_DEM_DIR");
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    std::fs::create_dir_all(out.join("hgt_mosaic")).unwrap();

    // Small real files, copied unchanged.
    for name in [
        "west_bijou_gully_3m.asc",
        "salish_sea_topobathy_f32.tif",
        "dfw_texas_srtm3.tif",
        "jacksboro_fault_u16.png",
        "mount_st_helens_30m.tif",
    ] {
        std::fs::write(out.join(name), std::fs::read(dem.join(name)).unwrap()).unwrap();
    }

    // Crop `w × h` at (row r0, column c0), north-up.
    fn crop(hf: &Heightfield, r0: usize, c0: usize, w: usize, h: usize) -> Vec<f32> {
        (r0..r0 + h).flat_map(|r| (c0..c0 + w).map(move |c| (r, c))).map(|(r, c)| hf.get(r, c)).collect()
    }

    // DEFLATE + horizontal predictor GeoTIFF: Death Valley from California.
    {
        let cal = ok(&dem.join("california_srtm3_8401x4801.tif"));
        let (r0, c0) = (4500, 5050);
        let data: Vec<i16> = crop(&cal, r0, c0, 64, 48).iter().map(|&h| h as i16).collect();
        let step = 1.0 / 1200.0;
        // PixelIsArea: the tie point is the corner of sample (0, 0).
        let corner = [-121.0 + c0 as f64 * step - step / 2.0, 40.0 - r0 as f64 * step + step / 2.0];
        write_deflate_geographic_i16(&out.join("california_crop_deflate.tif"), [64, 48], corner, step, 16, &data);
    }

    // Sierra 3 × 3 (3601 × 3601, 39…36° N, 119…116° W; J. de Ferranti's
    // void-filled SRTM3, public domain, attribution requested): the
    // footprints of the level-3 chunks above the two chunks the greedy TIN
    // once got wrong (`hard_cases`), 451 × 451 samples with their shared
    // border rows and columns: chunk 3/3/1 of the 113-cell-leaf tree at
    // 5 m over 5/14/7 (in tile N38W118), and chunk 3/6/5 of the
    // 16-cell-leaf tree over 6/52/44 (across N37W117 and N36W117).
    {
        let sierra = ok(&dem.join("srtm3_sierra_3x3"));
        let step = 1.0 / 1200.0;
        for (name, c0, r0) in [("sierra_n38w118_crop_i16.tif", 1350, 450), ("sierra_n37w117_crop_i16.tif", 2700, 2250)]
        {
            let data: Vec<i16> = crop(&sierra, r0, c0, 451, 451).iter().map(|&h| h as i16).collect();
            let corner = [-119.0 + c0 as f64 * step - step / 2.0, 39.0 - r0 as f64 * step + step / 2.0];
            write_deflate_geographic_i16(&out.join(name), [451, 451], corner, step, 16, &data);
            // The crop is the mosaic's block, sample for sample, in place.
            let back = ok(&out.join(name));
            assert_eq!(back.heights, crop(&sierra, r0, c0, 451, 451), "{name}");
            for a in 0..2 {
                let at = [c0, r0][a] as f64 * sierra.georef.step[a];
                assert!((back.georef.origin[a] - (sierra.georef.origin[a] + at)).abs() < 1e-9, "{name}");
            }
        }
        // The whole mosaic with only its south-east quadrant's ground (rows
        // and columns 1800…3600: the footprint of level-1 chunk 1/1/1 of the
        // 16-cell-leaf tree, above 6/52/44) and the rest at one height
        // (1291 m, about the median of 3/6/5's block). Unlike a crop it has
        // the mosaic's tree, and above 6/52/44 it keeps the fan of nearly
        // parallel parent edges: without `unsliver` its `quantize` build at
        // 5 m turns that chunk's triangle over, as the mosaic's does.
        // Smaller blocks of ground in place (1801 × 1351, 1801 × 901,
        // 901², 451²) did not.
        let data: Vec<i16> = (0..3601 * 3601)
            .map(|k| {
                let (r, c) = (k / 3601, k % 3601);
                if r >= 1800 && c >= 1800 { sierra.get(r, c) as i16 } else { 1291 }
            })
            .collect();
        let corner = [-119.0 - step / 2.0, 39.0 + step / 2.0];
        write_deflate_geographic_i16(&out.join("sierra_se_quadrant_i16.tif"), [3601, 3601], corner, step, 16, &data);
    }

    // .hgt mosaic: a 21 × 21 block of N43E007 (the Var estuary at Nice) around its
    // three-sample void at row 405, cut into four 11 × 11 tiles that share
    // their edges, named as a 2 × 2 set at 0…2°N, 0…2°E.
    {
        let src = ok(&dem.join("srtm3_provence/N43E007.hgt"));
        let block = crop(&src, 395, 242, 21, 21);
        for (k, name) in TILES.iter().enumerate() {
            let (r0, c0) = ((k / 2) * 10, (k % 2) * 10);
            let mut bytes = Vec::with_capacity(242);
            for r in r0..r0 + 11 {
                for c in c0..c0 + 11 {
                    let v = block[r * 21 + c];
                    let v = if v.is_nan() { i16::MIN } else { v as i16 };
                    bytes.extend(v.to_be_bytes());
                }
            }
            std::fs::write(out.join("hgt_mosaic").join(name), bytes).unwrap();
        }
    }

    // BT int16: Kīlauea's south coast, with the offshore nodata.
    {
        let src_path = dem.join("kilauea_30m.bt");
        let src = ok(&src_path);
        let header = std::fs::read(&src_path).unwrap();
        let f64_at = |o: usize| f64::from_le_bytes(header[o..o + 8].try_into().unwrap());
        let (left, top) = (f64_at(28), f64_at(52));
        let (r0, c0) = (688, 256);
        let data: Vec<f64> =
            crop(&src, r0, c0, 64, 48).iter().map(|&h| if h.is_nan() { -32768.0 } else { f64::from(h) }).collect();
        let l = left + c0 as f64 * 30.0;
        let t = top - r0 as f64 * 30.0;
        let edges = [l, l + 64.0 * 30.0, t - 48.0 * 30.0, t];
        let bytes = bt_bytes(64, 48, 2, false, 1, 5, 6326, edges, 1.0, &data);
        std::fs::write(out.join("kilauea_crop_i16.bt"), bytes).unwrap();
    }

    // EXR float32: the first 64 × 48 window (16-sample steps, north-west
    // first) of the seamount grid that is 30–60 % NaN.
    {
        let src = ok(&dem.join("seamount_holes_f32.tif"));
        let mut chosen = None;
        'search: for r0 in (0..src.height - 48).step_by(16) {
            for c0 in (0..src.width - 64).step_by(16) {
                let window = crop(&src, r0, c0, 64, 48);
                let nan = window.iter().filter(|h| h.is_nan()).count();
                if (922..=1843).contains(&nan) {
                    chosen = Some(window);
                    break 'search;
                }
            }
        }
        let window = chosen.expect("a window at the hole's edge");
        write_exr(&out.join("seamount_crop_f32.exr"), 64, 48, vec![("Y", exr::prelude::FlatSamples::F32(window))]);
    }

    // 8-bit grayscale PNG: Gothenburg archipelago, 0…117 m.
    {
        let src = ok(&dem.join("srtm3_kattegat/N57E011.hgt"));
        let data: Vec<u8> = crop(&src, 96, 864, 64, 48).iter().map(|&h| h as u8).collect();
        image::GrayImage::from_raw(64, 48, data).unwrap().save(out.join("kattegat_crop_u8.png")).unwrap();
    }

    // Terrain-RGB: the RGBA bytes around Fuji's summit, untouched.
    {
        let rgba = image::open(dem.join("fuji_terrainrgb.png")).unwrap().to_rgba8();
        let decoded = ok(&dem.join("fuji_terrainrgb.png"));
        let top =
            (0..decoded.heights.len()).max_by(|&a, &b| decoded.heights[a].total_cmp(&decoded.heights[b])).unwrap();
        let (r, c) = (top / 512, top % 512);
        let r0 = r.saturating_sub(24).min(512 - 48) as u32;
        let c0 = c.saturating_sub(32).min(512 - 64) as u32;
        let sub = image::imageops::crop_imm(&rgba, c0, r0, 64, 48).to_image();
        sub.save(out.join("fuji_crop_terrainrgb.png")).unwrap();
    }

    // Print what the tests pin, for a human to compare.
    for name in [
        "california_crop_deflate.tif",
        "sierra_n38w118_crop_i16.tif",
        "sierra_n37w117_crop_i16.tif",
        "sierra_se_quadrant_i16.tif",
        "hgt_mosaic",
        "hgt_mosaic/N01E000.hgt",
        "kilauea_crop_i16.bt",
        "seamount_crop_f32.exr",
        "kattegat_crop_u8.png",
        "fuji_crop_terrainrgb.png",
    ] {
        let hf = ok(&out.join(name));
        let zeros = hf.heights.iter().filter(|&&h| h == 0.0).count();
        println!("{name}: {} × {} {:?} zeros {zeros}", hf.width, hf.height, stats(&hf));
    }
}

/// An int16 GeoTIFF on a WGS 84 geographic grid, DEFLATE with the
/// horizontal predictor in strips of `rows_per_strip` (the layout real
/// GeoTIFFs most often use): `corner` is the north-west corner of sample
/// (0, 0) in degrees (PixelIsArea), `step` the sample spacing in degrees.
fn write_deflate_geographic_i16(
    path: &Path,
    [w, h]: [u32; 2],
    corner: [f64; 2],
    step: f64,
    rows_per_strip: u32,
    data: &[i16],
) {
    use tiff::encoder::{Compression, DeflateLevel, Predictor, TiffEncoder, colortype};
    use tiff::tags::Tag;
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap())
        .unwrap()
        .with_compression(Compression::Deflate(DeflateLevel::Best))
        .with_predictor(Predictor::Horizontal);
    let mut img = enc.new_image::<colortype::GrayI16>(w, h).unwrap();
    img.rows_per_strip(rows_per_strip).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[step, step, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, corner[0], corner[1], 0.0][..]).unwrap();
    let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326];
    e.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    e.write_tag(Tag::GdalNodata, "-32768").unwrap();
    img.write_data(data).unwrap();
}

/// A 20 × 10 float GeoTIFF in UTM 10N placed by a ModelTransformation.
fn write_transformed_tif(path: &Path, matrix: [f64; 16]) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let (w, h) = (20u32, 10u32);
    let data: Vec<f32> = (0..w * h).map(|k| 100.0 + (k % w) as f32).collect();
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(w, h).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelTransformationTag, &matrix[..]).unwrap();
    e.write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32610][..])
        .unwrap();
    img.write_data(&data).unwrap();
}

#[test]
fn a_geotiff_turned_against_its_crs_is_refused_not_placed_north_up() {
    let tmp = tempfile::tempdir().unwrap();
    // 10 m cells turned by about 6°: read north-up, the far corner would
    // land 20 m from where the file puts it.
    let turned = tmp.path().join("turned.tif");
    let (c, s) = (10.0 * 6f64.to_radians().cos(), 10.0 * 6f64.to_radians().sin());
    write_transformed_tif(
        &turned,
        [c, s, 0.0, 500_000.0, s, -c, 0.0, 5_000_000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    );
    assert_fails(load1(&turned), "Unsupported", "turned.tif", "north-up");
    // Rounding in the matrix's turn terms is read as north-up.
    let straight = tmp.path().join("straight.tif");
    write_transformed_tif(
        &straight,
        [10.0, 1e-12, 0.0, 500_000.0, -1e-12, -10.0, 0.0, 5_000_000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    );
    let hf = ok(&straight);
    assert_eq!(hf.georef.step, [10.0, -10.0]);
    assert_eq!(hf.georef.origin, [500_005.0, 4_999_995.0]);
}
