//! Where a georeferenced tileset sits on the globe: the root `transform`
//! (src/geodesy.rs) against positions computed outside terrachunk, by PROJ
//! 9.5.1 (pyproj 3.7.2: EPSG:32605 or EPSG:4326 → EPSG:4979 → EPSG:4978
//! ECEF) or from published worked examples of each projection (with the
//! datum's published Helmert shift done here), and the tileset-level
//! geometric error 3D Tiles clients cull by.

use std::path::Path;

use serde_json::Value;

use crate::common::{build_ok, cli, fixture, tileset, verified};

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

// ------------------------------------------- any CRS, against published points

/// An ellipsoid: semi-major axis and flattening.
#[derive(Clone, Copy)]
struct Ellipsoid {
    a: f64,
    f: f64,
}

const WGS84: Ellipsoid = Ellipsoid { a: 6_378_137.0, f: 1.0 / 298.257_223_563 };
/// GRS 80 (ETRS89, RGF93, NAD83).
const GRS80: Ellipsoid = Ellipsoid { a: 6_378_137.0, f: 1.0 / 298.257_222_101 };
/// Airy 1830 (OSGB36): a = 6 377 563.396 m, b = 6 356 256.909 m (Ordnance Survey).
const AIRY_1830: Ellipsoid = Ellipsoid { a: 6_377_563.396, f: 1.0 - 6_356_256.909 / 6_377_563.396 };
/// Clarke 1866 (NAD27): a = 6 378 206.4 m, b = 6 356 583.8 m.
const CLARKE_1866: Ellipsoid = Ellipsoid { a: 6_378_206.4, f: 1.0 - 6_356_583.8 / 6_378_206.4 };

fn ecef_on(ell: Ellipsoid, lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    let e2 = ell.f * (2.0 - ell.f);
    let (sp, cp) = lat_deg.to_radians().sin_cos();
    let (sl, cl) = lon_deg.to_radians().sin_cos();
    let n = ell.a / (1.0 - e2 * sp * sp).sqrt();
    [(n + h) * cp * cl, (n + h) * cp * sl, (n * (1.0 - e2) + h) * sp]
}

/// WGS 84 latitude and longitude (degrees) of an ECEF point near the
/// surface, by fixed-point iteration on the latitude.
fn wgs84_of_ecef(p: [f64; 3]) -> (f64, f64) {
    let e2 = WGS84.f * (2.0 - WGS84.f);
    let r = p[0].hypot(p[1]);
    let mut lat = p[2].atan2(r * (1.0 - e2));
    for _ in 0..10 {
        let n = WGS84.a / (1.0 - e2 * lat.sin().powi(2)).sqrt();
        lat = p[2].atan2(r - e2 * n * lat.cos());
    }
    (lat.to_degrees(), p[1].atan2(p[0]).to_degrees())
}

/// A datum as the reference points need it: its ellipsoid and the Helmert
/// transform (position-vector convention: translation m, rotations ″,
/// scale ppm) that takes its ECEF coordinates to WGS 84's.
struct Datum {
    ellipsoid: Ellipsoid,
    helmert: [f64; 7],
}

impl Datum {
    /// The ECEF point at ellipsoidal height 0 on WGS 84 under the datum's
    /// latitude/longitude: where a planar tileset puts height 0 there.
    fn wgs84_ecef(&self, lat_deg: f64, lon_deg: f64) -> [f64; 3] {
        let p = ecef_on(self.ellipsoid, lat_deg, lon_deg, 0.0);
        let [tx, ty, tz, rx, ry, rz, s] = self.helmert;
        let r = |arcsec: f64| (arcsec / 3600.0).to_radians();
        let (rx, ry, rz, m) = (r(rx), r(ry), r(rz), 1.0 + s * 1e-6);
        let q = [
            tx + m * (p[0] - rz * p[1] + ry * p[2]),
            ty + m * (rz * p[0] + p[1] - rx * p[2]),
            tz + m * (-ry * p[0] + rx * p[1] + p[2]),
        ];
        let (lat, lon) = wgs84_of_ecef(q);
        ecef_on(WGS84, lat, lon, 0.0)
    }
}

/// GRS 80 datums held equal to WGS 84 (as their EPSG definitions do).
const ETRS89: Datum = Datum { ellipsoid: GRS80, helmert: [0.0; 7] };
const WGS84_DATUM: Datum = Datum { ellipsoid: WGS84, helmert: [0.0; 7] };
/// OSGB36 → WGS 84: Ordnance Survey's published ETRS89 → OSGB36 Helmert
/// (−446.448, +125.157, −542.060 m; −0.1502, −0.2470, −0.8421″; +20.4894
/// ppm) with every sign turned (good to a few cm against the exact
/// inverse; the transform itself is good to about 5 m against OSTN15).
const OSGB36: Datum =
    Datum { ellipsoid: AIRY_1830, helmert: [446.448, -125.157, 542.060, 0.1502, 0.2470, 0.8421, -20.4894] };
/// NAD27 → WGS 84, the mean for the conterminous US (NIMA TR8350.2,
/// table B.1, NAS-C: −8, 160, 176 m).
const NAD27: Datum = Datum { ellipsoid: CLARKE_1866, helmert: [-8.0, 160.0, 176.0, 0.0, 0.0, 0.0, 0.0] };

fn dms(d: f64, m: f64, s: f64) -> f64 {
    d.signum() * (d.abs() + m / 60.0 + s / 3600.0)
}

/// Lambert-93 (EPSG:2154) from RGF93 latitude/longitude by IGN's published
/// constants of the projection (n = 0.7256077650, C = 11 754 255.426 m,
/// X_s = 700 000 m, Y_s = 12 655 612.050 m, λ0 = 3° E; GRS 80).
fn lambert93(lat_deg: f64, lon_deg: f64) -> [f64; 2] {
    let e = (GRS80.f * (2.0 - GRS80.f)).sqrt();
    let (sp, phi) = (lat_deg.to_radians().sin(), lat_deg.to_radians());
    let iso = ((std::f64::consts::FRAC_PI_4 + phi / 2.0).tan() * ((1.0 - e * sp) / (1.0 + e * sp)).powf(e / 2.0)).ln();
    let (n, c) = (0.725_607_765_0, 11_754_255.426);
    let r = c * (-n * iso).exp();
    let gamma = n * (lon_deg - 3.0).to_radians();
    [700_000.0 + r * gamma.sin(), 12_655_612.050 - r * gamma.cos()]
}

/// A flat float GeoTIFF of 41 × 41 samples `step` apart in EPSG `epsg`
/// (projected; no linear-unit key, so the unit is the code's), PixelIsPoint,
/// with sample (row, column) `at` on the point `xy`.
fn write_projected_tif(path: &Path, epsg: u16, step: f64, at: (f64, f64), xy: [f64; 2]) {
    projected_tif(path, epsg, (41, step), at, xy, |_, _| 0.0);
}

/// A projected GeoTIFF of `n` × `n` samples `step` apart (projected, no
/// linear-unit key, PixelIsPoint), sample (row, column) `at` on the point
/// `xy`, and the height `height(row, column)` at each sample.
fn projected_tif(
    path: &Path,
    epsg: u16,
    (n, step): (u32, f64),
    at: (f64, f64),
    xy: [f64; 2],
    height: impl Fn(f64, f64) -> f32,
) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(n, n).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[step, step, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[at.1, at.0, 0.0, xy[0], xy[1], 0.0][..]).unwrap();
    // Projected model, PixelIsPoint, ProjectedCSType = epsg.
    let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, epsg];
    e.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    let data: Vec<f32> = (0..n * n).map(|k| height(f64::from(k / n), f64::from(k % n))).collect();
    img.write_data(&data).unwrap();
}

/// One published point of a CRS: its projected coordinates and its
/// latitude/longitude on the CRS's datum.
struct Published {
    epsg: u16,
    /// Where the coordinates come from.
    source: &'static str,
    /// Source units per sample (metres, or US survey feet).
    step: f64,
    /// Metres per source unit, as the spacing must come out.
    unit_m: f64,
    xy: [f64; 2],
    lat_lon: (f64, f64),
    datum: Datum,
}

fn published_points() -> Vec<Published> {
    vec![
        Published {
            epsg: 2154,
            source: "Lambert-93 by IGN's published constants of the projection",
            step: 25.0,
            unit_m: 1.0,
            xy: lambert93(45.5, 6.0),
            lat_lon: (45.5, 6.0),
            datum: ETRS89,
        },
        Published {
            epsg: 3035,
            source: "IOGP Guidance Note 7-2, Lambert Azimuthal Equal Area example",
            step: 25.0,
            unit_m: 1.0,
            xy: [3_962_799.45, 2_999_718.85],
            lat_lon: (50.0, 5.0),
            datum: ETRS89,
        },
        Published {
            // NAD27 / Texas South Central: the US State Plane of 1927, in US survey feet.
            epsg: 32040,
            source: "IOGP Guidance Note 7-2, Lambert Conic Conformal (2SP) example",
            step: 100.0,
            unit_m: 1200.0 / 3937.0,
            xy: [2_963_503.91, 254_759.80],
            lat_lon: (28.5, -96.0),
            datum: NAD27,
        },
        Published {
            // The Guidance Note's example is for EPSG:3032 (λ0 = 70° E, false
            // origin 6 000 km both ways): the same point 70° further west on
            // EPSG:3031 (λ0 = 0, no false origin) has the same offsets.
            epsg: 3031,
            source: "IOGP Guidance Note 7-2, Polar Stereographic (variant B) example",
            step: 25.0,
            unit_m: 1.0,
            xy: [7_255_380.79 - 6_000_000.0, 7_053_389.56 - 6_000_000.0],
            lat_lon: (-75.0, 50.0),
            datum: WGS84_DATUM,
        },
        Published {
            epsg: 27700,
            source: "Ordnance Survey, Caister water tower (A guide to coordinate systems in Great Britain)",
            step: 25.0,
            unit_m: 1.0,
            xy: [651_409.903, 313_177.270],
            lat_lon: (dms(52.0, 39.0, 27.2531), dms(1.0, 43.0, 4.5177)),
            datum: OSGB36,
        },
    ]
}

/// The tileset's centre frame (east, north, up unit vectors in ECEF) from
/// its recorded placement, to split a miss into ground and height.
fn enu_axes(ts: &Value) -> [[f64; 3]; 3] {
    let p = &ts["extras"]["terrachunk"]["placement"];
    let (lat, lon) = (p["lat_deg"].as_f64().unwrap().to_radians(), p["lon_deg"].as_f64().unwrap().to_radians());
    let (sp, cp, sl, cl) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
    [[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]]
}

/// Builds a grid with sample `at` on the published point (checking its
/// spacing in metres) and returns how far that sample lands from the
/// point's ECEF position, along the ground and up, and its distance from
/// the grid centre, metres.
fn miss(dir: &Path, p: &Published, at: (f64, f64)) -> (f64, f64, f64) {
    let dem = dir.join(format!("epsg{}_{}_{}.tif", p.epsg, at.0, at.1));
    write_projected_tif(&dem, p.epsg, p.step, at, p.xy);
    landing(&dem, p, at)
}

/// Builds `dem` (41 × 41 samples) beside itself and measures where sample
/// `at` lands against the published point `p`, as [`miss`] says.
fn landing(dem: &Path, p: &Published, at: (f64, f64)) -> (f64, f64, f64) {
    let name = dem.file_stem().unwrap().to_string_lossy();
    let out = dem.with_file_name(format!("out_{name}"));
    let opts = crate::common::options(dem, &out, 0.5, 1);
    let report = terrachunk::pipeline::build(&opts).unwrap_or_else(|e| panic!("EPSG:{}: {e}", p.epsg));
    assert_eq!(report.not_placed, None, "EPSG:{}", p.epsg);
    verified(&out);
    let ts = tileset(&out);
    let spacing = &ts["extras"]["terrachunk"]["spacing_m"];
    for s in spacing.as_array().unwrap() {
        let s = s.as_f64().unwrap();
        assert!((s - p.step * p.unit_m).abs() < 1e-9, "EPSG:{}: spacing {s} m, not {} m", p.epsg, p.step * p.unit_m);
    }
    let got = apply(&ts, sample(&ts, at.0, at.1));
    let want = p.datum.wgs84_ecef(p.lat_lon.0, p.lat_lon.1);
    let d = [0, 1, 2].map(|r| got[r] - want[r]);
    let axes = enu_axes(&ts);
    let enu = axes.map(|ax| ax[0] * d[0] + ax[1] * d[1] + ax[2] * d[2]);
    let from_centre = p.step * p.unit_m * (at.0 - 20.0).hypot(at.1 - 20.0);
    (enu[0].hypot(enu[1]), enu[2], from_centre)
}

/// Lambert-93, ETRS89-LAEA, a US State Plane grid in feet, Antarctic polar
/// stereographic and the British National Grid: a grid centred on a point
/// whose coordinates are published lands that point on its ECEF position
/// within 1 cm (the published coordinates are rounded to 1 cm or 1 mm: the
/// misses were 0.02–3.3 mm). A grid whose north-west corner sample is on it
/// lands that sample within 2 cm along the ground, 707 or 862 m from the
/// grid centre (rounding, plus the change of the projection's scale
/// across the grid, which the tileset's one linear map cannot follow: 8 mm
/// for polar stereographic at 75° S, under 2 mm for the others), and d²/2R
/// (4–6 cm) above the ellipsoid, as a planar tileset must, within 5 mm.
#[test]
fn grids_in_any_crs_land_on_published_points() {
    let tmp = tempfile::tempdir().unwrap();
    let r = 6_371_000.0;
    for p in published_points() {
        let (ground, up, _) = miss(tmp.path(), &p, (20.0, 20.0));
        assert!(ground.hypot(up) < 0.01, "EPSG:{} ({}): centre {ground} m, {up} m up off", p.epsg, p.source);
        let (ground, up, d) = miss(tmp.path(), &p, (0.0, 0.0));
        assert!(ground < 0.02, "EPSG:{} ({}): corner {ground} m off along the ground", p.epsg, p.source);
        let float = d * d / (2.0 * r);
        assert!((up - float).abs() < 0.005, "EPSG:{} ({}): corner {up} m up, not {float}", p.epsg, p.source);
    }
}

/// An ASCII grid takes its CRS from the `.prj` beside it: the EPSG code
/// in its WKT (here a compound CRS, British National Grid + Newlyn
/// heights), or a PROJ.4 definition (here Lambert-93's); its sample
/// centred on the published point lands within 1 cm of it.
#[test]
fn an_ascii_grid_is_placed_by_the_crs_its_prj_names() {
    let tmp = tempfile::tempdir().unwrap();
    let points = published_points();
    let bng = points.iter().find(|p| p.epsg == 27700).unwrap();
    let l93 = points.iter().find(|p| p.epsg == 2154).unwrap();
    let wkt = r#"COMPD_CS["OSGB 1936 / British National Grid + ODN height",
        PROJCS["OSGB 1936 / British National Grid",GEOGCS["OSGB 1936",DATUM["OSGB_1936",
        SPHEROID["Airy 1830",6377563.396,299.3249646,AUTHORITY["EPSG","7001"]],AUTHORITY["EPSG","6277"]],
        PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4277"]],
        PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",49],UNIT["metre",1],
        AUTHORITY["EPSG","27700"]],VERT_CS["ODN height",VERT_DATUM["Ordnance Datum Newlyn",2005],
        UNIT["metre",1],AUTHORITY["EPSG","5701"]],AUTHORITY["EPSG","7405"]]"#;
    let proj4 = "+proj=lcc +lat_1=49 +lat_2=44 +lat_0=46.5 +lon_0=3 +x_0=700000 +y_0=6600000 +ellps=GRS80 \
                 +towgs84=0,0,0,0,0,0,0 +units=m +no_defs";
    for (name, prj, p) in [("bng", wkt, bng), ("l93", proj4, l93)] {
        let cell = p.step;
        let mut text = format!(
            "ncols 41\nnrows 41\nxllcorner {}\nyllcorner {}\ncellsize {cell}\n",
            p.xy[0] - 20.5 * cell,
            p.xy[1] - 20.5 * cell
        );
        text += &"0 ".repeat(41 * 41);
        let dem = tmp.path().join(format!("{name}.asc"));
        std::fs::write(&dem, text).unwrap();
        std::fs::write(dem.with_extension("prj"), prj).unwrap();
        let (ground, up, _) = landing(&dem, p, (20.0, 20.0));
        assert!(ground.hypot(up) < 0.01, "{name}.asc: centre {ground} m, {up} m up off");
    }
}

/// A GeoTIFF in a CRS no definition covers (EPSG code 9999 names none)
/// still builds, in its local frame, and the build says why it is not on
/// the globe.
#[test]
fn a_crs_the_library_does_not_know_builds_unplaced_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("unknown.tif");
    write_projected_tif(&dem, 9999, 25.0, (0.0, 0.0), [500_000.0, 5_000_000.0]);
    let out = tmp.path().join("out");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", "none"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("warning: not placed on the globe: EPSG:9999 is not a coordinate system terrachunk knows"),
        "{err}"
    );
    let ts = tileset(&out);
    assert!(ts["root"].get("transform").is_none() && ts["extras"]["terrachunk"].get("placement").is_none());
    assert_eq!(ts["extras"]["terrachunk"]["spacing_m"], serde_json::json!([25.0, 25.0]));
    verified(&out);
}

/// The distance, along the WGS 84 normal at `(lat, lon)` and across it,
/// from the ellipsoid point there to `drawn`.
fn off_the_ellipsoid(drawn: [f64; 3], lat: f64, lon: f64) -> (f64, f64) {
    let truth = ecef_on(WGS84, lat, lon, 0.0);
    let d = [0, 1, 2].map(|r| drawn[r] - truth[r]);
    let (sp, cp) = lat.to_radians().sin_cos();
    let (sl, cl) = lon.to_radians().sin_cos();
    let up = [cp * cl, cp * sl, sp];
    let along = d[0] * up[0] + d[1] * up[1] + d[2] * up[2];
    (along, (distance(d, [0.0; 3]).powi(2) - along * along).max(0.0).sqrt())
}

#[test]
fn the_flat_frames_distance_from_the_ellipsoid_is_stated_measured_and_warned_about() {
    let tmp = tempfile::tempdir().unwrap();
    // 2° × 2° at 40° N, sample centres from 106° W, 39° N.
    let dem = geographic_asc(tmp.path(), "wide", (41, 41), (-106.0, 39.0), 0.05);
    let out = tmp.path().join("out");
    let args = ["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", "none", "--frame", "flat"];
    let o = cli(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ts = tileset(&out);
    let stated = &ts["extras"]["terrachunk"]["placement"]["flat_frame_error"];
    // Independently: the four corners as a client draws them, against
    // their longitude and latitude on the ellipsoid.
    let mut worst = (0.0f64, 0.0f64);
    for (i, j) in [(0.0, 0.0), (0.0, 40.0), (40.0, 0.0), (40.0, 40.0)] {
        let (lat, lon) = (41.0 - 0.05 * i, -106.0 + 0.05 * j);
        let (up, across) = off_the_ellipsoid(apply(&ts, sample(&ts, i, j)), lat, lon);
        worst = (worst.0.max(up), worst.1.max(across));
    }
    // d²/2R at the corners, 140 km from the centre: about 1.5 km up.
    assert!((1450.0..1650.0).contains(&worst.0), "{worst:?}");
    let v = stated["vertical_m"].as_f64().unwrap();
    let h = stated["horizontal_m"].as_f64().unwrap();
    assert!((v - worst.0).abs() < 1e-3 * worst.0, "stated {v} m up, the corners are {} m", worst.0);
    assert!(h >= worst.1 - 1e-3, "stated {h} m across, a corner is {} m", worst.1);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stdout.contains("on the globe: planar, drawn up to"), "{stdout}");
    assert!(stderr.contains("warning: the tileset is planar") && stderr.contains("more than the leaf δ"), "{stderr}");

    // verify measures it again from the transform, and prints it.
    let r = verified(&out);
    let measured = r.flat_frame_error.expect("a placed tileset");
    assert!((measured.vertical_m - v).abs() < 1e-6);
    // Extras that state less than the transform does are a failure.
    let mut edited = ts.clone();
    edited["extras"]["terrachunk"]["placement"]["flat_frame_error"]["vertical_m"] = 1.0.into();
    std::fs::write(out.join("tileset.json"), serde_json::to_vec(&edited).unwrap()).unwrap();
    let r = terrachunk::verify::verify(&out, Some(&[dem])).unwrap();
    assert!(r.failures.iter().any(|f| f.contains("flat_frame_error")), "{:?}", r.failures);
}

#[test]
fn a_small_grid_is_placed_within_its_leaf_error_without_a_warning() {
    // Mount St Helens, 9.8 × 14 km: 5.7 m up at the corners (d²/2R),
    // within a 10 m leaf δ.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let dem = fixture("mount_st_helens_30m.tif");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--max-error", "10"]);
    assert!(o.status.success());
    assert!(!String::from_utf8_lossy(&o.stderr).contains("warning"), "{}", String::from_utf8_lossy(&o.stderr));
    let ts = tileset(&out);
    let e = &ts["extras"]["terrachunk"]["placement"]["flat_frame_error"];
    let v = e["vertical_m"].as_f64().unwrap();
    assert!((5.6..5.9).contains(&v), "{e}");
    // NAD27 UTM: the frame undoes convergence and scale, so across the
    // normal only centimetres remain.
    assert!(e["horizontal_m"].as_f64().unwrap() < 0.1, "{e}");
}

/// A geographic ASCII grid of `cols` × `rows` samples `cell` degrees
/// apart whose south-west sample centre is at (`west`, `south`): gentle
/// hills around 100 m.
fn geographic_asc(
    dir: &Path,
    name: &str,
    (cols, rows): (usize, usize),
    (west, south): (f64, f64),
    cell: f64,
) -> std::path::PathBuf {
    let dem = dir.join(format!("{name}.asc"));
    let mut text = format!(
        "ncols {cols}\nnrows {rows}\nxllcorner {}\nyllcorner {}\ncellsize {cell}\n",
        west - cell / 2.0,
        south - cell / 2.0
    );
    for i in 0..rows {
        let row: Vec<String> = (0..cols)
            .map(|j| format!("{:.2}", 100.0 + 50.0 * (i as f64 * 0.1).sin() * (j as f64 * 0.13).cos()))
            .collect();
        text += &row.join(" ");
        text += "\n";
    }
    std::fs::write(&dem, text).unwrap();
    std::fs::write(dem.with_extension("prj"), "+proj=longlat +datum=WGS84 +no_defs").unwrap();
    dem
}

#[test]
fn a_grid_across_the_antimeridian_is_placed_at_180_degrees_and_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    // 179.9° E to 180.1° E (written 180.1, past the antimeridian), 17° S: Fiji.
    let dem = geographic_asc(tmp.path(), "fiji", (81, 61), (179.9, -17.075), 0.0025);
    let (_t, out, _) = build_ok(&dem, 1.0);
    let ts = tileset(&out);
    let p = &ts["extras"]["terrachunk"]["placement"];
    let lon = p["lon_deg"].as_f64().unwrap();
    assert!((lon.rem_euclid(360.0) - 180.0).abs() < 1e-9, "{p}");
    assert!((p["lat_deg"].as_f64().unwrap() + 17.0).abs() < 1e-9, "{p}");
    // The corners against their own longitudes, east of the line too.
    for (i, j) in [(0.0, 0.0), (60.0, 80.0)] {
        let (lat, lon) = (-17.0 + 0.075 - 0.0025 * i, 179.9 + 0.0025 * j);
        let (up, across) = off_the_ellipsoid(apply(&ts, sample(&ts, i, j)), lat, lon);
        // 11 km from the centre: d²/2R ≈ 10 m up; the equirectangular
        // approximation a few metres across.
        assert!(up.abs() < 20.0 && across < 10.0, "corner ({i}, {j}): {up} m up, {across} m across");
    }
    crate::common::verified_against(&out, &[dem]);
}

#[test]
fn a_grid_touching_the_pole_builds_places_and_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    // Its north row is the pole itself: every sample there is one point.
    let dem = geographic_asc(tmp.path(), "pole", (81, 61), (10.0, 90.0 - 0.15), 0.0025);
    let (_t, out, _) = build_ok(&dem, 1.0);
    let ts = tileset(&out);
    let p = &ts["extras"]["terrachunk"]["placement"];
    assert!((p["lat_deg"].as_f64().unwrap() - 89.925).abs() < 1e-9, "{p}");
    let e = &p["flat_frame_error"];
    assert!(e["vertical_m"].as_f64().unwrap().is_finite() && e["horizontal_m"].as_f64().unwrap() > 0.0, "{e}");
    crate::common::verified_against(&out, &[dem]);
}

#[test]
fn a_whole_globe_grid_of_degrees_builds_and_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    // One sample per degree, −180° to 180° and pole to pole (as ETOPO's
    // grids are laid out): its equator spans the whole circumference,
    // 40 075 km, which the extent check once took for a wrong spacing.
    let dem = geographic_asc(tmp.path(), "globe", (361, 181), (-180.0, -90.0), 1.0);
    let (_t, out, _) = build_ok(&dem, 1.0);
    let ts = tileset(&out);
    let p = &ts["extras"]["terrachunk"]["placement"];
    assert!(p["lat_deg"].as_f64().unwrap().abs() < 1e-9 && p["lon_deg"].as_f64().unwrap().abs() < 1e-9, "{p}");
    crate::common::verified_against(&out, &[dem]);
}

#[test]
fn a_curved_grid_wider_than_a_hemisphere_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    // 240° of longitude: the root chunk's far columns lie more than 90°
    // from its middle, where the ground's up points below the chunk's
    // horizon and a longitude taken within half a turn of the grid's first
    // column lands on the wrong side.
    let dem = geographic_asc(tmp.path(), "wide", (241, 121), (-120.0, -60.0), 1.0);
    let (_t, out, report) = build_ok(&dem, 1.0);
    assert_eq!(report.frame, terrachunk::geodesy::FrameKind::Curved);
    let r = crate::common::verified_against(&out, &[dem]);
    assert!(r.curved);
}

#[test]
fn a_grid_once_round_the_earth_stays_planar_and_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    // −180° to 180° without a pole: its first and last columns are one
    // meridian, which a curved file could not tell apart again.
    let dem = geographic_asc(tmp.path(), "round", (361, 161), (-180.0, -80.0), 1.0);
    let (_t, out, report) = build_ok(&dem, 1.0);
    assert_eq!(report.frame, terrachunk::geodesy::FrameKind::Flat);
    crate::common::verified_against(&out, std::slice::from_ref(&dem));
    let refused = tmp.path().join("refused");
    let (d, o) = (dem.to_str().unwrap(), refused.to_str().unwrap());
    crate::common::assert_bad_input(&["build", d, "-o", o, "--frame", "curved"], &refused, "once round the Earth");
}

#[test]
fn a_curved_normal_mapped_tileset_has_the_grounds_up_for_its_vertex_normals() {
    let tmp = tempfile::tempdir().unwrap();
    // 60° × 40°: at the sides the ground's up is 30° from the grid centre's,
    // the axes every chunk is written in.
    let dem = geographic_asc(tmp.path(), "wide", (121, 81), (-30.0, -20.0), 0.5);
    let out = tmp.path().join("out");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--normal-map", "--max-error", "20"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ts = tileset(&out);
    assert_eq!(ts["extras"]["terrachunk"]["placement"]["frame"], "curved");
    crate::common::verified_against(&out, &[dem]);
    crate::common::khronos_validate(&out);
    let (mut worst, mut n) = (1.0f64, 0);
    let mut stack = vec![&ts["root"]];
    while let Some(tile) = stack.pop() {
        if let Some(uri) = tile["content"]["uri"].as_str() {
            let c = terrachunk::verify::read_chunk(&out.join(uri)).unwrap();
            for (p, nv) in c.surface.positions.iter().zip(&c.surface.normals) {
                let e = apply(&ts, [p[0], -p[2], p[1]]);
                let [x, y, z] = nv.map(f64::from);
                let (tip, base) = (apply(&ts, [x, -z, y]), apply(&ts, [0.0; 3]));
                let d = [0, 1, 2].map(|r| tip[r] - base[r]);
                let (lat, lon) = wgs84_of_ecef(e);
                let (sp, cp) = lat.to_radians().sin_cos();
                let (sl, cl) = lon.to_radians().sin_cos();
                let up = [cp * cl, cp * sl, sp];
                worst = worst.min((d[0] * up[0] + d[1] * up[1] + d[2] * up[2]) / distance(d, [0.0; 3]));
                n += 1;
            }
        }
        stack.extend(tile["children"].as_array().into_iter().flatten());
    }
    assert!(
        n > 1000 && worst > 0.99999,
        "{n} normals, the worst {:.3}° from the ground's up",
        worst.acos().to_degrees()
    );
}

/// Every surface vertex of every leaf of a curved tileset of a geographic
/// ASCII grid (`west`, `north` the centre of sample (0, 0), `cell`
/// degrees), taken to ECEF as a client does (node translation + POSITION,
/// y-up to z-up, the root transform), against the ECEF point of the grid
/// sample at its latitude, longitude and DEM height, computed here. Returns
/// the worst distance along the ellipsoid normal and across it, and the
/// vertices compared.
fn curved_leaf_vertices_against_their_samples(
    out: &Path,
    dem: &Path,
    (west, north, cell): (f64, f64, f64),
) -> (f64, f64, usize) {
    let ts = tileset(out);
    let text = std::fs::read_to_string(dem).unwrap();
    let heights: Vec<Vec<f64>> =
        text.lines().skip(5).map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect()).collect();
    let (mut along, mut across, mut n) = (0.0f64, 0.0f64, 0);
    let mut stack = vec![&ts["root"]];
    while let Some(tile) = stack.pop() {
        let kids = tile["children"].as_array().map(|k| k.iter().collect::<Vec<_>>()).unwrap_or_default();
        if kids.is_empty() && tile.get("content").is_some() {
            let uri = tile["content"]["uri"].as_str().unwrap();
            let c = terrachunk::verify::read_chunk(&out.join(uri)).unwrap();
            for p in &c.surface.positions {
                let e = apply(&ts, [p[0], -p[2], p[1]]);
                let (lat, lon) = wgs84_of_ecef(e);
                let (i, j) = (((north - lat) / cell).round(), ((lon - west) / cell).round());
                let h = heights[i as usize][j as usize];
                let truth = ecef_on(WGS84, north - i * cell, west + j * cell, h);
                let d = [0, 1, 2].map(|r| e[r] - truth[r]);
                let (sp, cp) = (north - i * cell).to_radians().sin_cos();
                let (sl, cl) = (west + j * cell).to_radians().sin_cos();
                let up = [cp * cl, cp * sl, sp];
                let a = d[0] * up[0] + d[1] * up[1] + d[2] * up[2];
                along = along.max(a.abs());
                across = across.max((distance(d, [0.0; 3]).powi(2) - a * a).max(0.0).sqrt());
                n += 1;
            }
        }
        stack.extend(kids);
    }
    (along, across, n)
}

#[test]
fn a_40_degree_grid_is_curved_and_verified_along_the_ellipsoid_normal() {
    // 40° × 40° from 20° W, 50° N to 20° E, 10° N: 513² samples 0.078° apart.
    let tmp = tempfile::tempdir().unwrap();
    let cell = 40.0 / 512.0;
    let dem = geographic_asc(tmp.path(), "wide", (513, 513), (-20.0, 10.0), cell);
    let out = tmp.path().join("out");
    let o =
        cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--max-error", "20", "--texture", "none"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ts = tileset(&out);
    let p = &ts["extras"]["terrachunk"]["placement"];
    assert_eq!(p["frame"], "curved", "{p}");
    // A planar frame would draw the corners hundreds of kilometres off.
    assert!(p["flat_frame_error"]["vertical_m"].as_f64().unwrap().abs() > 1e5, "{p}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("on the globe: curved"));
    assert!(!String::from_utf8_lossy(&o.stderr).contains("warning"), "{}", String::from_utf8_lossy(&o.stderr));
    // Leaf vertices are samples: where a client draws them is where they
    // are, up to the f32 rounding of chunk-local positions in leaves
    // hundreds of kilometres wide (an ulp of 2^20 m is 6 cm).
    let (along, across, n) = curved_leaf_vertices_against_their_samples(&out, &dem, (-20.0, 50.0, cell));
    assert!(n > 10_000, "{n} vertices");
    assert!(along < 0.25 && across < 0.25, "{along} m along the normal, {across} m across");
    // verify measures every sample's distance along the normal to the
    // surface as drawn, and every morph target on the parent as drawn.
    let r = crate::common::verified_against(&out, &[dem]);
    assert!(r.curved);
    for (level, l) in &r.levels {
        assert!(l.max_error_m <= l.delta_m * (1.0 + 1e-6), "level {level}: {} m over δ {}", l.max_error_m, l.delta_m);
    }
}

#[test]
fn a_planar_tileset_claiming_the_curved_frame_fails_verify() {
    // 4° × 4° at 45° N: the flat frame misses by kilometres, so auto curves it.
    let tmp = tempfile::tempdir().unwrap();
    let dem = geographic_asc(tmp.path(), "region", (129, 129), (5.0, 43.0), 4.0 / 128.0);
    let (_t, out, _) = build_ok(&dem, 5.0);
    assert_eq!(tileset(&out)["extras"]["terrachunk"]["placement"]["frame"], "curved");
    crate::common::verified_against(&out, std::slice::from_ref(&dem));
    // The planar build of the same grid has the same root transform (a
    // geographic grid's is the ENU frame at its centre either way), so only
    // the samples' distances in ECEF can tell that its chunks are not
    // where the Earth is.
    let flat = tmp.path().join("flat");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", flat.to_str().unwrap(), "--max-error", "5", "--frame", "flat"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut ts = tileset(&flat);
    assert_eq!(ts["root"]["transform"], tileset(&out)["root"]["transform"]);
    ts["extras"]["terrachunk"]["placement"]["frame"] = "curved".into();
    std::fs::write(flat.join("tileset.json"), serde_json::to_vec(&ts).unwrap()).unwrap();
    let r = terrachunk::verify::verify(&flat, Some(&[dem])).unwrap();
    assert!(
        r.failures.iter().any(|f| f.contains("along the ellipsoid normal")),
        "a planar tileset passed as curved: {:?}",
        r.failures
    );
}

#[test]
fn a_small_grid_keeps_the_flat_frame_byte_for_byte() {
    // 1 × 1 km at 46° N: the tangent plane is within a few centimetres.
    let tmp = tempfile::tempdir().unwrap();
    let dem = geographic_asc(tmp.path(), "small", (101, 101), (7.0, 46.0), 1e-4);
    let (_t, auto, _) = build_ok(&dem, 1.0);
    let ts = tileset(&auto);
    assert!(ts["extras"]["terrachunk"]["placement"].get("frame").is_none(), "{}", ts["extras"]["terrachunk"]);
    let flat = tmp.path().join("flat");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", flat.to_str().unwrap(), "--max-error", "1", "--frame", "flat"]);
    assert!(o.status.success());
    for entry in walkdir(&auto) {
        let rel = entry.strip_prefix(&auto).unwrap();
        assert_eq!(std::fs::read(&entry).unwrap(), std::fs::read(flat.join(rel)).unwrap(), "{}", rel.display());
    }
}

fn walkdir(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() { out.extend(walkdir(&p)) } else { out.push(p) }
    }
    out.sort();
    out
}

#[test]
fn the_curved_frame_refuses_settings_it_cannot_keep() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = geographic_asc(tmp.path(), "region", (33, 33), (5.0, 43.0), 0.1);
    for extra in [["--compress", "quantize"], ["--mesher", "tin"]] {
        let out = tmp.path().join("out");
        let mut args = vec!["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--frame", "curved"];
        args.extend(extra);
        let o = cli(&args);
        assert_eq!(o.status.code(), Some(2), "{extra:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("frame") && err.contains("rtin") && err.contains("none"), "{err}");
        assert!(!out.exists());
    }
    // Without a CRS there is no Earth to curve onto.
    let bare = tmp.path().join("bare.asc");
    std::fs::copy(&dem, &bare).unwrap();
    let out = tmp.path().join("out");
    let o = cli(&["build", bare.to_str().unwrap(), "-o", out.to_str().unwrap(), "--frame", "curved"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("cannot be placed on the Earth"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!out.exists());
}

/// A projected GeoTIFF of `n` × `n` samples `step` apart with sample
/// (0, 0) on `xy`: hills 1–3 km high.
fn projected_hills_tif(path: &Path, epsg: u16, n: u32, step: f64, xy: [f64; 2]) {
    projected_tif(path, epsg, (n, step), (0.0, 0.0), xy, |i, j| {
        (2000.0 + 800.0 * (i * 0.09).sin() * (j * 0.05).cos() + 200.0 * ((i + 2.0 * j) * 0.4).sin()) as f32
    });
}

#[test]
fn an_antarctic_polar_stereographic_grid_is_curved_and_verified() {
    // EPSG:3031, 256 × 256 km around 81° S (1 000 km from the pole).
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("antarctic.tif");
    projected_hills_tif(&dem, 3031, 129, 2000.0, [-128_000.0, -872_000.0]);
    let (_t, out, report) = build_ok(&dem, 10.0);
    assert_eq!(report.frame, terrachunk::geodesy::FrameKind::Curved);
    let ts = tileset(&out);
    assert_eq!(ts["extras"]["terrachunk"]["placement"]["frame"], "curved");
    let r = crate::common::verified_against(&out, &[dem]);
    assert!(r.curved && r.levels.len() >= 2, "{:?}", r.levels.keys());
}

#[test]
fn a_one_kilometre_grid_at_89_9_degrees_north_keeps_the_flat_frame_within_its_error() {
    // EPSG:3413 (NSIDC polar stereographic north), 1 × 1 km, 11 km from the
    // pole: the tangent plane is within centimetres, so it stays flat.
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("arctic.tif");
    projected_hills_tif(&dem, 3413, 101, 10.0, [-500.0, -10_600.0]);
    let (_t, out, report) = build_ok(&dem, 1.0);
    assert_eq!(report.frame, terrachunk::geodesy::FrameKind::Flat);
    let p = &tileset(&out)["extras"]["terrachunk"]["placement"];
    let lat = p["lat_deg"].as_f64().unwrap();
    assert!((89.89..89.91).contains(&lat), "{p}");
    let e = &p["flat_frame_error"];
    assert!(e["vertical_m"].as_f64().unwrap().abs() < 0.05 && e["horizontal_m"].as_f64().unwrap() < 0.01, "{e}");
    crate::common::verified_against(&out, &[dem]);
}

#[test]
fn a_steep_regional_grid_morphs_onto_its_parents_in_the_curved_frame() {
    // 4° × 4° of sharp ridges and cliffs at 45° N: where a steep child
    // triangle's chord sags more than its flatter parent's, the parent must
    // split there too, or the child's morph target leaves the parent's
    // surface (as it once did, by up to δ of the parent).
    let tmp = tempfile::tempdir().unwrap();
    let (n, cell) = (257usize, 4.0 / 256.0);
    let dem = tmp.path().join("ridges.asc");
    let mut text = format!(
        "ncols {n}\nnrows {n}\nxllcorner {}\nyllcorner {}\ncellsize {cell}\n",
        5.0 - cell / 2.0,
        43.0 - cell / 2.0
    );
    for i in 0..n {
        let row: Vec<String> = (0..n)
            .map(|j| {
                let (x, z) = (j as f64, i as f64);
                let ridge = 2500.0 * ((x * 0.21).sin() * (z * 0.17).cos()).abs();
                let cliff = if (i * 7 + j * 3) % 23 < 4 { 600.0 } else { 0.0 };
                format!("{:.1}", ridge + cliff)
            })
            .collect();
        text += &row.join(" ");
        text += "\n";
    }
    std::fs::write(&dem, text).unwrap();
    std::fs::write(dem.with_extension("prj"), "+proj=longlat +datum=WGS84 +no_defs").unwrap();
    let (_t, out, report) = build_ok(&dem, 2.0);
    assert_eq!(report.frame, terrachunk::geodesy::FrameKind::Curved);
    let r = crate::common::verified_against(&out, &[dem]);
    assert!(r.levels.len() >= 3, "{:?}", r.levels.keys());
}
