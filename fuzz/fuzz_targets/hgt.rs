//! The SRTM .hgt loader on arbitrary bytes (see fuzz/README.md). A tile is
//! 2·n² bytes with no header, so the input is cut to the largest such length
//! (any other length is refused before a sample is read).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let n = ((data.len() / 2) as f64).sqrt() as usize;
    terrachunk_fuzz::load_bytes("N36W118.hgt", &data[..2 * n * n]);
});
