//! The one integration-test binary: each stage has its own module.

mod common;
mod dem;
mod pipeline;
mod texture;
