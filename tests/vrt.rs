//! GDAL `.vrt` mosaics of GeoTIFF tiles: the Mount St Helens fixture cut
//! into overlapping tiles, as a tile server ships it, read back through a
//! VRT as `gdalbuildvrt` writes it.

use std::path::{Path, PathBuf};

use terrachunk::dem::{LoadOptions, load};
use terrachunk::store::Memory;

use crate::common::{all_files, assert_bad_input, build_ok, cli, fixture, verified_against};

/// Helens' placement (EPSG:26710, PixelIsPoint, 30 m).
const ORIGIN: [f64; 2] = [557_820.0, 5_121_990.0];
const STEP: f64 = 30.0;
const NODATA: f32 = -32767.0;

/// Writes rows `rows` and columns `cols` of `whole` (row-major, `width`
/// wide, NaN = nodata) as a float GeoTIFF placed where they lie, nodata
/// as `GDAL_NODATA` -32767; `shift` moves its tie point east, metres.
fn write_tile(path: &Path, whole: &[f32], width: usize, (rows, cols): ([usize; 2], [usize; 2]), shift: f64) {
    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;
    let (w, h) = (cols[1] - cols[0], rows[1] - rows[0]);
    let mut enc = TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(w as u32, h as u32).unwrap();
    let e = img.encoder();
    let x = ORIGIN[0] + cols[0] as f64 * STEP + shift;
    let y = ORIGIN[1] - rows[0] as f64 * STEP;
    e.write_tag(Tag::ModelPixelScaleTag, &[STEP, STEP, 0.0][..]).unwrap();
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, x, y, 0.0][..]).unwrap();
    let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, 26710];
    e.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    e.write_tag(Tag::GdalNodata, "-32767").unwrap();
    let data: Vec<f32> = (rows[0]..rows[1])
        .flat_map(|r| (cols[0]..cols[1]).map(move |c| (r, c)))
        .map(|(r, c)| whole[r * width + c])
        .map(|v| if v.is_nan() { NODATA } else { v })
        .collect();
    img.write_data(&data).unwrap();
}

/// A source as `gdalbuildvrt` writes it: a file relative to the VRT, drawn
/// at its place; `dst_size` other than the tile's own asks to resample.
struct Tile {
    file: String,
    rows: [usize; 2],
    cols: [usize; 2],
    dst_size: Option<[usize; 2]>,
}

fn write_vrt(path: &Path, (width, height): (usize, usize), tiles: &[Tile], bands: usize) {
    let mut s = format!("<VRTDataset rasterXSize=\"{width}\" rasterYSize=\"{height}\">\n");
    s += "  <SRS dataAxisToSRSAxisMapping=\"1,2\">PROJCS[\"NAD27 / UTM zone 10N\",AUTHORITY[\"EPSG\",\"26710\"]]</SRS>\n";
    s += &format!(
        "  <GeoTransform> {:e}, {:e}, 0.0, {:e}, 0.0, {:e}</GeoTransform>\n",
        ORIGIN[0] - STEP / 2.0,
        STEP,
        ORIGIN[1] + STEP / 2.0,
        -STEP
    );
    for band in 1..=bands {
        s +=
            &format!("  <VRTRasterBand dataType=\"Float32\" band=\"{band}\">\n    <NoDataValue>-32767</NoDataValue>\n");
        for t in tiles {
            let (w, h) = (t.cols[1] - t.cols[0], t.rows[1] - t.rows[0]);
            let [dw, dh] = t.dst_size.unwrap_or([w, h]);
            s += &format!(
                "    <ComplexSource>\n      <SourceFilename relativeToVRT=\"1\">{}</SourceFilename>\n      \
                 <SourceBand>1</SourceBand>\n      <SrcRect xOff=\"0\" yOff=\"0\" xSize=\"{w}\" ySize=\"{h}\" />\n      \
                 <DstRect xOff=\"{}\" yOff=\"{}\" xSize=\"{dw}\" ySize=\"{dh}\" />\n      <NODATA>-32767</NODATA>\n    \
                 </ComplexSource>\n",
                t.file, t.cols[0], t.rows[0]
            );
        }
        s += "  </VRTRasterBand>\n";
    }
    s += "</VRTDataset>\n";
    std::fs::write(path, s).unwrap();
}

/// Helens cut into four tiles that share their middle row and column.
fn cut_helens(dir: &Path, shift_last: f64) -> (PathBuf, Vec<Tile>) {
    let whole = load(&[fixture("mount_st_helens_30m.tif")], &LoadOptions::default()).unwrap();
    let (w, h) = (whole.width, whole.height);
    let (mr, mc) = (h / 2, w / 2);
    let mut tiles = Vec::new();
    for (k, (rows, cols)) in
        [([0, mr + 1], [0, mc + 1]), ([0, mr + 1], [mc, w]), ([mr, h], [0, mc + 1]), ([mr, h], [mc, w])]
            .into_iter()
            .enumerate()
    {
        let file = format!("helens_{k}.tif");
        let shift = if k == 3 { shift_last } else { 0.0 };
        write_tile(&dir.join(&file), &whole.heights, w, (rows, cols), shift);
        tiles.push(Tile { file, rows, cols, dst_size: None });
    }
    let vrt = dir.join("helens.vrt");
    write_vrt(&vrt, (w, h), &tiles, 1);
    (vrt, tiles)
}

#[test]
fn a_vrt_mosaic_of_tiles_is_the_grid_they_were_cut_from_and_builds_the_same_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let (vrt, _) = cut_helens(dir.path(), 0.0);
    let whole = load(&[fixture("mount_st_helens_30m.tif")], &LoadOptions::default()).unwrap();
    let mosaic = load(std::slice::from_ref(&vrt), &LoadOptions::default()).unwrap();
    assert_eq!((mosaic.width, mosaic.height), (whole.width, whole.height));
    let bits = |v: &[f32]| v.iter().map(|h| if h.is_nan() { u32::MAX } else { h.to_bits() }).collect::<Vec<_>>();
    assert!(bits(&mosaic.heights) == bits(&whole.heights), "every sample, nodata included, as in the whole file");
    assert_eq!(mosaic.georef.crs, whole.georef.crs);
    assert_eq!(mosaic.georef.origin, whole.georef.origin);
    assert_eq!(mosaic.georef.step, whole.georef.step);
    assert_eq!(mosaic.spacing_m, whole.spacing_m);
    // Past a memory limit's share, the mosaic and the single file are
    // decoded straight into scratch files, to the same samples.
    let memory = Memory::new(1 << 20, dir.path());
    let opts = LoadOptions { memory: Some(memory.clone()), ..LoadOptions::default() };
    for path in [vrt.clone(), fixture("mount_st_helens_30m.tif")] {
        let mapped = load(std::slice::from_ref(&path), &opts).unwrap();
        assert!(mapped.heights.is_mapped(), "{}", path.display());
        assert!(bits(&mapped.heights) == bits(&whole.heights), "{}: the same samples", path.display());
    }
    assert!(memory.mapped_bytes() >= 2 * 4 * (whole.width * whole.height) as u64);

    let (_a, from_tif, _) = build_ok(&fixture("mount_st_helens_30m.tif"), 8.0);
    let (_b, from_vrt, _) = build_ok(&vrt, 8.0);
    let tiles = |out: &Path| all_files(&out.join("tiles"));
    let (t, v) = (tiles(&from_tif), tiles(&from_vrt));
    assert!(!t.is_empty());
    assert_eq!(t.len(), v.len());
    for ((pt, bt), (pv, bv)) in t.iter().zip(&v) {
        assert_eq!(pt, pv);
        assert!(bt == bv, "{} differs between the GeoTIFF and its VRT mosaic", pt.display());
    }
    verified_against(&from_vrt, std::slice::from_ref(&vrt));
}

#[test]
fn a_vrt_with_a_missing_tile_leaves_its_ground_nodata() {
    let dir = tempfile::tempdir().unwrap();
    let (_, tiles) = cut_helens(dir.path(), 0.0);
    let whole = load(&[fixture("mount_st_helens_30m.tif")], &LoadOptions::default()).unwrap();
    let vrt = dir.path().join("three.vrt");
    write_vrt(&vrt, (whole.width, whole.height), &tiles[..3], 1);
    let mosaic = load(&[vrt], &LoadOptions::default()).unwrap();
    let last = &tiles[3];
    for i in 0..whole.height {
        for j in 0..whole.width {
            let (m, w) = (mosaic.get(i, j), whole.get(i, j));
            // The others share the last tile's first row and column.
            let covered = !(i > last.rows[0] && j > last.cols[0]);
            if covered {
                assert!(m.to_bits() == w.to_bits() || m.is_nan() && w.is_nan(), "({i}, {j})");
            } else {
                assert!(m.is_nan(), "({i}, {j}) no tile covers: nodata, the band's NoDataValue");
            }
        }
    }
}

#[test]
fn a_vrt_whose_tiles_do_not_line_up_or_resample_is_refused_naming_the_tile() {
    let dir = tempfile::tempdir().unwrap();
    let (vrt, mut tiles) = cut_helens(dir.path(), STEP);
    let out = dir.path().join("out");
    let args = |v: &Path| vec![String::from("build"), v.display().to_string(), "-o".into(), out.display().to_string()];
    let run = |v: &Path, says: &str| {
        let a = args(v);
        assert_bad_input(&a.iter().map(String::as_str).collect::<Vec<_>>(), &out, says);
    };
    run(&vrt, "helens_3.tif starts at (562740, 5114970) but the VRT draws it at (562710, 5114970)");

    let (vrt, _) = cut_helens(dir.path(), 0.0);
    tiles[1].dst_size = Some([10, 10]);
    let resampled = dir.path().join("resampled.vrt");
    write_vrt(&resampled, (327, 468), &tiles, 1);
    run(&resampled, "helens_1.tif: <SrcRect> 164 × 235 drawn into <DstRect> 10 × 10");

    tiles[1].dst_size = None;
    tiles[2].file = "gone.tif".into();
    let missing = dir.path().join("missing.vrt");
    write_vrt(&missing, (327, 468), &tiles, 1);
    run(&missing, "gone.tif");

    tiles[2].file = "N00E000.hgt".into();
    std::fs::copy(fixture("hgt_mosaic/N00E000.hgt"), dir.path().join("N00E000.hgt")).unwrap();
    let not_tiff = dir.path().join("hgt.vrt");
    write_vrt(&not_tiff, (327, 468), &tiles, 1);
    run(&not_tiff, "N00E000.hgt is not a GeoTIFF");

    let two = dir.path().join("two.vrt");
    write_vrt(&two, (327, 468), &tiles[..2], 2);
    run(&two, "2 bands; a DEM mosaic has one");

    let text = std::fs::read_to_string(&vrt).unwrap();
    let broken = dir.path().join("broken.vrt");
    std::fs::write(&broken, &text[..text.len() / 2]).unwrap();
    run(&broken, "not valid VRT XML");
    // The message names the VRT the user gave.
    let o = cli(&args(&broken).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(String::from_utf8_lossy(&o.stderr).contains("broken.vrt"));
}

#[test]
fn a_sharded_build_of_a_vrt_matches_the_single_build_and_refuses_a_changed_tile() {
    use terrachunk::config::Config;
    use terrachunk::pipeline::build;
    use terrachunk::shard;
    let dir = tempfile::tempdir().unwrap();
    let (vrt, tiles) = cut_helens(dir.path(), 0.0);
    let cfg = |out: &Path| {
        crate::common::with_config(&vrt, out, Config { max_error_m: 8.0, leaf_cells: Some(64), ..Config::default() })
    };
    let (single, merged) = (dir.path().join("single"), dir.path().join("merged"));
    build(&cfg(&single)).unwrap();
    let manifest = shard::plan(&cfg(&merged), 3, &dir.path().join("work")).unwrap();
    let jobs = shard::read_manifest(&manifest).unwrap().jobs.len();
    for job in 0..jobs {
        shard::run_job(&manifest, job, Some(1)).unwrap();
    }
    shard::merge(&manifest).unwrap();
    assert!(all_files(&single) == all_files(&merged), "sharded and single builds of a VRT differ");

    // A tile rewritten after a plan: the VRT is the same bytes, the input is not.
    let manifest = shard::plan(&cfg(&dir.path().join("again")), 3, &dir.path().join("work2")).unwrap();
    let whole = load(&[fixture("mount_st_helens_30m.tif")], &LoadOptions::default()).unwrap();
    let raised: Vec<f32> = whole.heights.iter().map(|h| h + 1.0).collect();
    let t = &tiles[2];
    write_tile(&dir.path().join(&t.file), &raised, whole.width, (t.rows, t.cols), 0.0);
    let o = cli(&["build", "--manifest", manifest.to_str().unwrap(), "--job", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("changed since the plan"), "{err}");
}

/// A VRT cut and flipped anywhere, or claiming a raster its tiles cannot
/// fill, is refused with a message: never a panic, never a huge allocation.
#[test]
fn a_mangled_or_inflated_vrt_is_refused_without_a_panic() {
    use crate::common::{Mangler, mangle_rounds};
    let dir = tempfile::tempdir().unwrap();
    let (vrt, tiles) = cut_helens(dir.path(), 0.0);
    let bytes = std::fs::read(&vrt).unwrap();
    let mut mangler = Mangler::new(0x9e37_79b9_7f4a_7c15);
    let p = dir.path().join("mangled.vrt");
    for k in 0..mangle_rounds() * 4 {
        std::fs::write(&p, mangler.mangle(&bytes, k)).unwrap();
        let _ = load(std::slice::from_ref(&p), &LoadOptions::default());
    }
    let huge = dir.path().join("huge.vrt");
    write_vrt(&huge, (40_000, 40_000), &tiles, 1);
    let err = load(&[huge], &LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("huge.vrt") && err.contains("refused before decoding"), "{err}");
}

/// Sources that draw parts of one file (`SrcRect` inside it) read just
/// those parts, and the mosaic is the file.
#[test]
fn sources_drawing_parts_of_one_file_give_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let whole = load(&[fixture("mount_st_helens_30m.tif")], &LoadOptions::default()).unwrap();
    let (w, h) = (whole.width, whole.height);
    std::fs::copy(fixture("mount_st_helens_30m.tif"), dir.path().join("helens.tif")).unwrap();
    let mut s = format!("<VRTDataset rasterXSize=\"{w}\" rasterYSize=\"{h}\">\n");
    s += &format!(
        "  <GeoTransform>{}, {STEP}, 0, {}, 0, -{STEP}</GeoTransform>\n  <VRTRasterBand dataType=\"Int16\" band=\"1\">\n    \
         <NoDataValue>-32767</NoDataValue>\n",
        ORIGIN[0] - STEP / 2.0,
        ORIGIN[1] + STEP / 2.0
    );
    for (x, y, sw, sh) in [(0, 0, 100, 300), (100, 0, w - 100, 300), (0, 300, w, h - 300)] {
        s += &format!(
            "    <SimpleSource><SourceFilename relativeToVRT=\"1\">helens.tif</SourceFilename><SourceBand>1</SourceBand>\
             <SrcRect xOff=\"{x}\" yOff=\"{y}\" xSize=\"{sw}\" ySize=\"{sh}\"/><DstRect xOff=\"{x}\" yOff=\"{y}\" \
             xSize=\"{sw}\" ySize=\"{sh}\"/></SimpleSource>\n"
        );
    }
    s += "  </VRTRasterBand>\n</VRTDataset>\n";
    let vrt = dir.path().join("parts.vrt");
    std::fs::write(&vrt, s).unwrap();
    let mosaic = load(&[vrt], &LoadOptions::default()).unwrap();
    let bits = |v: &[f32]| v.iter().map(|h| if h.is_nan() { u32::MAX } else { h.to_bits() }).collect::<Vec<_>>();
    assert!(bits(&mosaic.heights) == bits(&whole.heights));
    assert_eq!((mosaic.georef.origin, mosaic.spacing_m), (whole.georef.origin, whole.spacing_m));
}
