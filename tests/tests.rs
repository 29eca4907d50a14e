//! The one integration-test binary: each stage has its own module, and
//! `common` holds the helpers they share.

mod bench;
mod common;
mod compress;
mod dem;
mod geoid;
mod goldens;
mod hard_cases;
mod loader_limits;
mod memory;
mod output_safety;
mod pipeline;
mod placement;
mod properties;
mod rtin;
mod shard;
mod texture;
mod verify_trust;
mod viewer;
mod vrt;
