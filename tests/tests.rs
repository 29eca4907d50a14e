//! The one integration-test binary: each stage has its own module, and
//! `common` holds the helpers they share.

mod bench;
mod common;
mod compress;
mod dem;
mod hard_cases;
mod pipeline;
mod placement;
mod properties;
mod shard;
mod texture;
mod viewer;
