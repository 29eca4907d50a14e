//! `terrachunk bench`: the command on a tiny fixture (CSV, PNG, SVG, peers,
//! scaling), and the error checker on meshes whose error is known exactly.
//! No timing is asserted anywhere: only counts, structure and errors.

use std::path::{Path, PathBuf};
use std::process::Command;

use terrachunk::bench::measure::{mesh_errors, read_obj};
use terrachunk::bench::{grid, table};
use terrachunk::heightfield::Heightfield;
use terrachunk::mesh::MeshVertex;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

fn terrachunk(args: &[&str]) -> std::process::Output {
    let o = Command::new(env!("CARGO_BIN_EXE_terrachunk")).args(args).output().unwrap();
    assert!(o.status.success(), "terrachunk {args:?} failed: {}", String::from_utf8_lossy(&o.stderr));
    o
}

fn csv_lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path).unwrap().lines().map(str::to_string).collect()
}

fn vertex(x: f64, z: f64, h: f64) -> MeshVertex {
    MeshVertex { x, z, h, ph: h }
}

fn grid_of(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Heightfield {
    let heights: Vec<f32> = (0..h).flat_map(|i| (0..w).map(move |j| (i, j))).map(|(i, j)| f(i, j)).collect();
    Heightfield::ungeoreferenced(w, h, heights, "test".into())
}

/// Two triangles per cell over every sample, with the sample heights.
fn full_mesh(hf: &Heightfield) -> (Vec<MeshVertex>, Vec<[u32; 3]>) {
    let verts = (0..hf.height)
        .flat_map(|i| (0..hf.width).map(move |j| (i, j)))
        .map(|(i, j)| vertex(j as f64, i as f64, f64::from(hf.get(i, j))))
        .collect();
    let at = |i: usize, j: usize| (i * hf.width + j) as u32;
    let mut tris = Vec::new();
    for i in 0..hf.height - 1 {
        for j in 0..hf.width - 1 {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (verts, tris)
}

#[test]
fn a_mesh_with_every_sample_as_a_vertex_has_no_error() {
    let hf = grid_of(7, 5, |i, j| ((i * 31 + j * 17) % 11) as f32 * 123.456 - 300.0);
    let (verts, tris) = full_mesh(&hf);
    let e = mesh_errors(&hf, &verts, &tris);
    assert_eq!(e.max_error_m, 0.0);
    assert_eq!(e.rms_error_m, 0.0);
    assert_eq!(e.samples, 35);
    assert_eq!(e.uncovered_samples, 0);
}

#[test]
fn a_one_metre_bump_under_two_flat_triangles() {
    // 3 × 3 grid, all 0 but the centre at 1 m; the mesh is the four corners.
    let hf = grid_of(3, 3, |i, j| if (i, j) == (1, 1) { 1.0 } else { 0.0 });
    let verts = vec![vertex(0.0, 0.0, 0.0), vertex(2.0, 0.0, 0.0), vertex(0.0, 2.0, 0.0), vertex(2.0, 2.0, 0.0)];
    let tris = vec![[0, 2, 3], [0, 3, 1]];
    let e = mesh_errors(&hf, &verts, &tris);
    assert_eq!(e.max_error_m, 1.0);
    assert!((e.rms_error_m - (1.0f64 / 9.0).sqrt()).abs() < 1e-12, "{}", e.rms_error_m);
    assert_eq!((e.samples, e.uncovered_samples), (9, 0));
    // Half the grid left out: its three samples off the diagonal are uncovered.
    let e = mesh_errors(&hf, &verts, &tris[..1]);
    assert_eq!((e.samples, e.uncovered_samples, e.max_error_m), (6, 3, 1.0));
}

#[test]
fn measure_mesh_reads_an_obj_against_a_dem_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("bump.asc");
    std::fs::write(
        &dem,
        "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n0 0 0\n0 1 0\n0 0 0\n",
    )
    .unwrap();
    let obj = tmp.path().join("flat.obj");
    std::fs::write(&obj, "# column height row\nv 0 0 0\nv 2 0 0\nv 0 0 2\nv 2 0 2\nf 1 3 4 2\n").unwrap();
    let (verts, tris) = read_obj(&obj).unwrap();
    assert_eq!((verts.len(), tris.len()), (4, 2));
    let o = terrachunk(&["bench", dem.to_str().unwrap(), "--measure-mesh", obj.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["max_error_m"], 1.0);
    assert_eq!(v["triangles"], 2);
    assert_eq!(v["uncovered_samples"], 0);
    // A face naming a vertex that does not exist is refused, naming the file.
    std::fs::write(&obj, "v 0 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_terrachunk"))
        .args(["bench", dem.to_str().unwrap(), "--measure-mesh", obj.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("flat.obj"));
}

#[test]
fn square_crops_or_pads_and_npy_holds_the_same_heights() {
    let hf = grid_of(4, 3, |i, j| (i * 10 + j) as f32);
    let (sq, change) = grid::square(&hf, 5);
    assert_eq!((change.columns, change.rows), (-1, -2));
    assert_eq!(sq.get(4, 4), hf.get(2, 3), "last row and column repeated");
    assert_eq!(sq.get(1, 2), hf.get(1, 2));
    let (sq, change) = grid::square(&hf, 2);
    assert_eq!((change.columns, change.rows), (2, 1));
    assert_eq!(sq.heights, vec![0.0, 1.0, 10.0, 11.0]);

    let tmp = tempfile::tempdir().unwrap();
    let npy = tmp.path().join("g.npy");
    grid::write_npy(&hf, &npy).unwrap();
    let bytes = std::fs::read(&npy).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!((10 + hlen) % 64, 0, "header padded to 64 bytes");
    let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
    assert!(header.contains("'shape': (3, 4)") && header.contains("'<f4'"), "{header}");
    let data: Vec<f32> =
        bytes[10 + hlen..].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    assert_eq!(data, hf.heights);
}

#[test]
fn bench_writes_csv_png_svg_and_takes_peer_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bench");
    let dem = fixture("fuji_crop_terrainrgb.png");
    let (d, o) = (dem.to_str().unwrap(), out.to_str().unwrap());
    terrachunk(&["bench", d, "--errors", "2,5", "--runs", "1", "--warmup", "0", "--single-tin", "-o", o]);

    let lines = csv_lines(&out.join("bench.csv"));
    assert_eq!(lines[0], table::COLUMNS.join(","));
    assert_eq!(lines.len(), 1 + 2 * 2, "2 errors × (pipeline + single TIN):\n{}", lines.join("\n"));
    let rows = table::read(&out.join("bench.csv")).unwrap();
    for r in &rows {
        assert_eq!((r.width, r.height, r.samples), (64, 48, 64 * 48));
        let measured = r.measured_max_error_m.unwrap();
        assert!(measured > 0.0 && measured <= r.max_error_m, "{}: measured {measured} m", r.tool);
        assert_eq!(r.uncovered_samples, Some(0));
        assert!(r.leaf_triangles.unwrap() <= r.triangles.unwrap());
        assert!(r.total_seconds().is_some() && r.runs == 1);
    }
    let pipeline: Vec<_> = rows.iter().filter(|r| r.tool == "terrachunk").collect();
    assert_eq!(pipeline.len(), 2);
    assert!(pipeline.iter().all(|r| r.bytes.unwrap() > 0 && r.peak_rss_bytes.is_some() && r.seconds[0].is_some()));
    let leftovers: Vec<_> = std::fs::read_dir(&out).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(leftovers.len(), 3, "only bench.csv/png/svg remain: {leftovers:?}");
    check_plots(&out);

    // A peer's mesh: every sample of the grid as a vertex, so error 0.
    let hf = terrachunk::dem::load(std::slice::from_ref(&dem), &Default::default()).unwrap();
    let (verts, tris) = full_mesh(&hf);
    let mut obj = String::new();
    for v in &verts {
        obj += &format!("v {} {} {}\n", v.x, v.h, v.z);
    }
    for t in &tris {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(tmp.path().join("full.obj"), obj).unwrap();
    let manifest = tmp.path().join("manifest.csv");
    std::fs::write(&manifest, "tool,max_error_m,seconds,runs,mesh\nfull-grid,0.5,0.01,3,full.obj\n").unwrap();
    terrachunk(&["bench", d, "--peers", manifest.to_str().unwrap(), "-o", o]);
    let rows = table::read(&out.join("bench.csv")).unwrap();
    assert_eq!(rows.len(), 5);
    let peer = rows.last().unwrap();
    assert_eq!(peer.tool, "full-grid");
    assert_eq!(peer.measured_max_error_m, Some(0.0));
    assert_eq!(peer.triangles, Some(2 * 63 * 47));
    assert_eq!((peer.runs, peer.total_seconds()), (3, Some(0.01)));
    check_plots(&out);
}

fn check_plots(out: &Path) {
    let png = image::open(out.join("bench.png")).expect("bench.png decodes");
    assert!(png.width() > 400 && png.height() > 200);
    let svg = std::fs::read_to_string(out.join("bench.svg")).unwrap();
    let doc = roxmltree::Document::parse(&svg).expect("bench.svg is XML");
    assert_eq!(doc.root_element().tag_name().name(), "svg");
    let lines = doc.descendants().filter(|n| n.has_tag_name("polyline")).count();
    assert!(lines >= 2, "one line per (tool, DEM) in each panel, found {lines}");
    assert!(svg.contains("max_error_m"), "axis labels are drawn");
}

#[test]
fn scaling_runs_each_window_and_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("scale");
    let dem = fixture("fuji_crop_terrainrgb.png");
    let o = terrachunk(&[
        "bench",
        dem.to_str().unwrap(),
        "--scale",
        "4,1",
        "--errors",
        "5",
        "--threads",
        "1,2",
        "--runs",
        "1",
        "--warmup",
        "0",
        "-o",
        out.to_str().unwrap(),
    ]);
    let lines = csv_lines(&out.join("scaling.csv"));
    assert_eq!(lines.len(), 1 + 2 * 2, "{}", lines.join("\n"));
    assert!(lines[1].starts_with("fuji_crop_terrainrgb.png 1/4 32x24,1/4,32,24,768,5,1,"), "{}", lines[1]);
    assert!(lines[4].starts_with("fuji_crop_terrainrgb.png,1/1,64,48,3072,5,2,"), "{}", lines[4]);
    let peak = lines[1].split(',').nth(19).unwrap();
    assert!(peak.parse::<u64>().unwrap() > 0, "peak RSS of the child build");
    assert!(String::from_utf8_lossy(&o.stdout).contains("µs/sample"));
}

/// Flat ground ends shallow. Half a grid flat, half
/// hills: the error-bounded tree stops over the flat half, the complete tree
/// (every chunk to the deepest level) does not, and both verify.
#[test]
fn savings_compares_the_bounded_tree_with_a_complete_one() {
    use crate::common::{verified, with_config, write_asc};
    use terrachunk::config::Config;
    let tmp = tempfile::tempdir().unwrap();
    let hills = |i: usize, j: usize| {
        if j <= 64 { 100.0 } else { 100.0 + 40.0 * ((i as f64 / 7.0).sin() * (j as f64 / 5.0).cos()) }
    };
    let dem = write_asc(tmp.path(), "half_flat.asc", 129, 129, hills);
    let cfg = Config { max_error_m: 0.5, leaf_cells: Some(16), complete_tree: true, ..Config::default() };
    let out = tmp.path().join("complete");
    let complete = terrachunk::pipeline::build(&with_config(&dem, &out, cfg)).unwrap();
    verified(&out);
    let bench = tmp.path().join("savings");
    let o = terrachunk(&[
        "bench",
        dem.to_str().unwrap(),
        "--savings",
        "--errors",
        "0.5",
        "--config",
        write_config(tmp.path(), "leaf_cells = 16\n").to_str().unwrap(),
        "-o",
        bench.to_str().unwrap(),
    ]);
    let lines = csv_lines(&bench.join("savings.csv"));
    assert_eq!(lines.len(), 2, "{}", lines.join("\n"));
    let f: Vec<&str> = lines[1].split(',').collect();
    let n = |k: usize| f[k].parse::<u64>().unwrap();
    // dem, samples, valid, error, levels, complete levels, chunks, complete
    // chunks, triangles, complete triangles, ...
    assert_eq!((n(1), n(2)), (129 * 129, 129 * 129));
    assert_eq!(n(4), n(5), "the hills reach the deepest level");
    let complete_chunks: usize = complete.levels.iter().map(|l| l.chunks).sum();
    assert_eq!(n(7) as usize, complete_chunks, "the same complete tree as the library builds");
    assert!(n(6) * 4 < n(7) * 3, "the flat half ends shallow: {} of {} chunks", n(6), n(7));
    assert!(n(8) < n(9), "fewer triangles: {} of {}", n(8), n(9));
    assert!(String::from_utf8_lossy(&o.stdout).contains("| half_flat.asc |"));
}

fn write_config(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("settings.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// A curved tileset is measured as `verify` measures it, along the
/// ellipsoid normal from each sample's true place: within δ, where reading
/// its Earth-placed positions as grid metres found tens of metres.
#[test]
fn a_curved_tileset_is_measured_along_the_ellipsoid_normal() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("dfw_texas_srtm3.tif");
    let out = tmp.path().join("out");
    terrachunk(&[
        "build",
        dem.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--frame",
        "curved",
        "--texture",
        "none",
    ]);
    let hf = terrachunk::dem::load(&[dem], &terrachunk::dem::LoadOptions::default()).unwrap();
    let m = terrachunk::bench::measure::leaf_errors(&out, &hf).unwrap();
    assert!(m.errors.samples > 0 && m.errors.uncovered_samples == 0, "{:?}", m.errors);
    assert!(m.errors.max_error_m <= 1.0 + 1e-3, "measured {} m at δ 1 m", m.errors.max_error_m);
    assert!(m.errors.max_error_m > 0.1, "measured nothing: {} m", m.errors.max_error_m);
}
