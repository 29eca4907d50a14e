//! The baseline the nested hierarchy is measured against: one greedy TIN
//! over the whole grid at a given error, with no chunks, constraints or
//! dividing lines. Prints triangles, vertices, measured max error and time.
//!
//! `cargo run --release --example single_tin -- DEM MAX_ERROR_M`

use std::path::PathBuf;
use std::time::Instant;

use terrachunk::dem::{LoadOptions, load};
use terrachunk::heightfield::void_fill;
use terrachunk::mesh::decimate::{ChunkSpec, Grid, build_chunk};

fn main() {
    let args: Vec<String> = std::env::args().collect();
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
        "{} samples: {} triangles, {} vertices, max error {:.4} m (target {max_error} m), {secs:.2} s",
        hf.width * hf.height,
        tris,
        mesh.vertices.len(),
        mesh.max_error_m
    );
}
