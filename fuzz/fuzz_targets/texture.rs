//! The texture image loader (`--texture`) on arbitrary bytes (see fuzz/README.md).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| terrachunk_fuzz::load_texture_bytes(data));
