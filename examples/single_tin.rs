//! The baseline the nested hierarchy is measured against: one greedy TIN
//! over the whole grid at a given error, with no chunks, constraints or
//! dividing lines. Prints triangles, vertices, measured max error and time.
//!
//! `cargo run --release --example single_tin -- DEM MAX_ERROR_M [--meshopt]`
//!
//! `--meshopt` also prints what that one mesh costs through meshoptimizer's
//! codecs (KHR_meshopt_compression, vertex codec v1 at level 3, as
//! `--compress meshopt-v1` writes): u16 grid positions with heights on the
//! power-of-two step `meshopt-v1` uses (at most `MAX_ERROR_M`/16) and on whole
//! metres, and the triangles in strip order. No normals, morph deltas,
//! skirts, coarser levels or JSON: the least any meshopt tileset whose finest
//! level is a TIN to that error must write, per input sample.

use std::path::PathBuf;
use std::time::Instant;

use terrachunk::dem::{LoadOptions, load};
use terrachunk::heightfield::void_fill;
use terrachunk::mesh::decimate::{ChunkSpec, build_chunk};
use terrachunk::mesh::grid::Grid;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let with_meshopt = args.iter().any(|a| a == "--meshopt");
    let dem = PathBuf::from(&args[1]);
    let max_error: f64 = args[2].parse().expect("MAX_ERROR_M");
    let hf = load(&[dem], &LoadOptions::default()).expect("loads");
    let filled = void_fill(&hf);
    let grid = Grid::new(hf.width, hf.height, &hf.heights, filled.as_deref());
    let t = Instant::now();
    let spec = ChunkSpec::unconstrained(((0, hf.width as u32 - 1), (0, hf.height as u32 - 1)), max_error);
    let mesh = build_chunk(&grid, &spec).expect("meshes");
    let secs = t.elapsed().as_secs_f64();
    let tris = mesh.kept.iter().filter(|k| **k).count();
    println!(
        "{} samples: {} triangles, {} vertices, max error {:.4} m (target {max_error} m), {secs:.4} s",
        hf.width * hf.height,
        tris,
        mesh.vertices.len(),
        mesh.max_error_m
    );
    if with_meshopt {
        let samples = (hf.width * hf.height) as f64;
        let triangles: Vec<u32> =
            mesh.triangles.iter().zip(&mesh.kept).filter(|(_, k)| **k).flat_map(|(t, _)| *t).collect();
        let n = mesh.vertices.len();
        let strip = meshopt::optimize_vertex_cache_strip(&triangles, n);
        let mut ordered = strip.clone();
        let remap = meshopt::optimize_vertex_fetch_remap(&ordered, n);
        for i in &mut ordered {
            *i = remap[*i as usize];
        }
        let indices = meshopt::encode_index_buffer(&ordered, n).expect("a triangle list");
        let low = mesh.vertices.iter().map(|v| v.h).fold(f64::INFINITY, f64::min);
        let fine = 2f64.powi((max_error / 16.0).log2().floor() as i32);
        for (name, step) in [("step max_error/16", fine), ("whole metres", 1.0)] {
            // x, z, then the height in steps as two u16 halves (a whole
            // grid's relief may pass 65 535 steps; the codec, working byte
            // by byte, pays little for a high half that rarely changes).
            let mut placed = vec![[0u16; 4]; n];
            for (old, v) in mesh.vertices.iter().enumerate() {
                let h = ((v.h - low) / step).round() as u32;
                placed[remap[old] as usize] = [v.x as u16, v.z as u16, h as u16, (h >> 16) as u16];
            }
            let positions = meshopt::encode_vertex_buffer_level(&placed, 3, Some(1)).expect("vertex encoding");
            let total = (indices.len() + positions.len()) as f64;
            println!(
                "meshopt-v1, heights on {name} ({step} m): positions {} B, triangles {} B: {:.3} bytes per sample, {:.3} per vertex",
                positions.len(),
                indices.len(),
                total / samples,
                total / n as f64
            );
        }
    }
}
