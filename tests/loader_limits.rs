//! The loaders read only what a file declares and refuse what it cannot
//! hold: TIFF strips and tiles within their byte counts, PNG heightmaps and
//! PNG/JPEG textures within the decompression ratio TIFF and EXR have, text
//! grids streamed with the header checked first, 16-bit PNG textures
//! refused as the README says. Every file here is generated.

use std::path::{Path, PathBuf};

use terrachunk::dem::{LoadOptions, load};

use crate::common::{assert_bad_input, write_asc};

/// CRC-32 (ISO-HDLC, PNG's), bit by bit: a few chunks of test data.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A PNG whose header promises `w × h` pixels of `depth` bits and colour
/// type `colour`, `padding` bytes long in all (an ancillary chunk of
/// zeros): what a bomb looks like before it is decoded.
fn png_header_only(path: &Path, (w, h): (u32, u32), depth: u8, colour: u8, padding: usize) {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[depth, colour, 0, 0, 0]);
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(&mut out, b"paDd", &vec![0; padding]);
    png_chunk(&mut out, b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    png_chunk(&mut out, b"IEND", &[]);
    std::fs::write(path, out).unwrap();
}

/// A little-endian, uncompressed, one-strip 64 × 64 int16 TIFF whose
/// StripByteCounts says `declared` bytes; the strip holds 8 192, then the
/// file goes on with `tail` bytes of 0x7f (what a reader past the strip
/// would take for heights).
fn tiff_with_strip_count(path: &Path, declared: u32, tail: usize) -> PathBuf {
    let (w, h) = (64u32, 64u32);
    let entries: [(u16, u16, u32); 9] = [
        (256, 3, w),        // ImageWidth
        (257, 3, h),        // ImageLength
        (258, 3, 16),       // BitsPerSample
        (259, 3, 1),        // Compression: none
        (262, 3, 1),        // Photometric: BlackIsZero
        (273, 4, 0),        // StripOffsets (set below)
        (278, 3, h),        // RowsPerStrip
        (279, 4, declared), // StripByteCounts
        (339, 3, 2),        // SampleFormat: signed
    ];
    let ifd_len = 2 + 12 * entries.len() + 4;
    let data_at = (8 + ifd_len) as u32;
    let mut out = b"II*\0".to_vec();
    out.extend_from_slice(&8u32.to_le_bytes());
    out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, kind, value) in entries {
        let value = if tag == 273 { data_at } else { value };
        out.extend_from_slice(&tag.to_le_bytes());
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&1u32.to_le_bytes());
        if kind == 3 {
            out.extend_from_slice(&(value as u16).to_le_bytes());
            out.extend_from_slice(&[0, 0]);
        } else {
            out.extend_from_slice(&value.to_le_bytes());
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
    for k in 0..(w * h) as u16 {
        out.extend_from_slice(&(100 + (k % 50) as i16).to_le_bytes());
    }
    out.extend(std::iter::repeat_n(0x7f, tail));
    std::fs::write(path, out).unwrap();
    path.to_path_buf()
}

#[test]
fn a_tiff_strip_is_read_only_within_its_declared_byte_count() {
    let tmp = tempfile::tempdir().unwrap();
    // As declared: it loads, heights as written.
    let good = tiff_with_strip_count(&tmp.path().join("good.tif"), 8192, 0);
    let hf = load(&[good], &LoadOptions::default()).unwrap();
    assert_eq!((hf.width, hf.height, hf.heights[0], hf.heights[4095]), (64, 64, 100.0, 145.0));
    // StripByteCounts 100 of the 8 192 bytes the strip needs, with the
    // file long enough to read past it: refused, naming the file and strip.
    let short = tiff_with_strip_count(&tmp.path().join("short.tif"), 100, 8192);
    let e = load(&[short], &LoadOptions::default()).unwrap_err().to_string();
    assert!(
        e.contains("short.tif")
            && e.contains("strip 0 needs more than the 100 bytes its StripByteCounts entry declares"),
        "{e}"
    );
    let out = tmp.path().join("out");
    assert_bad_input(
        &["build", tmp.path().join("short.tif").to_str().unwrap(), "-o", out.to_str().unwrap()],
        &out,
        "strip 0",
    );
}

#[test]
fn a_png_promising_far_more_pixels_than_its_bytes_hold_is_refused_before_decoding() {
    let tmp = tempfile::tempdir().unwrap();
    let bomb = tmp.path().join("bomb.png");
    // 30 000² gray pixels (3.6 GB as heights) from 1.7 MB.
    png_header_only(&bomb, (30_000, 30_000), 8, 0, 1_700_000);
    let e = load(std::slice::from_ref(&bomb), &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("bomb.png") && e.contains("30000 × 30000") && e.contains("refused before decoding"), "{e}");
    let out = tmp.path().join("out");
    assert_bad_input(&["build", bomb.to_str().unwrap(), "-o", out.to_str().unwrap()], &out, "more than 1024 to 1");
    // As a texture over a small DEM, the same.
    let dem = write_asc(tmp.path(), "small.asc", 33, 33, |i, j| (i * j) as f64 / 10.0);
    let args = ["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", bomb.to_str().unwrap()];
    assert_bad_input(&args, &out, "more than 1024 to 1");
}

#[test]
fn a_sixteen_bit_png_texture_is_refused_as_the_readme_says() {
    let tmp = tempfile::tempdir().unwrap();
    let photo = tmp.path().join("photo16.png");
    let img = image::RgbImage::from_fn(16, 16, |x, y| image::Rgb([x as u8 * 16, y as u8 * 16, 99]));
    image::DynamicImage::ImageRgb8(img).into_rgb16().save(&photo).unwrap();
    let dem = write_asc(tmp.path(), "small.asc", 33, 33, |i, j| (i + j) as f64);
    let out = tmp.path().join("out");
    let args = ["build", dem.to_str().unwrap(), "-o", out.to_str().unwrap(), "--texture", photo.to_str().unwrap()];
    assert_bad_input(&args, &out, "16-bit PNG; a texture needs 8 bits per channel");
}

#[test]
fn an_asc_header_is_checked_before_its_body_is_read() {
    let tmp = tempfile::tempdir().unwrap();
    // A header promising 10⁹ values over a body of four: refused from the
    // header and the file's length, before a value is read.
    let p = tmp.path().join("liar.asc");
    std::fs::write(&p, "ncols 100000\nnrows 10000\ncellsize 1\n1 2\n3 4\n").unwrap();
    let e = load(&[p], &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("liar.asc") && e.contains("promises") && e.contains("1000000000 values"), "{e}");
    // A file with no whitespace in it is refused at its first long token,
    // not read whole into one line.
    let p = tmp.path().join("blob.asc");
    std::fs::write(&p, format!("ncols 2\nnrows 2\ncellsize 1\n{}", "7".repeat(1 << 20))).unwrap();
    let e = load(&[p], &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("blob.asc") && e.contains("line 4: a token longer than 64 bytes"), "{e}");
    // A `.prj` beside the grid that is a FIFO is passed over, not waited on.
    let dem = write_asc(tmp.path(), "fifo.asc", 3, 3, |i, j| (i + j) as f64);
    assert!(std::process::Command::new("mkfifo").arg(tmp.path().join("fifo.prj")).status().unwrap().success());
    let hf = load(&[dem], &LoadOptions::default()).unwrap();
    assert_eq!(hf.heights.len(), 9);
}

#[test]
fn a_dem_that_is_not_a_regular_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("dem.tif");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    for p in [fifo, PathBuf::from("/dev/zero")] {
        let e = load(std::slice::from_ref(&p), &LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains(&*p.to_string_lossy()) && e.contains("not a regular file"), "{e}");
    }
}
