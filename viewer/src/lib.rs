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
pub mod input;
pub mod pager;
pub mod render;
pub mod scene;
pub mod viewer;

/// A renderer for offscreen (headless) drawing on the first Vulkan adapter
/// wgpu finds; on a machine without a GPU that is Mesa's lavapipe, and
/// without it this fails with the line that installs it. (Vulkan only, so
/// that headless images and the tests' references come from one kind of
/// driver; the window may also use GL.)
pub fn headless_renderer() -> anyhow::Result<render::Renderer> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    let instance = wgpu::Instance::new(desc);
    render::Renderer::new(&instance, None, None)
}
