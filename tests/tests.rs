//! The one integration-test binary: each stage has its own module.

mod bench;
mod dem;
mod pipeline;
