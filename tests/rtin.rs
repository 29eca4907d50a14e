//! The right-triangle bintree mesher (`mesher = "rtin"`) end to end: real
//! fixtures and generated hard cases through `build`, `verify` and the
//! Khronos validator in every `--compress` mode, the same bytes at any
//! thread count, and every written triangle right-isosceles (aspect 2).

use std::path::Path;

use terrachunk::config::{Compress, Config, Mesher};
use terrachunk::pipeline::build;
use terrachunk::verify::read_chunk;

use crate::common::{all_files, cli, fixture, khronos_validate, verified, with_config, write_asc_spaced};

const MODES: [Compress; 4] = [Compress::None, Compress::Quantize, Compress::Meshopt, Compress::MeshoptV1];

fn rtin(max_error_m: f64, compress: Compress) -> Config {
    Config { max_error_m, compress, mesher: Mesher::Rtin, ..Config::default() }
}

/// Largest aspect (longest edge ÷ its height, in plan) over every written
/// surface triangle of every chunk.
fn largest_aspect(out: &Path) -> f64 {
    let mut worst: f64 = 0.0;
    for (path, _) in all_files(out).into_iter().filter(|(p, _)| p.extension().is_some_and(|e| e == "glb")) {
        let c = read_chunk(&out.join(path)).unwrap();
        for t in &c.surface.triangles {
            let [a, b, p] = t.map(|v| c.surface.positions[v as usize]);
            let cross = ((b[0] - a[0]) * (p[2] - a[2]) - (b[2] - a[2]) * (p[0] - a[0])).abs();
            let longest =
                [(a, b), (b, p), (p, a)].iter().map(|(u, v)| (v[0] - u[0]).hypot(v[2] - u[2])).fold(0.0, f64::max);
            worst = worst.max(longest * longest / cross);
        }
    }
    worst
}

#[test]
fn rtin_fixtures_verify_and_validate_in_every_compress_mode() {
    for (name, max_error_m) in [
        ("fuji_crop_terrainrgb.png", 1.0),
        ("west_bijou_gully_3m.asc", 0.25),
        ("salish_sea_topobathy_f32.tif", 5.0),
        ("kattegat_crop_u8.png", 0.5),
    ] {
        for compress in MODES {
            let tmp = tempfile::tempdir().unwrap();
            let out = tmp.path().join("out");
            build(&with_config(&fixture(name), &out, rtin(max_error_m, compress)))
                .unwrap_or_else(|e| panic!("{name} {compress:?}: {e}"));
            verified(&out);
            khronos_validate(&out);
            // Spacing may differ per axis; on the grid every triangle is
            // right-isosceles, so in metres the aspect is bounded by the
            // spacing ratio.
            let a = largest_aspect(&out);
            assert!(a < 12.0, "{name} {compress:?}: aspect {a}");
        }
    }
}

#[test]
fn rtin_builds_the_same_bytes_at_one_and_two_threads() {
    let dem = fixture("mount_st_helens_30m.tif");
    let tmp = tempfile::tempdir().unwrap();
    let runs: Vec<_> = [1, 2]
        .map(|threads| {
            let out = tmp.path().join(format!("t{threads}"));
            build(&with_config(&dem, &out, Config { threads, ..rtin(2.0, Compress::MeshoptV1) })).unwrap();
            all_files(&out)
        })
        .into();
    assert_eq!(runs[0].len(), runs[1].len());
    for ((pa, a), (pb, b)) in runs[0].iter().zip(&runs[1]) {
        assert_eq!(pa, pb);
        assert!(a == b, "{} differs between 1 and 2 threads", pa.display());
    }
}

/// Flat sea at one height with islands, a straight coast, a bay of tidal
/// flats and whole-metre terraces on a gentle slope, on a grid of no power
/// of two: what made the greedy TIN's slivers. Square cells give aspect 2.
#[test]
fn rtin_flat_coast_terraces_and_islands_verify_with_no_slivers() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = write_asc_spaced(tmp.path(), "coast.asc", 301, 173, 30.0, |i, j| {
        let (x, z) = (j as f64, i as f64);
        let island = ((x - 60.0).powi(2) + (z - 40.0).powi(2)).sqrt() < 9.0;
        if x < 120.0 && !island {
            0.0 // sea
        } else if island {
            (9.0 - ((x - 60.0).powi(2) + (z - 40.0).powi(2)).sqrt()).floor()
        } else if z > 100.0 && x < 200.0 {
            ((x - 120.0) / 27.0).floor().min(3.0) // tidal flats, 0–3 m
        } else {
            ((x - 120.0) * 0.07 + z * 0.02).floor() // terraces a metre apart
        }
    });
    for compress in MODES {
        for max_error_m in [0.5, 1.0, 5.0] {
            let out = tmp.path().join(format!("{compress:?}-{max_error_m}"));
            build(&with_config(&dem, &out, rtin(max_error_m, compress))).unwrap();
            verified(&out);
            let a = largest_aspect(&out);
            assert!(a <= 2.0 + 1e-6, "{compress:?} at {max_error_m} m: aspect {a}");
        }
    }
}

#[test]
fn mesher_is_a_setting_and_a_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let toml = tmp.path().join("p.toml");
    std::fs::write(&toml, "mesher = \"rtin\"\n").unwrap();
    assert_eq!(Config::from_file(&toml).unwrap().mesher, Mesher::Rtin);
    std::fs::write(&toml, "mesher = \"bintree\"\n").unwrap();
    let e = Config::from_file(&toml).unwrap_err().to_string();
    assert!(e.contains("p.toml"), "{e}");

    let out = tmp.path().join("out");
    let dem = fixture("kilauea_crop_i16.bt");
    let o = cli(&["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--mesher", "rtin"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    verified(&out);
    assert!(largest_aspect(&out) <= 2.0 + 1e-6);
}
