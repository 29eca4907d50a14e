//! `--memory-limit`: a grid past the limit's share goes through mapped
//! scratch files, and the tileset is the same bytes as an unlimited build's.

use std::path::Path;

use terrachunk::config::Config;
use terrachunk::pipeline::build;
use terrachunk::texture::TextureSource;

use crate::common::{all_files, assert_bad_input, verified_against, with_config};

/// A float GeoTIFF of `w` × `h` samples of rolling ground with ridges and a
/// few voids (GDAL_NODATA), 10 m apart in UTM zone 10N.
fn write_terrain(path: &Path, w: usize, h: usize) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(w as u32, h as u32).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[10.0, 10.0, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, 500_000.0, 5_100_000.0, 0.0][..]).unwrap();
    let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, 26710];
    e.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    e.write_tag(Tag::GdalNodata, "-32767").unwrap();
    let data: Vec<f32> = (0..h)
        .flat_map(|i| (0..w).map(move |j| (i as f64, j as f64)))
        .map(|(i, j)| {
            if (i - 300.0).powi(2) + (j - 700.0).powi(2) < 900.0 {
                return -32767.0; // a lake of nodata
            }
            let ridge = 40.0 * ((i * 0.013 + j * 0.021).sin() * (j * 0.007).cos()).abs();
            (300.0 + 80.0 * (i * 0.004).sin() + 60.0 * (j * 0.005).cos() + ridge + (i * j * 1e-4).sin()) as f32
        })
        .collect();
    img.write_data(&data).unwrap();
}

/// Built with a 16 MB limit, the 1.1 M-sample grid's heights, void fill,
/// error field and generated colour map (4.4, 4.4, 4.4 and 3.3 MB, each
/// past an eighth of the limit) live in scratch files; every file written
/// is byte for byte the unlimited build's, verify passes, and no scratch
/// file is left beside the output.
#[test]
fn a_grid_past_its_memory_limit_builds_through_scratch_files_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("terrain.tif");
    write_terrain(&dem, 1100, 1000);
    let run = |name: &str, limit: &str| {
        let out = tmp.path().join(name);
        let config = Config { max_error_m: 2.0, memory_limit: limit.into(), ..Config::default() };
        let mut opts = with_config(&dem, &out, config);
        opts.texture = TextureSource::Generated;
        (build(&opts).unwrap(), out)
    };
    let (free, free_out) = run("free", "none");
    let (held, held_out) = run("held", "16MB");
    assert_eq!(free.scratch_bytes, 0);
    assert_eq!(free.memory_limit_bytes, None);
    assert_eq!(held.memory_limit_bytes, Some(16_000_000));
    let grid = 1100 * 1000 * 4;
    assert!(held.scratch_bytes >= 3 * grid as u64 + 1100 * 1000 * 3, "{} bytes mapped", held.scratch_bytes);
    let (a, b) = (all_files(&free_out), all_files(&held_out));
    assert_eq!(a.len(), b.len());
    for ((pa, ba), (pb, bb)) in a.iter().zip(&b) {
        assert_eq!(pa, pb);
        assert!(ba == bb, "{} differs", pb.display());
    }
    verified_against(&held_out, std::slice::from_ref(&dem));
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(left.is_empty(), "left beside the output: {left:?}");
}

/// A limit that is no size, or too small for the process itself, is
/// refused before anything is read.
#[test]
fn a_memory_limit_that_is_no_size_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let out_s = out.to_str().unwrap();
    let dem = crate::common::fixture("mount_st_helens_30m.tif");
    let dem = dem.to_str().unwrap();
    assert_bad_input(&["build", dem, "-o", out_s, "--memory-limit", "12 parsecs"], &out, "memory_limit");
    assert_bad_input(&["build", dem, "-o", out_s, "--memory-limit", "1MB"], &out, "at least 16MB");
}
