//! Where a georeferenced tileset sits on the globe: the root `transform`
//! (src/geodesy.rs) against positions computed outside terrachunk, by PROJ
//! 9.5.1 (pyproj 3.7.2: EPSG:32605 or EPSG:4326 → EPSG:4979 → EPSG:4978
//! ECEF), and the tileset-level geometric error 3D Tiles clients cull by.

use serde_json::Value;

use crate::common::{build_ok, fixture, tileset};

/// The root transform (column-major) applied to a point in tileset metres.
fn apply(ts: &Value, p: [f64; 3]) -> [f64; 3] {
    let m: Vec<f64> =
        ts["root"]["transform"].as_array().expect("root.transform").iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(m.len(), 16);
    assert_eq!([m[3], m[7], m[11], m[15]], [0.0, 0.0, 0.0, 1.0]);
    [0, 1, 2].map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r])
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// Tileset coordinates (east, north, up) of grid sample (row i, column j) at height 0.
fn sample(ts: &Value, i: f64, j: f64) -> [f64; 3] {
    let s = &ts["extras"]["terrachunk"]["spacing_m"];
    [j * s[0].as_f64().unwrap(), -i * s[1].as_f64().unwrap(), 0.0]
}

#[test]
fn a_utm_grid_centre_lands_on_its_ecef_point_and_its_corners_within_centimetres() {
    // Kilauea, 64 × 48 samples of 30 m in UTM zone 5N (WGS 84).
    let (_tmp, out, _) = build_ok(&fixture("kilauea_crop_i16.bt"), 1.0);
    let ts = tileset(&out);
    let centre = apply(&ts, sample(&ts, 23.5, 31.5));
    let want = [-5_469_956.842_623_514, -2_521_067.996_831_817, 2_091_634.534_425_858_9];
    assert!(distance(centre, want) < 1e-3, "grid centre at {centre:?}, PROJ says {want:?}");
    // The corners: within 1 cm, plus the planar tileset's d²/2R (≈ 0.1 m at
    // 1.2 km) along the vertical.
    for ((i, j), want) in [
        ((0.0, 0.0), [-5_470_148.441_337_79, -2_520_106.072_885_359_6, 2_092_288.152_035_478_3]),
        ((47.0, 63.0), [-5_469_765.058_178_593, -2_522_029.837_840_527_8, 2_090_980.837_470_56]),
    ] {
        let got = apply(&ts, sample(&ts, i, j));
        let d = distance(got, want);
        assert!(d < 0.15, "sample ({i}, {j}) at {got:?}, {d} m from PROJ's {want:?}");
    }
    let p = &ts["extras"]["terrachunk"]["placement"];
    assert!((p["convergence_deg"].as_f64().unwrap() + 0.7447).abs() < 1e-3, "{p}");
}

#[test]
fn a_geographic_grid_centre_lands_on_its_ecef_point() {
    // Dallas–Fort Worth, SRTM 3″ in EPSG:4326: centre (−97.33208°, 32.67208°).
    let (_tmp, out, _) = build_ok(&fixture("dfw_texas_srtm3.tif"), 1.0);
    let ts = tileset(&out);
    let ex = &ts["extras"]["terrachunk"];
    let (w, h) = (ex["grid"]["width"].as_f64().unwrap(), ex["grid"]["height"].as_f64().unwrap());
    let mid = sample(&ts, (h - 1.0) / 2.0, (w - 1.0) / 2.0);
    let centre = apply(&ts, mid);
    let want = [-685_854.690_031_767_8, -5_330_249.945_079_397, 3_423_402.645_685_694];
    assert!(distance(centre, want) < 1e-3, "grid centre at {centre:?}, PROJ says {want:?}");
    // Up is the ellipsoid normal there: 100 m of height is 100 m outward
    // (the normal misses the Earth's centre by up to 21 km, hence 0.1 m).
    let up = apply(&ts, [mid[0], mid[1], 100.0]);
    let r = |p: [f64; 3]| distance(p, [0.0; 3]);
    assert!((r(up) - r(centre) - 100.0).abs() < 0.1);
}

#[test]
fn grids_without_a_usable_georeference_get_no_transform() {
    // A PNG (no georeference) and an .asc in an unnamed projected CRS.
    for name in ["fuji_crop_terrainrgb.png", "west_bijou_gully_3m.asc"] {
        let (_tmp, out, _) = build_ok(&fixture(name), 4.0);
        let ts = tileset(&out);
        assert!(ts["root"].get("transform").is_none(), "{name}");
        assert!(ts["extras"]["terrachunk"].get("placement").is_none(), "{name}");
    }
}

#[test]
fn the_tileset_is_not_culled_while_it_is_bigger_than_a_pixel() {
    // Clients skip a tileset whose geometricError is below their bound on
    // screen; for terrain, drawing nothing is an error as large as the
    // terrain, so the tileset's (and a content-less root's) error is at
    // least the root box's diagonal.
    for name in ["dfw_texas_srtm3.tif", "kilauea_crop_i16.bt"] {
        let (_tmp, out, _) = build_ok(&fixture(name), 1.0);
        let ts = tileset(&out);
        let b: Vec<f64> =
            ts["root"]["boundingVolume"]["box"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let diagonal = 2.0 * (b[3].powi(2) + b[7].powi(2) + b[11].powi(2)).sqrt();
        let ge = ts["geometricError"].as_f64().unwrap();
        assert!(ge >= diagonal * (1.0 - 1e-9), "{name}: geometricError {ge} < box diagonal {diagonal}");
    }
}
