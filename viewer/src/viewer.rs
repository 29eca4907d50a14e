//! One frame, start to end, without ever waiting on a file:
//!
//! 1. select the cut top down (`terrachunk::lod::select`: ρ ≤ τ, a parent
//!    until all its children are resident, frustum-culled by chunk boxes),
//!    with ρ bounding the shift anywhere in the image (`screen_k_bound`)
//!    and the prefetch ranked at the eye the last frames' motion predicts;
//! 2. upload decoded chunks, those the cut waits for first, then the
//!    prefetched ones, within a per-frame byte budget (and count, and time)
//!    and the GPU memory budget, evicting the least recently used chunks
//!    that the cut did not pass through this frame (so ancestors of drawn
//!    chunks stay; prefetched ones go before them); if something was
//!    uploaded, select again;
//! 3. hand the still-missing and the prefetched chunks to the pager
//!    (background threads);
//! 4. draw, each chunk morphed toward its parent by `lod::morph_weight`; a
//!    chunk that replaces its parent while that weight is below 1 (its
//!    children came late) starts at the parent's shape and morphs to it
//!    over `fade_frames` frames instead of popping.
//!
//! The roots are loaded when the viewer opens, so the first frame draws.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Result;
use terrachunk::lod::{self, LodView, MorphSchedule, Selection};

use crate::camera::Camera;
use crate::pager::{Load, Pager};
use crate::render::{DrawItem, GpuChunk, Look, Mode, Renderer, Targets, sun_direction};
use crate::scene::Tileset;

/// Viewer settings.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Screen-space error tolerance τ, pixels (see [`Options::set_tau`]).
    pub tau_px: f64,
    /// The largest τ the tileset's textures were sized for; τ stays below
    /// it unless `force_tau`.
    pub tau_max_px: Option<f64>,
    /// Allows τ past `tau_max_px` (texels may then cover several pixels).
    pub force_tau: bool,
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
    /// Most bytes uploaded in one frame (at least one chunk always goes).
    pub upload_bytes_per_frame: u64,
    /// Most time spent uploading in one frame, ms (`None`: no limit, so a
    /// run's frames do not depend on the machine's speed).
    pub upload_ms_per_frame: Option<f64>,
    /// Frames over which a chunk that replaced its parent early morphs from
    /// the parent's shape to its scheduled weight (0: it pops).
    pub fade_frames: u32,
    /// Request the children of drawn chunks before the cut needs them.
    pub prefetch: bool,
    /// How far ahead, in frames of the current motion, prefetch predicts
    /// the eye (0: no prediction).
    pub lookahead_frames: f64,
    /// Switches and colours.
    pub look: Look,
}

impl Options {
    /// Defaults for a tileset: τ = 2 px (or τ_max if lower), bounded
    /// morph, 512 MB, 32 MB uploaded per frame, an 8-frame fade, prefetch
    /// 20 frames ahead, the sun of the tileset's hillshade (else from the
    /// north-west, 45° high, the pipeline's default), fog density from the
    /// terrain's size (f ≈ 0.1 across its diagonal).
    pub fn for_tileset(ts: &Tileset) -> Self {
        let (lo, hi) = ts.bounds;
        let diag = ((hi[0] - lo[0]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt().max(1.0);
        let [az, el] = ts.sun_deg.unwrap_or([315.0, 45.0]);
        Options {
            tau_px: ts.tau_max_px.map_or(2.0, |m| m.min(2.0)),
            tau_max_px: ts.tau_max_px,
            force_tau: false,
            schedule: MorphSchedule::Bounded,
            budget_bytes: 512 << 20,
            threads: 2,
            max_pending: 16,
            max_uploads_per_frame: 16,
            upload_bytes_per_frame: 32 << 20,
            upload_ms_per_frame: None,
            fade_frames: 8,
            prefetch: true,
            lookahead_frames: 20.0,
            look: Look {
                fog: true,
                lighting: true,
                mode: Mode::Shaded,
                skirts: true,
                clear: [0.62, 0.72, 0.85],
                fog_density: 1.5 / diag,
                sun: sun_direction(az, el),
            },
        }
    }

    /// Sets τ, capped at τ_max unless `force_tau`; returns the τ set.
    pub fn set_tau(&mut self, tau_px: f64) -> f64 {
        self.tau_px = match self.tau_max_px {
            Some(m) if !self.force_tau => tau_px.min(m),
            _ => tau_px,
        };
        self.tau_px
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
    /// The frame's worst screen error among drawn chunks that have
    /// children (leaves are the finest data there is; they may exceed τ up
    /// close), pixels: ρ scaled by the morph blend the chunk is drawn with
    /// (`lod::shown_error_px`), ρ bounding the whole image.
    pub max_rho_px: f64,
    /// Drawn chunks with children shown above τ.
    pub over_tau: usize,
    /// Of those, the ones whose children are still loading.
    pub over_tau_loading: usize,
    /// Of those, the ones whose children are decoded but do not fit the
    /// GPU memory budget beside the rest of the cut.
    pub over_tau_budget: usize,
    /// Of those, the ones shown above τ only while morphing in (late).
    pub over_tau_fading: usize,
    /// Chunks morphing in from their parent's shape.
    pub fading: usize,
    /// Chunks prefetched but not resident yet.
    pub prefetch: usize,
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
    pub const CSV_HEADER: &'static str = "frame,chunks,triangles,max_rho_px,over_tau,over_tau_loading,over_tau_budget,over_tau_fading,fading,frame_ms,pending_loads,missing,prefetch,resident_bytes,uploaded,chunks_per_level";

    /// One CSV row.
    pub fn csv_row(&self) -> String {
        let levels: Vec<String> = self.per_level.iter().map(|n| n.to_string()).collect();
        format!(
            "{},{},{},{:.4},{},{},{},{},{},{:.3},{},{},{},{},{},{}",
            self.frame,
            self.chunks,
            self.triangles,
            self.max_rho_px,
            self.over_tau,
            self.over_tau_loading,
            self.over_tau_budget,
            self.over_tau_fading,
            self.fading,
            self.frame_ms,
            self.pending,
            self.missing,
            self.prefetch,
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
    /// The eye of the previous frame (motion for the prefetch).
    last_eye: Option<[f64; 3]>,
    /// Chunks drawn in the previous frame.
    drawn_before: HashSet<usize>,
    /// Chunks morphing in from their parent's shape: the weight drawn last.
    fading: HashMap<usize, f64>,
    /// Decoded chunks that did not fit the memory budget this frame.
    over_budget: HashSet<usize>,
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
        let mut v = Viewer {
            tileset,
            renderer,
            opts,
            pager,
            cache: HashMap::new(),
            resident_bytes: 0,
            frame_no: 0,
            last_eye: None,
            drawn_before: HashSet::new(),
            fading: HashMap::new(),
            over_budget: HashSet::new(),
        };
        // The first frame draws the whole terrain, coarse: never a blank one.
        let roots = v.tileset.tree.roots.clone();
        v.load_blocking(&roots)?;
        Ok(v)
    }

    /// Forgets the camera's motion and the fades (a jump, or a still).
    pub fn reset_motion(&mut self) {
        self.last_eye = None;
        self.fading.clear();
        self.drawn_before.clear();
    }

    /// The pager (tests pause it to show that frames never wait on it).
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// The pager, to wait for it (tests that fix how long loads take).
    pub fn pager_mut(&mut self) -> &mut Pager {
        &mut self.pager
    }

    /// Bytes of chunks on the GPU.
    pub fn resident_bytes(&self) -> u64 {
        self.resident_bytes
    }

    /// Whether a node is on the GPU.
    pub fn is_resident(&self, node: usize) -> bool {
        self.cache.contains_key(&node)
    }

    /// The cut for `cam` at `size` over what is resident now (ρ bounds the
    /// shift of any pixel: K carries the off-axis factor).
    pub fn select(&self, cam: &Camera, size: [u32; 2]) -> Selection {
        let k = lod::screen_k_bound([f64::from(size[0]), f64::from(size[1])], cam.hfov_deg.to_radians());
        let moved = self.last_eye.filter(|&l| l != cam.eye);
        let ahead = |frames: f64| moved.map(|l| [0, 1, 2].map(|a| cam.eye[a] + frames * (cam.eye[a] - l[a])));
        let eye_ahead = if self.opts.lookahead_frames > 0.0 { ahead(self.opts.lookahead_frames) } else { None };
        let view = LodView {
            eye: cam.eye,
            k,
            eye_ahead,
            eye_next: ahead(1.0),
            tau_px: self.opts.tau_px,
            schedule: self.opts.schedule,
        };
        let frustum = cam.frustum(f64::from(size[0]) / f64::from(size[1]));
        let nodes = &self.tileset.tree.nodes;
        lod::select(
            &self.tileset.tree,
            &view,
            |n| self.cache.contains_key(&n),
            |n| frustum.intersects_box(nodes[n].min, nodes[n].max),
        )
    }

    /// Marks what the selection keeps: the cut's chunks as used this frame,
    /// the prefetched ones from the frame before (evicted first).
    fn touch(&mut self, sel: &Selection) {
        for n in &sel.kept {
            if let Some(c) = self.cache.get_mut(n) {
                c.last_used = c.last_used.max(self.frame_no - 1);
            }
        }
        for n in &sel.touched {
            if let Some(c) = self.cache.get_mut(n) {
                c.last_used = self.frame_no;
            }
        }
    }

    /// Uploads decoded chunks that `sel` wants, those the cut waits for
    /// first, then prefetched ones, each group highest priority first,
    /// within the per-frame limits and the memory budget; drops decoded
    /// chunks no longer wanted. Returns the number uploaded.
    fn upload(&mut self, sel: &Selection) -> usize {
        self.pager.poll();
        let started = Instant::now();
        // (group, priority): 0 = the cut waits for it, 1 = prefetch.
        let mut rank: HashMap<usize, (u8, f64)> = sel.prefetch.iter().map(|&(n, p)| (n, (1, p))).collect();
        rank.extend(sel.requests.iter().map(|&(n, p)| (n, (0, p))));
        let ready = self.pager.ready();
        ready.retain(|n, _| rank.contains_key(n));
        let mut order: Vec<usize> = ready.keys().copied().collect();
        order.sort_by(|a, b| rank[a].0.cmp(&rank[b].0).then(rank[b].1.total_cmp(&rank[a].1)).then(a.cmp(b)));
        let (mut uploaded, mut bytes) = (0, 0u64);
        for n in order {
            let need = self.pager.ready()[&n].gpu_bytes();
            let over_frame = uploaded >= self.opts.max_uploads_per_frame
                || bytes + need > self.opts.upload_bytes_per_frame
                || self.opts.upload_ms_per_frame.is_some_and(|ms| started.elapsed().as_secs_f64() * 1e3 > ms);
            if uploaded > 0 && over_frame {
                break;
            }
            // A chunk the cut waits for may evict prefetched ones; a
            // prefetched one only chunks neither frame kept.
            let keep_from = if rank[&n].0 == 0 { self.frame_no } else { self.frame_no - 1 };
            while self.resident_bytes + need > self.opts.budget_bytes {
                let victim = self
                    .cache
                    .iter()
                    .filter(|(_, c)| c.last_used < keep_from)
                    .min_by_key(|(k, c)| (c.last_used, **k))
                    .map(|(k, _)| *k);
                let Some(v) = victim else { break };
                let c = self.cache.remove(&v).expect("victim is cached");
                self.resident_bytes -= c.gpu.bytes;
            }
            if self.resident_bytes + need > self.opts.budget_bytes {
                // Does not fit beside what the cut needs: the parent stays.
                self.over_budget.insert(n);
                continue;
            }
            let mesh = self.pager.ready().remove(&n).expect("ready");
            let gpu = self.renderer.upload(&mesh);
            self.resident_bytes += gpu.bytes;
            bytes += gpu.bytes;
            self.cache.insert(n, Cached { gpu, last_used: self.frame_no });
            uploaded += 1;
        }
        uploaded
    }

    fn request(&mut self, sel: &Selection) {
        let tree = &self.tileset.tree;
        let wanted: Vec<Load> = sel
            .requests
            .iter()
            .chain(&sel.prefetch)
            .map(|&(n, p)| Load {
                node: n,
                priority: p,
                path: self.tileset.chunk_path(n),
                parent: tree.nodes[n].parent.map(|q| self.tileset.chunk_path(q)),
            })
            .collect();
        self.pager.request(&wanted);
    }

    /// Selection and paging for one frame (steps 1–3), without drawing; the
    /// draws' weights include the fades.
    pub fn prepare(&mut self, cam: &Camera, size: [u32; 2]) -> (Selection, usize) {
        self.frame_no += 1;
        self.over_budget.clear();
        let mut sel = self.select(cam, size);
        if !self.opts.prefetch {
            sel.prefetch.clear();
        }
        self.touch(&sel);
        let uploaded = self.upload(&sel);
        if uploaded > 0 {
            sel = self.select(cam, size);
            if !self.opts.prefetch {
                sel.prefetch.clear();
            }
            self.touch(&sel);
        }
        self.request(&sel);
        self.fade(&mut sel);
        self.last_eye = Some(cam.eye);
        (sel, uploaded)
    }

    /// A chunk drawn where its parent was drawn the frame before, with a
    /// scheduled weight below 1, would pop: it starts near its parent's
    /// shape and comes down to its schedule by at least 1/`fade_frames` a
    /// frame, faster where an invisible step keeps it within τ
    /// (`lod::late_weight`).
    fn fade(&mut self, sel: &mut Selection) {
        let nodes = &self.tileset.tree.nodes;
        let fade = f64::from(self.opts.fade_frames);
        let mut drawn = HashSet::with_capacity(sel.draws.len());
        for d in &mut sel.draws {
            drawn.insert(d.node);
            let parent = nodes[d.node].parent.filter(|p| self.drawn_before.contains(p));
            let from = match parent {
                Some(_) if d.weight < 1.0 && fade > 0.0 => Some((1.0, 0.0)),
                _ => self.fading.get(&d.node).map(|&w| (w, 1.0 / fade)),
            };
            let Some((from, slide)) = from else { continue };
            let deltas = (nodes[d.node].delta_m, self.tileset.tree.parent_delta(d.node).unwrap_or(0.0));
            let w = lod::late_weight(d.rho, self.opts.tau_px, deltas, from, d.weight).min(from - slide);
            if w <= d.weight {
                self.fading.remove(&d.node);
            } else {
                d.weight = w;
                self.fading.insert(d.node, w);
            }
        }
        self.fading.retain(|n, _| drawn.contains(n));
        self.drawn_before = drawn;
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
            prefetch: sel.prefetch.len(),
            fading: self.fading.len(),
            resident_bytes: self.resident_bytes,
            ..Default::default()
        };
        let tau = self.opts.tau_px;
        for d in &sel.draws {
            let n = &nodes[d.node];
            let l = n.key.level as usize;
            if st.per_level.len() <= l {
                st.per_level.resize(l + 1, 0);
            }
            st.per_level[l] += 1;
            st.triangles += u64::from(self.cache[&d.node].gpu.triangles);
            if n.children.is_empty() {
                continue;
            }
            let shown = lod::shown_error_px(d.rho, d.weight, n.delta_m, self.tileset.tree.parent_delta(d.node));
            st.max_rho_px = st.max_rho_px.max(shown);
            // A hair over τ is the bound met with rounding.
            if shown <= tau * (1.0 + 1e-9) {
                continue;
            }
            st.over_tau += 1;
            if d.within_tau {
                st.over_tau_fading += 1;
            } else if n.children.iter().any(|c| self.over_budget.contains(c)) {
                st.over_tau_budget += 1;
            } else {
                st.over_tau_loading += 1;
            }
        }
        st
    }

    /// Loads and uploads until the cut for a still camera is complete (or
    /// the budget stops it), without prefetch or fades. Blocks: screenshots
    /// and tests only.
    pub fn settle(&mut self, cam: &Camera, size: [u32; 2]) -> Result<Selection> {
        loop {
            self.reset_motion();
            let (mut sel, uploaded) = self.prepare(cam, size);
            sel.prefetch.clear();
            self.request(&sel);
            if sel.requests.is_empty() {
                self.reset_motion();
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
            self.reset_motion();
            return Ok(sel);
        }
    }

    /// Loads the given nodes (blocking; the roots at the start, tests).
    /// Ignores the budget.
    pub fn load_blocking(&mut self, nodes: &[usize]) -> Result<()> {
        for &n in nodes {
            if !self.cache.contains_key(&n) {
                let parent = self.tileset.tree.nodes[n].parent.map(|p| self.tileset.chunk_path(p));
                let mesh = crate::scene::load_chunk_under(&self.tileset.chunk_path(n), parent.as_deref())?;
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
