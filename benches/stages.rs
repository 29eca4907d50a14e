//! Micro-benchmarks of the hot stages, on a real fixture (Mount St Helens,
//! USGS 30 m, 327 × 468): load, one chunk's greedy insertion at several
//! window sizes, the error measurement of a chunk, and its .glb encoding.
//!
//! `cargo bench --bench stages` (criterion; `-- greedy` runs one group).
//! Chunks are built as the pipeline builds a top-level chunk: no parent,
//! dividing lines on, u16 vertex limit.

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use terrachunk::bench::measure::{Window, scan};
use terrachunk::config::NormalEncoding;
use terrachunk::config::VertexCache;
use terrachunk::dem::{LoadOptions, load};
use terrachunk::heightfield::Heightfield;
use terrachunk::mesh::ChunkMesh;
use terrachunk::mesh::decimate::{ChunkSpec, DividingLines, build_chunk};
use terrachunk::mesh::grid::Grid;
use terrachunk::output::gltf::{GlbContext, encode_glb};
use terrachunk::pipeline::assemble;
use terrachunk::quadtree::ChunkKey;

/// Error bound of the benchmarked chunks, metres.
const DELTA_M: f64 = 2.0;
/// Window sides, samples.
const SIZES: [u32; 3] = [65, 129, 257];

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/mount_st_helens_30m.tif")
}

fn grid(hf: &Heightfield) -> Grid<'_> {
    Grid::new(hf.width, hf.height, &hf.heights, None)
}

/// The centred `n × n` window, closed.
fn window(hf: &Heightfield, n: u32) -> ((u32, u32), (u32, u32)) {
    let x0 = (hf.width as u32 - n) / 2;
    let z0 = (hf.height as u32 - n) / 2;
    ((x0, x0 + n - 1), (z0, z0 + n - 1))
}

fn chunk(hf: &Heightfield, n: u32) -> ChunkMesh {
    let spec = ChunkSpec {
        key: ChunkKey { level: 0, x: 0, y: 0 },
        footprint: window(hf, n),
        delta_m: DELTA_M,
        parent: None,
        keep_parent_edges: true,
        max_vertices: terrachunk::config::MAX_CHUNK_VERTICES as usize,
        dividing_lines: DividingLines::Children,
        split_insertion: false,
        cancel: None,
        cut_share: terrachunk::mesh::decimate::CUT_SHARE,
        cut_lattice: None,
        height_step: None,
        thin: false,
    };
    build_chunk(&grid(hf), &spec).expect("the fixture meshes")
}

fn stages(c: &mut Criterion) {
    let path = fixture();
    let hf = load(std::slice::from_ref(&path), &LoadOptions::default()).expect("fixture loads");

    let mut g = c.benchmark_group("load");
    g.throughput(Throughput::Elements((hf.width * hf.height) as u64));
    g.bench_function("geotiff_u16_327x468", |b| {
        b.iter(|| load(black_box(std::slice::from_ref(&path)), &LoadOptions::default()).unwrap())
    });
    g.finish();

    let mut g = c.benchmark_group("greedy_insertion");
    for n in SIZES {
        g.throughput(Throughput::Elements(u64::from(n) * u64::from(n)));
        g.bench_with_input(BenchmarkId::from_parameter(format!("{n}x{n}")), &n, |b, &n| {
            b.iter(|| chunk(black_box(&hf), n))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("measure_error");
    for n in SIZES {
        let mesh = chunk(&hf, n);
        let ((x0, x1), (z0, z1)) = mesh.footprint;
        let w = Window { x0, x1, z0, z1 };
        g.throughput(Throughput::Elements(u64::from(n) * u64::from(n)));
        g.bench_with_input(BenchmarkId::from_parameter(format!("{n}x{n}")), &mesh, |b, mesh| {
            b.iter(|| scan(black_box(&hf), &mesh.vertices, &mesh.triangles, w, w))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("glb_encode");
    let ctx = GlbContext {
        spacing_m: hf.spacing_m,
        generator: "bench",
        vertex_cache: VertexCache::Fast,
        quantization: None,
        meshopt: None,
        normals: NormalEncoding::Rounded,
    };
    for n in SIZES {
        let part = assemble(&grid(&hf), hf.spacing_m, &chunk(&hf, n), 4.0 * DELTA_M, None, false);
        g.throughput(Throughput::Elements(part.surface.triangle_count() as u64));
        g.bench_with_input(BenchmarkId::from_parameter(format!("{n}x{n}")), &part, |b, part| {
            b.iter(|| encode_glb(black_box(part), None, &ctx).expect("f32 output"))
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = stages
}
criterion_main!(benches);
