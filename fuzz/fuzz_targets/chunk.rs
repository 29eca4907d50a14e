//! The chunk reader (`verify`, `inspect`, the viewer's decoder) on arbitrary
//! bytes: plain and compressed .glb (see fuzz/README.md).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| terrachunk_fuzz::read_chunk_bytes(data));
