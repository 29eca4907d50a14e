//! The GPU side (wgpu): one pipeline for shaded triangles, one for the
//! wireframe drawn as a line list of the chunk's edges (works on every
//! adapter, lavapipe included, unlike POLYGON_MODE_LINE; in wireframe mode
//! the triangles fill with the background colour to hide lines), each with
//! a "capture" variant that also writes camera-relative positions to an
//! Rgba32Float target for the tests' screen-error and crack measurements.
//!
//! Depth is reversed-Z with an infinite far plane (Depth32Float), and every
//! position the GPU sees is camera-relative f32: the chunk origin minus the
//! eye is formed in f64 on the CPU.

use anyhow::{Context, Result, anyhow};
use wgpu::util::DeviceExt;

use crate::camera::Camera;
use crate::scene::{ChunkMesh, Vertex};

/// Colour of the offscreen target (headless, tests): plain RGBA8.
pub const OFFSCREEN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const POSITION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Per-draw uniform stride (the WebGPU minimum dynamic-offset alignment).
const CHUNK_STRIDE: u64 = 256;

/// What is drawn of the triangles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// Lit, textured, fogged surfaces.
    #[default]
    Shaded,
    /// The edges alone, hidden lines removed (the surfaces fill with the
    /// background colour).
    Wireframe,
    /// The edges over the shaded surfaces.
    Overlay,
}

impl Mode {
    /// The next mode of the `w` key's cycle.
    pub fn next(self) -> Self {
        match self {
            Mode::Shaded => Mode::Wireframe,
            Mode::Wireframe => Mode::Overlay,
            Mode::Overlay => Mode::Shaded,
        }
    }
}

/// Unit direction toward a sun at `azimuth_deg` (clockwise from north) and
/// `elevation_deg` above the horizon, in the glTF frame (x east, y up, z south).
pub fn sun_direction(azimuth_deg: f64, elevation_deg: f64) -> [f64; 3] {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    [a.sin() * e.cos(), e.sin(), -a.cos() * e.cos()]
}

/// Switches and colours of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    /// exp² fog, with the clear colour as fog colour.
    pub fog: bool,
    /// Diffuse sun, one-sided: a face turned away from the sun gets the
    /// ambient term only (off: unlit base colour / texture).
    pub lighting: bool,
    /// Shaded, wireframe, or both.
    pub mode: Mode,
    /// Draw the skirts (off only to show the cracks they hide).
    pub skirts: bool,
    /// Clear colour, linear RGB 0–1; also the fog colour.
    pub clear: [f64; 3],
    /// Fog density ρ_fog, 1/m: f = exp(−(ρ_fog·d)²).
    pub fog_density: f64,
    /// Direction toward the sun (need not be unit), e.g. [`sun_direction`].
    pub sun: [f64; 3],
}

/// A chunk on the GPU.
pub struct GpuChunk {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    edges: wgpu::Buffer,
    textures: wgpu::BindGroup,
    surface_indices: u32,
    all_indices: u32,
    edge_indices: u32,
    has_texture: bool,
    has_normal_map: bool,
    normal_uv1: bool,
    base_colour: [f32; 4],
    /// Node translation, world metres.
    pub translation: [f64; 3],
    /// Bytes counted against the budget.
    pub bytes: u64,
    /// Surface triangles.
    pub triangles: u32,
}

/// One chunk to draw and its morph weight toward the parent.
pub struct DrawItem<'a> {
    /// The chunk.
    pub chunk: &'a GpuChunk,
    /// Morph weight toward the parent shape, 0–1.
    pub weight: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniform {
    view_proj: [[f32; 4]; 4],
    sun: [f32; 4],
    fog: [f32; 4],
    flags: [f32; 4],
    mode: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkUniform {
    origin: [f32; 4],
    base_colour: [f32; 4],
    opts: [f32; 4],
}

struct Pipelines {
    tri: wgpu::RenderPipeline,
    wire: wgpu::RenderPipeline,
}

/// Offscreen targets of one size.
pub struct Targets {
    /// Width and height, pixels.
    pub size: [u32; 2],
    colour: wgpu::Texture,
    position: wgpu::Texture,
    depth: wgpu::TextureView,
}

/// The device, pipelines and per-frame buffers.
pub struct Renderer {
    /// The wgpu device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name and backend, for reports.
    pub adapter_info: String,
    frame_buf: wgpu::Buffer,
    chunk_buf: wgpu::Buffer,
    chunk_cap: u64,
    bg0_layout: wgpu::BindGroupLayout,
    tex_layout: wgpu::BindGroupLayout,
    bg0: wgpu::BindGroup,
    sampler: wgpu::Sampler,
    white: wgpu::TextureView,
    flat_normal: wgpu::TextureView,
    plain: Pipelines,
    capture: Pipelines,
    surface_format: wgpu::TextureFormat,
}

impl Renderer {
    /// A renderer on the first adapter wgpu finds (lavapipe where there is
    /// no GPU), drawing to `surface_format` (and always able to draw offscreen).
    pub fn new(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
        surface_format: Option<wgpu::TextureFormat>,
    ) -> Result<Self> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| {
            anyhow!(
                "no graphics adapter ({e}). Without a GPU, install Mesa's software Vulkan driver \
                 (lavapipe): `apt-get install -y mesa-vulkan-drivers`"
            )
        })?;
        let info = adapter.get_info();
        let adapter_info = format!("{} ({:?})", info.name, info.backend);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("terrachunk-view"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .context("requesting a device")?;
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain"),
            source: wgpu::ShaderSource::Wgsl(include_str!("terrain.wgsl").into()),
        });
        let uniform = |binding, dynamic: bool, size: u64| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: dynamic,
                min_binding_size: wgpu::BufferSize::new(size),
            },
            count: None,
        };
        let frame_size = std::mem::size_of::<FrameUniform>() as u64;
        let chunk_size = std::mem::size_of::<ChunkUniform>() as u64;
        let bg0_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame+chunk"),
            entries: &[uniform(0, false, frame_size), uniform(1, true, chunk_size)],
        });
        let tex_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("texture"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("terrain"),
            bind_group_layouts: &[Some(&bg0_layout), Some(&tex_layout)],
            immediate_size: 0,
        });
        let surface_format = surface_format.unwrap_or(OFFSCREEN_FORMAT);
        let plain = pipelines(&device, &layout, &shader, surface_format, false);
        let capture = pipelines(&device, &layout, &shader, OFFSCREEN_FORMAT, true);
        let frame_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame"),
            size: frame_size,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let chunk_cap = 64;
        let chunk_buf = chunk_buffer(&device, chunk_cap);
        let bg0 = bind_group0(&device, &bg0_layout, &frame_buf, &chunk_buf);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("terrain"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let white = texture_view(&device, &queue, 1, 1, &[vec![255u8; 4]]);
        // (0, 0, 1) in the tangent frame: the vertex normal as it is.
        let flat_normal = texture_view(&device, &queue, 1, 1, &[vec![128u8, 128, 255, 255]]);
        Ok(Renderer {
            device,
            queue,
            adapter_info,
            frame_buf,
            chunk_buf,
            chunk_cap,
            bg0_layout,
            tex_layout,
            bg0,
            sampler,
            white,
            flat_normal,
            plain,
            capture,
            surface_format,
        })
    }

    /// Colour format of the on-screen pipelines.
    pub fn surface_format(&self) -> wgpu::TextureFormat {
        self.surface_format
    }

    /// Uploads a decoded chunk.
    pub fn upload(&self, mesh: &ChunkMesh) -> GpuChunk {
        let buf = |label, contents: &[u8], usage| {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let vertices = buf("vertices", bytemuck::cast_slice(&mesh.vertices), wgpu::BufferUsages::VERTEX);
        // Never an empty buffer: wgpu rejects size 0.
        let pad = |v: &[u32]| if v.is_empty() { vec![0u32] } else { v.to_vec() };
        let indices = buf("indices", bytemuck::cast_slice(&pad(&mesh.indices)), wgpu::BufferUsages::INDEX);
        let edges = buf("edges", bytemuck::cast_slice(&pad(&mesh.edges)), wgpu::BufferUsages::INDEX);
        let view = |m: &Option<crate::scene::Mips>| {
            m.as_ref().map(|m| {
                let levels: Vec<Vec<u8>> = m.levels.iter().map(|l| l.2.clone()).collect();
                texture_view(&self.device, &self.queue, m.levels[0].0, m.levels[0].1, &levels)
            })
        };
        let (colour, normal) = (view(&mesh.texture), view(&mesh.normal_map));
        let textures = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("chunk textures"),
            layout: &self.tex_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(colour.as_ref().unwrap_or(&self.white)),
                },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(normal.as_ref().unwrap_or(&self.flat_normal)),
                },
            ],
        });
        GpuChunk {
            vertices,
            indices,
            edges,
            textures,
            surface_indices: mesh.surface_indices,
            all_indices: mesh.indices.len() as u32,
            edge_indices: mesh.edges.len() as u32,
            has_texture: colour.is_some(),
            has_normal_map: normal.is_some(),
            normal_uv1: mesh.normal_uv1,
            base_colour: mesh.base_colour,
            translation: mesh.translation,
            bytes: mesh.gpu_bytes(),
            triangles: mesh.surface_triangles(),
        }
    }

    /// Offscreen colour, position and depth targets of `size`.
    pub fn targets(&self, size: [u32; 2]) -> Targets {
        let tex = |format, usage| {
            self.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("offscreen"),
                size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let rw = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        Targets {
            size,
            colour: tex(OFFSCREEN_FORMAT, rw),
            position: tex(POSITION_FORMAT, rw),
            depth: self.depth_view(size),
        }
    }

    /// A depth buffer of `size`.
    pub fn depth_view(&self, size: [u32; 2]) -> wgpu::TextureView {
        self.device
            .create_texture(&wgpu::TextureDescriptor {
                label: Some("depth"),
                size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: DEPTH_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                view_formats: &[],
            })
            .create_view(&wgpu::TextureViewDescriptor::default())
    }

    /// Draws into the offscreen targets (colour and positions).
    pub fn draw_offscreen(&mut self, t: &Targets, cam: &Camera, items: &[DrawItem<'_>], look: &Look) {
        let c = t.colour.create_view(&wgpu::TextureViewDescriptor::default());
        let p = t.position.create_view(&wgpu::TextureViewDescriptor::default());
        self.draw(&c, Some(&p), &t.depth, t.size, cam, items, look);
    }

    /// Draws `items` seen by `cam` into `colour` (and, when given, the
    /// camera-relative positions into `position`), then submits.
    #[allow(clippy::too_many_arguments)]
    pub fn draw(
        &mut self,
        colour: &wgpu::TextureView,
        position: Option<&wgpu::TextureView>,
        depth: &wgpu::TextureView,
        size: [u32; 2],
        cam: &Camera,
        items: &[DrawItem<'_>],
        look: &Look,
    ) {
        let m = cam.view_proj(f64::from(size[0]) / f64::from(size[1]));
        // WGSL matrices are column-major.
        let view_proj = [0, 1, 2, 3].map(|c| [0, 1, 2, 3].map(|r| m[r][c] as f32));
        let s = look.sun;
        let sl = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt().max(1e-12);
        let f = |v: bool| if v { 1.0f32 } else { 0.0 };
        let frame = FrameUniform {
            view_proj,
            sun: [(s[0] / sl) as f32, (s[1] / sl) as f32, (s[2] / sl) as f32, 0.0],
            fog: [look.clear[0] as f32, look.clear[1] as f32, look.clear[2] as f32, look.fog_density as f32],
            flags: [f(look.fog), f(look.lighting), 2e-5, 0.0],
            mode: [f(look.mode == Mode::Wireframe), 0.0, 0.0, 0.0],
        };
        self.queue.write_buffer(&self.frame_buf, 0, bytemuck::bytes_of(&frame));
        if items.len() as u64 > self.chunk_cap {
            self.chunk_cap = (items.len() as u64).next_power_of_two();
            self.chunk_buf = chunk_buffer(&self.device, self.chunk_cap);
            self.bg0 = bind_group0(&self.device, &self.bg0_layout, &self.frame_buf, &self.chunk_buf);
        }
        let mut bytes = vec![0u8; (items.len().max(1) as u64 * CHUNK_STRIDE) as usize];
        for (i, it) in items.iter().enumerate() {
            let o = [0, 1, 2].map(|a| (it.chunk.translation[a] - cam.eye[a]) as f32);
            let u = ChunkUniform {
                origin: [o[0], o[1], o[2], it.weight],
                base_colour: it.chunk.base_colour,
                opts: [f(it.chunk.has_texture), f(it.chunk.has_normal_map), f(it.chunk.normal_uv1), 0.0],
            };
            let at = i * CHUNK_STRIDE as usize;
            bytes[at..at + std::mem::size_of::<ChunkUniform>()].copy_from_slice(bytemuck::bytes_of(&u));
        }
        self.queue.write_buffer(&self.chunk_buf, 0, &bytes);
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        {
            let clear = wgpu::Color { r: look.clear[0], g: look.clear[1], b: look.clear[2], a: 1.0 };
            let mut attachments = vec![Some(wgpu::RenderPassColorAttachment {
                view: colour,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(clear), store: wgpu::StoreOp::Store },
            })];
            if let Some(p) = position {
                attachments.push(Some(wgpu::RenderPassColorAttachment {
                    view: p,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                }));
            }
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("terrain"),
                color_attachments: &attachments,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            let pl = if position.is_some() { &self.capture } else { &self.plain };
            pass.set_pipeline(&pl.tri);
            for (i, it) in items.iter().enumerate() {
                let g = it.chunk;
                pass.set_bind_group(0, &self.bg0, &[(i as u64 * CHUNK_STRIDE) as u32]);
                pass.set_bind_group(1, &g.textures, &[]);
                pass.set_vertex_buffer(0, g.vertices.slice(..));
                pass.set_index_buffer(g.indices.slice(..), wgpu::IndexFormat::Uint32);
                let n = if look.skirts { g.all_indices } else { g.surface_indices };
                pass.draw_indexed(0..n, 0, 0..1);
            }
            if look.mode != Mode::Shaded {
                pass.set_pipeline(&pl.wire);
                for (i, it) in items.iter().enumerate() {
                    let g = it.chunk;
                    if g.edge_indices == 0 {
                        continue;
                    }
                    pass.set_bind_group(0, &self.bg0, &[(i as u64 * CHUNK_STRIDE) as u32]);
                    pass.set_bind_group(1, &g.textures, &[]);
                    pass.set_vertex_buffer(0, g.vertices.slice(..));
                    pass.set_index_buffer(g.edges.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(0..g.edge_indices, 0, 0..1);
                }
            }
        }
        self.queue.submit([enc.finish()]);
    }

    /// Reads the offscreen colour back as RGBA8 rows (blocks: tests and
    /// screenshots only).
    pub fn read_colour(&self, t: &Targets) -> Vec<u8> {
        self.read(&t.colour, t.size, 4)
    }

    /// Reads the offscreen positions back: camera-relative xyz and a role
    /// (0 nothing, 1 surface, 2 skirt) per pixel.
    pub fn read_positions(&self, t: &Targets) -> Vec<[f32; 4]> {
        bytemuck::cast_slice(&self.read(&t.position, t.size, 16)).to_vec()
    }

    fn read(&self, tex: &wgpu::Texture, size: [u32; 2], bpp: u32) -> Vec<u8> {
        let row = (size[0] * bpp).div_ceil(256) * 256;
        let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(row * size[1]),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("readback") });
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: tex,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(size[1]),
                },
            },
            wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
        );
        self.queue.submit([enc.finish()]);
        buf.slice(..).map_async(wgpu::MapMode::Read, |r| r.expect("map readback"));
        self.device.poll(wgpu::PollType::wait_indefinitely()).expect("device poll");
        let data = buf.slice(..).get_mapped_range().expect("mapped readback");
        let mut out = Vec::with_capacity((size[0] * size[1] * bpp) as usize);
        for y in 0..size[1] {
            let at = (y * row) as usize;
            out.extend_from_slice(&data[at..at + (size[0] * bpp) as usize]);
        }
        out
    }

    /// Waits for the GPU to finish the submitted work (frame timing).
    pub fn finish(&self) {
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }
}

fn texture_view(device: &wgpu::Device, queue: &wgpu::Queue, w: u32, h: u32, levels: &[Vec<u8>]) -> wgpu::TextureView {
    let tex = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("chunk texture"),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: levels.len() as u32,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        // Stored values as they are: the targets are not sRGB either.
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    for (mip, px) in levels.iter().enumerate() {
        let (mw, mh) = ((w >> mip).max(1), (h >> mip).max(1));
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &tex,
                mip_level: mip as u32,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            px,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * mw), rows_per_image: Some(mh) },
            wgpu::Extent3d { width: mw, height: mh, depth_or_array_layers: 1 },
        );
    }
    tex.create_view(&wgpu::TextureViewDescriptor::default())
}

fn chunk_buffer(device: &wgpu::Device, cap: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("chunk uniforms"),
        size: cap * CHUNK_STRIDE,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

fn bind_group0(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    frame: &wgpu::Buffer,
    chunks: &wgpu::Buffer,
) -> wgpu::BindGroup {
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("frame+chunk"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: frame.as_entire_binding() },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: chunks,
                    offset: 0,
                    size: wgpu::BufferSize::new(std::mem::size_of::<ChunkUniform>() as u64),
                }),
            },
        ],
    })
}

fn pipelines(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    shader: &wgpu::ShaderModule,
    format: wgpu::TextureFormat,
    capture: bool,
) -> Pipelines {
    let attrs = wgpu::vertex_attr_array![
        0 => Float32x3, 1 => Float32x3, 2 => Float32x2, 3 => Float32x3, 4 => Float32, 5 => Float32x3, 6 => Float32x2
    ];
    let vbuf = [Some(wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &attrs,
    })];
    let colour = Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL });
    let pos = |mask| Some(wgpu::ColorTargetState { format: POSITION_FORMAT, blend: None, write_mask: mask });
    let tri_targets = if capture { vec![colour.clone(), pos(wgpu::ColorWrites::ALL)] } else { vec![colour.clone()] };
    let wire_targets = if capture { vec![colour, pos(wgpu::ColorWrites::empty())] } else { vec![colour] };
    let make = |vs: &str, fs: &str, topology, write: bool, targets: &[Option<wgpu::ColorTargetState>]| {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(fs),
            layout: Some(layout),
            vertex: wgpu::VertexState {
                module: shader,
                entry_point: Some(vs),
                compilation_options: Default::default(),
                buffers: &vbuf,
            },
            primitive: wgpu::PrimitiveState { topology, cull_mode: None, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(write),
                depth_compare: Some(wgpu::CompareFunction::GreaterEqual),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: shader,
                entry_point: Some(fs),
                compilation_options: Default::default(),
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    let (fs_tri, fs_wire) = if capture { ("fs_capture", "fs_wire_capture") } else { ("fs_main", "fs_wire") };
    Pipelines {
        tri: make("vs_main", fs_tri, wgpu::PrimitiveTopology::TriangleList, true, &tri_targets),
        wire: make("vs_wire", fs_wire, wgpu::PrimitiveTopology::LineList, false, &wire_targets),
    }
}
