//! The one integration-test binary: each stage has its own module.

mod dem;
mod pipeline;
