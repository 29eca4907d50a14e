//! terrachunk-view: a small real-time viewer for terrachunk tilesets (wgpu).
//!
//! It reads only what the output contract promises (DESIGN.md): the
//! `tileset.json` index and one `.glb` per chunk. Chunk selection and morph
//! weights are `terrachunk::lod` (the library's, not a copy); this crate adds
//! the loading ([`pager`]), the GPU side ([`render`]), the camera
//! ([`camera`]) and the per-frame loop that ties them ([`viewer`]).
#![deny(missing_docs)]

pub mod camera;
pub mod flythrough;
pub mod pager;
pub mod render;
pub mod scene;
pub mod viewer;

/// A renderer for offscreen (headless) drawing on the first adapter wgpu
/// finds; on a machine without a GPU that is Mesa's lavapipe, and without
/// it this fails with the line that installs it.
pub fn headless_renderer() -> anyhow::Result<render::Renderer> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    render::Renderer::new(&instance, None, None)
}
