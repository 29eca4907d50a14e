//! terrachunk: a DEM in, a Chunked-LOD tileset out (Ulrich 2002; DESIGN.md).
//!
//! The stages, in the order [`pipeline::build`] calls them: [`dem`] (load) →
//! [`quadtree`] (plan) → [`mesh`] (decimate, skirt) → [`morph`] →
//! [`texture`] → [`output`] (glTF chunks, 3D Tiles index); [`lod`] is what
//! a client runs per frame (chunk selection, morph weights); [`verify`]
//! re-checks a written tileset from its files alone; [`mod@bench`] measures speed
//! against error, beside other tools; [`shard`] splits one build into
//! independent jobs for a distributed engine; [`store`] keeps whole-grid
//! arrays in memory or, past a memory limit, in mapped scratch files (the
//! one module with `unsafe`, for the mapping).
#![deny(unsafe_code)]
#![deny(missing_docs)]

pub mod bench;
pub mod chunk;
pub mod config;
pub mod dem;
pub mod geodesy;
pub mod geoid;
pub mod heightfield;
pub mod lod;
pub mod mesh;
pub mod output;
pub mod pipeline;
mod progress;
pub mod quadtree;
pub mod shard;
pub mod store;
#[cfg(test)]
mod test_rng;
pub mod text;
pub mod texture;
pub mod verify;
