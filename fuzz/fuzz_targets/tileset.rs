//! `verify` on a tileset whose index and chunk files are replaced by
//! arbitrary bytes (see fuzz/README.md).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    terrachunk_fuzz::verify_tileset_bytes(data);
});
