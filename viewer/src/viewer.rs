//! One frame, start to end, without ever waiting on a file:
//!
//! 1. select the cut top down (`terrachunk::lod::select`: ρ ≤ τ, a parent
//!    until all its children are resident, frustum-culled by chunk boxes);
//! 2. upload the decoded chunks the cut waits for, most wanted first, within
//!    the GPU memory budget, evicting the least recently used chunks that
//!    the cut did not pass through this frame (so ancestors of drawn chunks
//!    stay); if something was uploaded, select again;
//! 3. hand the still-missing chunks to the pager (background threads);
//! 4. draw, each chunk morphed toward its parent by `lod::morph_weight`.

use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Result;
use terrachunk::lod::{self, LodView, MorphSchedule, Selection};

use crate::camera::Camera;
use crate::pager::Pager;
use crate::render::{DrawItem, GpuChunk, Look, Renderer, Targets};
use crate::scene::Tileset;

/// Viewer settings.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Screen-space error tolerance τ, pixels.
    pub tau_px: f64,
    /// Morph schedule.
    pub schedule: MorphSchedule,
    /// GPU memory budget for chunks, bytes.
    pub budget_bytes: u64,
    /// Loader threads.
    pub threads: usize,
    /// Most chunks queued, decoding or decoded-but-not-uploaded at once.
    pub max_pending: usize,
    /// Most chunks uploaded in one frame (keeps frames even).
    pub max_uploads_per_frame: usize,
    /// Switches and colours.
    pub look: Look,
}

impl Options {
    /// Defaults for a tileset: τ = 2 px, bounded morph, 512 MB, fog
    /// density from the terrain's size (f ≈ 0.1 across its diagonal).
    pub fn for_tileset(ts: &Tileset) -> Self {
        let (lo, hi) = ts.bounds;
        let diag = ((hi[0] - lo[0]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt().max(1.0);
        Options {
            tau_px: 2.0,
            schedule: MorphSchedule::Bounded,
            budget_bytes: 512 << 20,
            threads: 2,
            max_pending: 16,
            max_uploads_per_frame: 16,
            look: Look {
                fog: true,
                lighting: true,
                wireframe: false,
                skirts: true,
                clear: [0.62, 0.72, 0.85],
                fog_density: 1.5 / diag,
                sun: [-0.5, 0.8, -0.3],
            },
        }
    }
}

/// What one frame did (one row of `--stats`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// Frame number from 0.
    pub frame: u64,
    /// Chunks drawn.
    pub chunks: usize,
    /// Chunks drawn per level.
    pub per_level: Vec<usize>,
    /// Surface triangles drawn.
    pub triangles: u64,
    /// Largest ρ among drawn chunks that have children (leaves are the
    /// finest data there is; they may exceed τ up close), pixels.
    pub max_rho_px: f64,
    /// Drawn chunks with children and ρ > τ (children still loading).
    pub over_tau: usize,
    /// CPU + GPU time of the frame, ms (the GPU is waited for in headless
    /// runs so that the time is real; never the loader).
    pub frame_ms: f64,
    /// Loads queued or decoding at the end of the frame.
    pub pending: usize,
    /// Chunks wanted but not resident.
    pub missing: usize,
    /// Bytes of chunks on the GPU.
    pub resident_bytes: u64,
    /// Chunks uploaded this frame.
    pub uploaded: usize,
}

impl FrameStats {
    /// The CSV header of [`FrameStats::csv_row`].
    pub const CSV_HEADER: &'static str = "frame,chunks,triangles,max_rho_px,over_tau,frame_ms,pending_loads,missing,resident_bytes,uploaded,chunks_per_level";

    /// One CSV row.
    pub fn csv_row(&self) -> String {
        let levels: Vec<String> = self.per_level.iter().map(|n| n.to_string()).collect();
        format!(
            "{},{},{},{:.4},{},{:.3},{},{},{},{},{}",
            self.frame,
            self.chunks,
            self.triangles,
            self.max_rho_px,
            self.over_tau,
            self.frame_ms,
            self.pending,
            self.missing,
            self.resident_bytes,
            self.uploaded,
            levels.join(" ")
        )
    }
}

struct Cached {
    gpu: GpuChunk,
    last_used: u64,
}

/// A tileset being viewed: the tree, the pager, the GPU cache, the renderer.
pub struct Viewer {
    /// The tileset.
    pub tileset: Tileset,
    /// The GPU side.
    pub renderer: Renderer,
    /// Settings (τ, look, …) may change between frames.
    pub opts: Options,
    pager: Pager,
    cache: HashMap<usize, Cached>,
    resident_bytes: u64,
    frame_no: u64,
}

/// Where a frame is drawn.
pub enum Target<'a> {
    /// The offscreen targets (headless, tests): colour and positions.
    Offscreen(&'a Targets),
    /// A window: its colour view and a depth view of `size`.
    Window(&'a wgpu::TextureView, &'a wgpu::TextureView),
}

impl Viewer {
    /// Opens the tileset in `dir`.
    pub fn open(dir: &Path, renderer: Renderer, opts: Option<Options>) -> Result<Self> {
        let tileset = Tileset::open(dir)?;
        let opts = opts.unwrap_or_else(|| Options::for_tileset(&tileset));
        let pager = Pager::new(opts.threads, opts.max_pending);
        Ok(Viewer { tileset, renderer, opts, pager, cache: HashMap::new(), resident_bytes: 0, frame_no: 0 })
    }

    /// The pager (tests pause it to show that frames never wait on it).
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// Bytes of chunks on the GPU.
    pub fn resident_bytes(&self) -> u64 {
        self.resident_bytes
    }

    /// Whether a node is on the GPU.
    pub fn is_resident(&self, node: usize) -> bool {
        self.cache.contains_key(&node)
    }

    /// The cut for `cam` at `size` over what is resident now.
    pub fn select(&self, cam: &Camera, size: [u32; 2]) -> Selection {
        let k = lod::screen_k(f64::from(size[0]), cam.hfov_deg.to_radians());
        let view = LodView { eye: cam.eye, k, tau_px: self.opts.tau_px, schedule: self.opts.schedule };
        let frustum = cam.frustum(f64::from(size[0]) / f64::from(size[1]));
        let nodes = &self.tileset.tree.nodes;
        lod::select(
            &self.tileset.tree,
            &view,
            |n| self.cache.contains_key(&n),
            |n| frustum.intersects_box(nodes[n].min, nodes[n].max),
        )
    }

    fn touch(&mut self, sel: &Selection) {
        for n in &sel.touched {
            if let Some(c) = self.cache.get_mut(n) {
                c.last_used = self.frame_no;
            }
        }
    }

    /// Uploads decoded chunks that `sel` wants, highest priority first,
    /// within the budget; drops decoded chunks no longer wanted. Returns the
    /// number uploaded.
    fn upload(&mut self, sel: &Selection, limit: usize) -> usize {
        self.pager.poll();
        let prio: HashMap<usize, f64> = sel.requests.iter().copied().collect();
        let ready = self.pager.ready();
        ready.retain(|n, _| prio.contains_key(n));
        let mut order: Vec<usize> = ready.keys().copied().collect();
        order.sort_by(|a, b| prio[b].total_cmp(&prio[a]).then(a.cmp(b)));
        let mut uploaded = 0;
        for n in order.into_iter().take(limit) {
            let need = self.pager.ready()[&n].gpu_bytes();
            while self.resident_bytes + need > self.opts.budget_bytes {
                // Least recently used among the chunks this frame did not pass through.
                let victim = self
                    .cache
                    .iter()
                    .filter(|(_, c)| c.last_used < self.frame_no)
                    .min_by_key(|(k, c)| (c.last_used, **k))
                    .map(|(k, _)| *k);
                let Some(v) = victim else { break };
                let c = self.cache.remove(&v).expect("victim is cached");
                self.resident_bytes -= c.gpu.bytes;
            }
            if self.resident_bytes + need > self.opts.budget_bytes {
                // Does not fit beside what the cut needs: the parent stays.
                break;
            }
            let mesh = self.pager.ready().remove(&n).expect("ready");
            let gpu = self.renderer.upload(&mesh);
            self.resident_bytes += gpu.bytes;
            self.cache.insert(n, Cached { gpu, last_used: self.frame_no });
            uploaded += 1;
        }
        uploaded
    }

    fn request(&mut self, sel: &Selection) {
        let wanted: Vec<(usize, f64, std::path::PathBuf)> =
            sel.requests.iter().map(|&(n, p)| (n, p, self.tileset.chunk_path(n))).collect();
        self.pager.request(&wanted);
    }

    /// Selection and paging for one frame (steps 1–3), without drawing.
    pub fn prepare(&mut self, cam: &Camera, size: [u32; 2]) -> (Selection, usize) {
        self.frame_no += 1;
        let mut sel = self.select(cam, size);
        self.touch(&sel);
        let uploaded = self.upload(&sel, self.opts.max_uploads_per_frame);
        if uploaded > 0 {
            sel = self.select(cam, size);
            self.touch(&sel);
        }
        self.request(&sel);
        (sel, uploaded)
    }

    /// One frame: select, page, draw. Never waits for a load.
    pub fn frame(&mut self, cam: &Camera, size: [u32; 2], target: Target<'_>) -> FrameStats {
        let t0 = Instant::now();
        let (sel, uploaded) = self.prepare(cam, size);
        let draws: Vec<(usize, f32)> = sel.draws.iter().map(|d| (d.node, d.weight as f32)).collect();
        self.draw(cam, size, target, &draws);
        let mut st = self.stats(&sel);
        st.uploaded = uploaded;
        st.frame_ms = t0.elapsed().as_secs_f64() * 1e3;
        st
    }

    /// Draws the given resident nodes with the given morph weights (nodes
    /// not resident are skipped), then waits for the GPU.
    pub fn draw(&mut self, cam: &Camera, size: [u32; 2], target: Target<'_>, nodes: &[(usize, f32)]) {
        let items: Vec<DrawItem<'_>> = nodes
            .iter()
            .filter_map(|&(n, w)| self.cache.get(&n).map(|c| DrawItem { chunk: &c.gpu, weight: w }))
            .collect();
        let look = self.opts.look;
        match target {
            Target::Offscreen(t) => self.renderer.draw_offscreen(t, cam, &items, &look),
            Target::Window(c, d) => self.renderer.draw(c, None, d, size, cam, &items, &look),
        }
        self.renderer.finish();
    }

    fn stats(&self, sel: &Selection) -> FrameStats {
        let nodes = &self.tileset.tree.nodes;
        let mut st = FrameStats {
            frame: self.frame_no - 1,
            chunks: sel.draws.len(),
            pending: self.pager.pending(),
            missing: sel.requests.len(),
            resident_bytes: self.resident_bytes,
            ..Default::default()
        };
        for d in &sel.draws {
            let n = &nodes[d.node];
            let l = n.key.level as usize;
            if st.per_level.len() <= l {
                st.per_level.resize(l + 1, 0);
            }
            st.per_level[l] += 1;
            st.triangles += u64::from(self.cache[&d.node].gpu.triangles);
            if !n.children.is_empty() {
                st.max_rho_px = st.max_rho_px.max(d.rho);
                st.over_tau += usize::from(!d.within_tau);
            }
        }
        st
    }

    /// Loads and uploads until the cut for a still camera is complete (or
    /// the budget stops it). Blocks: screenshots and tests only.
    pub fn settle(&mut self, cam: &Camera, size: [u32; 2]) -> Result<Selection> {
        loop {
            let (sel, uploaded) = self.prepare(cam, size);
            if sel.requests.is_empty() {
                return Ok(sel);
            }
            if uploaded > 0 {
                continue;
            }
            if self.pager.pending() > 0 {
                if !self.pager.wait(Duration::from_secs(60)) {
                    anyhow::bail!("chunk loads did not finish within a minute");
                }
                continue;
            }
            // Nothing in flight and nothing fits (budget) or loads failed:
            // the cut stays as it is.
            return Ok(sel);
        }
    }

    /// Loads the given nodes (blocking; tests). Ignores the budget.
    pub fn load_blocking(&mut self, nodes: &[usize]) -> Result<()> {
        for &n in nodes {
            if !self.cache.contains_key(&n) {
                let mesh = crate::scene::load_chunk(&self.tileset.chunk_path(n))?;
                let gpu = self.renderer.upload(&mesh);
                self.resident_bytes += gpu.bytes;
                self.cache.insert(n, Cached { gpu, last_used: self.frame_no });
            }
        }
        Ok(())
    }

    /// Chunk translation of a resident node.
    pub fn translation(&self, node: usize) -> Option<[f64; 3]> {
        self.cache.get(&node).map(|c| c.gpu.translation)
    }

    /// Surface triangles of a resident node.
    pub fn triangles(&self, node: usize) -> Option<u32> {
        self.cache.get(&node).map(|c| c.gpu.triangles)
    }
}
