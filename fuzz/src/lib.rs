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
        heights: vec![100.0; 41 * 41].into(),
        spacing_m: [10.0, 10.0],
        georef: Georef {
            crs: Crs::Projected { epsg: Some(32610) },
            origin: [500_005.0, 4_999_995.0],
            step: [10.0, -10.0],
            local_tangent: None,
            definition: None,
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

/// A small tileset (a 17 × 17 grid of rolling ground, untextured, three
/// levels) built once per process in a scratch folder, with its DEM beside
/// it, and the bytes of each of its files: `tileset.json` first, then the
/// chunks in path order.
struct Template {
    dir: PathBuf,
    files: Vec<(PathBuf, Vec<u8>)>,
}

fn template() -> &'static Template {
    static TEMPLATE: std::sync::OnceLock<Template> = std::sync::OnceLock::new();
    TEMPLATE.get_or_init(|| {
        use terrachunk::config::Config;
        use terrachunk::pipeline::{BuildOptions, build};
        let root = scratch("tileset");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).expect("scratch folder");
        let dem = root.join("dem.asc");
        let mut text = String::from("ncols 17\nnrows 17\nxllcorner 0\nyllcorner 0\ncellsize 10\n");
        for i in 0..17 {
            let row: Vec<String> =
                (0..17).map(|j| format!("{:.2}", 100.0 + 20.0 * ((i * 7 + j * 3) as f64 / 9.0).sin())).collect();
            text += &(row.join(" ") + "\n");
        }
        std::fs::write(&dem, text).expect("write the DEM");
        let dir = root.join("out");
        let config = Config { max_error_m: 0.5, leaf_cells: Some(4), threads: 1, ..Config::default() };
        let options = BuildOptions {
            inputs: vec![dem],
            out: dir.clone(),
            force: false,
            config,
            texture: terrachunk::texture::TextureSource::None,
            progress: false,
            geoid: None,
        };
        build(&options).expect("the template tileset builds");
        let mut files = vec![PathBuf::from("tileset.json")];
        let mut stack = vec![dir.join("tiles")];
        let mut chunks = Vec::new();
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).expect("tiles folder") {
                let p = e.expect("entry").path();
                if p.is_dir() {
                    stack.push(p)
                } else {
                    chunks.push(p.strip_prefix(&dir).expect("inside").to_path_buf())
                }
            }
        }
        chunks.sort();
        files.extend(chunks);
        let files = files.into_iter().map(|f| (f.clone(), std::fs::read(dir.join(&f)).expect("read back"))).collect();
        Template { dir, files }
    })
}

/// Replaces files of the template tileset with parts of `data` and runs
/// `verify` on it, as a user would on a damaged or hostile tileset: any
/// input gives a report or an error, never a panic, a hang or a read
/// outside the tileset. `data` is a list of records, each a file index
/// byte (0: `tileset.json`, then the chunks, modulo their count), a
/// little-endian u16 length and that many bytes (cut short at the end).
/// No record leaves the tileset as built, which must verify clean.
pub fn verify_tileset_bytes(data: &[u8]) -> Option<terrachunk::verify::VerifyReport> {
    let t = template();
    let mut touched = vec![false; t.files.len()];
    let mut rest = data;
    let mut replaced: Vec<(usize, &[u8])> = Vec::new();
    while rest.len() >= 3 {
        let which = rest[0] as usize % t.files.len();
        let len = u16::from_le_bytes([rest[1], rest[2]]) as usize;
        let body = &rest[3..(3 + len).min(rest.len())];
        replaced.push((which, body));
        touched[which] = true;
        rest = &rest[3 + body.len()..];
    }
    for (i, (path, bytes)) in t.files.iter().enumerate() {
        let new = replaced.iter().rev().find(|(w, _)| *w == i).map_or(bytes.as_slice(), |(_, b)| b);
        std::fs::write(t.dir.join(path), new).expect("write a file of the tileset");
    }
    let result = terrachunk::verify::verify(&t.dir, None);
    if !touched.iter().any(|&x| x) {
        let report = result.as_ref().expect("the built tileset verifies");
        assert!(report.failures.is_empty(), "the built tileset fails: {:?}", report.failures);
    }
    result.ok()
}
