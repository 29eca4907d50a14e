//! What every fuzz target does: write the input where the loader reads
//! (a file named like the format, so dispatch by magic bytes and by
//! extension both run), load it, and check that a success keeps every
//! promise `dem::load` makes. A panic, an abort or an allocation beyond
//! libFuzzer's limit is a finding; an `Err` is the right answer to junk.

use std::path::PathBuf;

use terrachunk::dem::{LoadOptions, load};
use terrachunk::heightfield::void_fill;

/// A per-process scratch file named `name` (one directory per process, so
/// parallel fuzzing jobs do not share it), in memory where Linux offers it:
/// on a disk-backed /tmp the write costs 30 times the load.
fn scratch(name: &str) -> PathBuf {
    let shm = std::path::Path::new("/dev/shm");
    let base = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
    let dir = base.join(format!("terrachunk-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

/// Loads `data` as a file called `name` and checks the result.
pub fn load_bytes(name: &str, data: &[u8]) {
    let path = scratch(name);
    std::fs::write(&path, data).expect("write the input");
    let Ok(hf) = load(std::slice::from_ref(&path), &LoadOptions::default()) else {
        return;
    };
    // What `dem::load` promises every later stage.
    assert!(hf.width >= 2 && hf.height >= 2, "{} × {} grid", hf.width, hf.height);
    assert_eq!(hf.heights.len(), hf.width * hf.height);
    assert!(hf.spacing_m.iter().all(|s| s.is_finite() && *s > 0.0), "spacing {:?}", hf.spacing_m);
    assert!(hf.heights.iter().all(|h| !h.is_infinite()), "an infinite height");
    assert!(hf.heights.iter().any(|h| !h.is_nan()), "no valid sample");
    // The first thing the pipeline does with it.
    if hf.heights.len() <= 1 << 20
        && let Some(filled) = void_fill(&hf)
    {
        assert!(filled.iter().all(|h| h.is_finite()), "void fill left a non-finite height");
    }
}

/// Loads `data` as a texture image (`--texture`: PNG, JPEG or 8-bit
/// GeoTIFF, told apart by their first bytes) over a 41 × 41 DEM of 10 m
/// samples in UTM zone 10N, so a georeferenced image is placed by its
/// keys, and checks the result.
pub fn load_texture_bytes(data: &[u8]) {
    use terrachunk::heightfield::{Crs, Georef, Heightfield};
    let path = scratch("photo.img");
    std::fs::write(&path, data).expect("write the input");
    let hf = Heightfield {
        width: 41,
        height: 41,
        heights: vec![100.0; 41 * 41],
        spacing_m: [10.0, 10.0],
        georef: Georef {
            crs: Crs::Projected { epsg: Some(32610) },
            origin: [500_005.0, 4_999_995.0],
            step: [10.0, -10.0],
            local_tangent: None,
        },
        source: "dem.tif".into(),
    };
    let Ok(source) = terrachunk::texture::source::load_image(&path, &hf) else {
        return;
    };
    // What the texture stage relies on.
    assert!(source.width > 0 && source.height > 0, "{} × {} image", source.width, source.height);
    assert_eq!(source.rgb.len(), source.width * source.height * 3);
    let finite = source.to_px.iter().all(|(a, b)| a.is_finite() && b.is_finite() && *b != 0.0);
    assert!(finite, "DEM-to-pixel map {:?}", source.to_px);
    assert!(source.texel_m.iter().all(|t| t.is_finite() && *t > 0.0), "texel size {:?}", source.texel_m);
}

/// Reads `data` as a chunk file (`.glb`, plain or compressed) as `verify`,
/// `inspect` and the viewer's decoder do, and checks what `verify` relies
/// on when it succeeds.
pub fn read_chunk_bytes(data: &[u8]) {
    let Ok(chunk) = terrachunk::verify::parse_chunk(std::path::Path::new("fuzz.glb"), data) else {
        return;
    };
    for prim in std::iter::once(&chunk.surface).chain(chunk.skirt.as_ref()) {
        let n = prim.positions.len();
        assert_eq!(prim.morph_dy.len(), n, "a morph delta per vertex");
        assert!(prim.triangles.iter().flatten().all(|&i| (i as usize) < n), "an index past {n} vertices");
        assert!(prim.uv.is_empty() || prim.uv.len() == n, "{} texture coordinates for {n} vertices", prim.uv.len());
    }
}
