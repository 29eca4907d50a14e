//! terrachunk: a DEM in, a Chunked-LOD tileset out (Ulrich 2002; DESIGN.md).
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod dem;
pub mod heightfield;
