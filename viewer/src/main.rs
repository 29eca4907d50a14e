//! `terrachunk-view`: draws a terrachunk tileset in a window (winit), or
//! headless to a PNG or through a flythrough with per-frame statistics.

use std::collections::HashSet;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use terrachunk::lod::MorphSchedule;
use terrachunk_view::camera::Camera;
use terrachunk_view::flythrough::Flythrough;
use terrachunk_view::input::{self, Move};
use terrachunk_view::render::{Mode, Renderer, sun_direction};
use terrachunk_view::scene::Tileset;
use terrachunk_view::viewer::{FrameStats, Options, Target, Viewer};
use winit::application::ApplicationHandler;
use winit::event::{DeviceEvent, ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, KeyCode, PhysicalKey};

use winit::window::{Window, WindowId};

#[derive(Parser)]
#[command(name = "terrachunk-view", version, about = "Real-time Chunked-LOD viewer for a terrachunk tileset")]
struct Cli {
    /// Tileset directory (holds tileset.json and tiles/).
    dir: PathBuf,
    /// Screen-space error tolerance τ, pixels (`+`/`-` change it by √2):
    /// no point of the image is drawn more than τ pixels from where the
    /// tileset's finest level puts it, corners included. At most the
    /// tileset's τ_max (its textures are sized for it) unless --force-tau
    /// [default: 2, or τ_max if lower].
    #[arg(long)]
    tau: Option<f64>,
    /// Allow τ past the tileset's τ_max.
    #[arg(long)]
    force_tau: bool,
    /// Morph schedule: `bounded` keeps the screen error ≤ τ; `ulrich` is the
    /// paper's, up to 9/8·τ mid-morph.
    #[arg(long, value_enum, default_value_t = MorphArg::Bounded)]
    morph: MorphArg,
    /// GPU memory budget for chunks, MiB.
    #[arg(long, default_value_t = 512)]
    budget_mb: u64,
    /// Most chunk bytes uploaded per frame, MiB (at least one chunk goes).
    #[arg(long, default_value_t = 32)]
    upload_mb_per_frame: u64,
    /// Frames over which a chunk whose children came late morphs in (0: it pops).
    #[arg(long, default_value_t = 8)]
    fade_frames: u32,
    /// Load only what the cut waits for (no prefetch of children): to see
    /// what prefetch buys.
    #[arg(long)]
    no_prefetch: bool,
    /// Horizontal field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    hfov: f64,
    /// Image or window size, `WxH`.
    #[arg(long, default_value = "1280x720", value_parser = parse_size)]
    size: [u32; 2],
    /// Camera `x,y,z,yaw,pitch` (metres, degrees; yaw 0 = north, 90 = east)
    /// [default: south of the terrain, looking north and down].
    #[arg(long, value_parser = parse_camera, allow_hyphen_values = true)]
    camera: Option<[f64; 5]>,
    /// Render without a window.
    #[arg(long)]
    headless: bool,
    /// Headless: write the (last) frame here as PNG.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Headless: fly this path (JSON: {"cameras": [[x,y,z,yaw,pitch],…], "frames_per_segment": 30}).
    #[arg(long)]
    flythrough: Option<PathBuf>,
    /// Write per-frame statistics (CSV) here.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Headless flythrough: also write every `--frames-every`-th frame into
    /// this directory as `frame_NNNN.png`.
    #[arg(long)]
    frames: Option<PathBuf>,
    /// See `--frames`.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..))]
    frames_every: u32,
    /// Start with fog off.
    #[arg(long)]
    no_fog: bool,
    /// Fog density ρ_fog, 1/m (fog factor exp(−(ρ_fog·d)²)) [default: 1.5 /
    /// the terrain's diagonal].
    #[arg(long)]
    fog_density: Option<f64>,
    /// Start with lighting off.
    #[arg(long)]
    no_lighting: bool,
    /// Start in this mode (`w` cycles them).
    #[arg(long, value_enum, default_value_t = ModeArg::Shaded)]
    mode: ModeArg,
    /// Sun `azimuth,elevation` in degrees (clockwise from north, above the
    /// horizon) [default: the tileset's hillshade sun, else 315,45].
    #[arg(long, value_parser = parse_sun, allow_hyphen_values = true)]
    sun: Option<[f64; 2]>,
    /// Fog and background colour `r,g,b`, 0–1 [default: 0.62,0.72,0.85].
    #[arg(long, value_parser = parse_colour)]
    fog_colour: Option<[f64; 3]>,
    /// Loader threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
}

#[derive(Clone, Copy, ValueEnum)]
enum MorphArg {
    Bounded,
    Ulrich,
}

#[derive(Clone, Copy, ValueEnum)]
enum ModeArg {
    Shaded,
    Wireframe,
    Overlay,
}

fn numbers<const N: usize>(s: &str, what: &str) -> Result<[f64; N], String> {
    let v: Vec<f64> =
        s.split(',').map(|t| t.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("{s:?}: not finite"));
    }
    v.try_into().map_err(|_| format!("expected {what}"))
}

fn parse_sun(s: &str) -> Result<[f64; 2], String> {
    let [a, e] = numbers::<2>(s, "azimuth,elevation")?;
    if !(-90.0..=90.0).contains(&e) {
        return Err(format!("elevation {e} is not within ±90°"));
    }
    Ok([a, e])
}

fn parse_colour(s: &str) -> Result<[f64; 3], String> {
    let c = numbers::<3>(s, "r,g,b")?;
    if c.iter().any(|v| !(0.0..=1.0).contains(v)) {
        return Err(format!("{s:?}: each channel within 0..=1"));
    }
    Ok(c)
}

fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or("expected WxH, e.g. 640x480")?;
    let p = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| n > 0).ok_or(format!("bad size {s:?}"));
    Ok([p(w)?, p(h)?])
}

fn parse_camera(s: &str) -> Result<[f64; 5], String> {
    let v: Vec<f64> =
        s.split(',').map(|t| t.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    v.try_into().map_err(|_| "expected x,y,z,yaw,pitch".to_string())
}

fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("terrachunk-view: {e:#}");
            // Bad input (a tileset it cannot read, a setting it refuses): 2.
            std::process::ExitCode::from(2)
        }
    }
}

fn options(cli: &Cli, ts: &Tileset) -> Result<Options> {
    let mut o = Options::for_tileset(ts);
    o.force_tau = cli.force_tau;
    if let Some(t) = cli.tau {
        if !(t.is_finite() && t > 0.0) {
            bail!("--tau {t}: must be a positive number of pixels");
        }
        if let Some(m) = ts.tau_max_px.filter(|&m| t > m && !cli.force_tau) {
            bail!(
                "--tau {t} px is past the tileset's τ_max {m} px (its textures would be magnified); --force-tau allows it"
            );
        }
        o.tau_px = t;
    }
    o.schedule = match cli.morph {
        MorphArg::Bounded => MorphSchedule::Bounded,
        MorphArg::Ulrich => MorphSchedule::Ulrich,
    };
    o.budget_bytes = cli.budget_mb << 20;
    o.upload_bytes_per_frame = cli.upload_mb_per_frame << 20;
    o.fade_frames = cli.fade_frames;
    o.prefetch = !cli.no_prefetch;
    o.threads = cli.threads;
    o.look.fog = !cli.no_fog;
    if let Some(d) = cli.fog_density {
        o.look.fog_density = d;
    }
    if let Some([a, e]) = cli.sun {
        o.look.sun = sun_direction(a, e);
    }
    if let Some(c) = cli.fog_colour {
        o.look.clear = c;
    }
    o.look.lighting = !cli.no_lighting;
    o.look.mode = match cli.mode {
        ModeArg::Shaded => Mode::Shaded,
        ModeArg::Wireframe => Mode::Wireframe,
        ModeArg::Overlay => Mode::Overlay,
    };
    Ok(o)
}

/// South of the terrain, above its highest point, looking north and down.
fn default_camera(ts: &Tileset, hfov: f64) -> Camera {
    let (lo, hi) = ts.bounds;
    let ext = (hi[0] - lo[0]).max(hi[2] - lo[2]);
    Camera {
        eye: [(lo[0] + hi[0]) / 2.0, hi[1] + 0.25 * ext, hi[2] + 0.35 * ext],
        yaw_deg: 0.0,
        pitch_deg: -30.0,
        hfov_deg: hfov,
        near_m: near_plane(ext),
    }
}

fn near_plane(extent_m: f64) -> f64 {
    (extent_m * 1e-5).clamp(0.05, 10.0)
}

fn camera(cli: &Cli, ts: &Tileset) -> Camera {
    let base = default_camera(ts, cli.hfov);
    match cli.camera {
        Some(c) => Camera { eye: [c[0], c[1], c[2]], yaw_deg: c[3], pitch_deg: c[4], ..base },
        None => base,
    }
}

fn run(cli: Cli) -> Result<()> {
    if cli.headless {
        return headless(&cli);
    }
    if cli.out.is_some() || cli.flythrough.is_some() {
        bail!("--out and --flythrough need --headless");
    }
    let event_loop = EventLoop::new().context("opening a window (no display? use --headless)")?;
    let mut app = App { cli, state: None, keys: HashSet::new(), look_mode: false, error: None };

    event_loop.run_app(&mut app)?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

fn headless(cli: &Cli) -> Result<()> {
    let renderer = terrachunk_view::headless_renderer()?;
    let ts = Tileset::open(&cli.dir)?;
    let opts = options(cli, &ts)?;
    let cam = camera(cli, &ts);
    let mut v = Viewer::open(&cli.dir, renderer, Some(opts))?;
    let targets = v.renderer.targets(cli.size);
    let mut stats = match &cli.stats {
        Some(p) => {
            let mut f = std::fs::File::create(p).with_context(|| format!("{}: cannot create", p.display()))?;
            writeln!(f, "{}", FrameStats::CSV_HEADER)?;
            Some(f)
        }
        None => None,
    };
    let mut row = |st: &FrameStats| -> Result<()> {
        if let Some(f) = stats.as_mut() {
            writeln!(f, "{}", st.csv_row())?;
        }
        Ok(())
    };
    if let Some(path) = &cli.flythrough {
        // The start view is loaded first, as a viewer opening on it would;
        // then frames back to back: whatever is not loaded yet is simply
        // not drawn finer (see the pending_loads column).
        let frames = Flythrough::read(path)?.frames(&cam);
        if let Some(first) = frames.first() {
            v.settle(first, cli.size)?;
        }
        let (mut total, mut worst, mut over, mut blank) = (0.0, 0.0f64, 0, 0);
        if let Some(d) = &cli.frames {
            std::fs::create_dir_all(d).with_context(|| format!("{}: cannot create", d.display()))?;
        }
        for c in &frames {
            let st = v.frame(c, cli.size, Target::Offscreen(&targets));
            if let Some(d) = cli.frames.as_ref().filter(|_| st.frame % u64::from(cli.frames_every) == 0) {
                let out = d.join(format!("frame_{:04}.png", st.frame));
                let px = v.renderer.read_colour(&targets);
                image::save_buffer(&out, &px, cli.size[0], cli.size[1], image::ExtendedColorType::Rgba8)
                    .with_context(|| format!("{}: cannot write", out.display()))?;
            }
            total += st.frame_ms;
            worst = worst.max(st.max_rho_px);
            over += usize::from(st.over_tau > 0);
            blank += usize::from(st.chunks == 0);
            row(&st)?;
        }
        println!(
            "{} frames, {:.1} ms/frame mean, worst ρ {worst:.3} px at τ {} px, {over} frames over τ, {blank} blank, on {}",
            frames.len(),
            total / frames.len().max(1) as f64,
            v.opts.tau_px,
            v.renderer.adapter_info
        );
    } else {
        // A still: load the whole cut first, then draw it once.
        v.settle(&cam, cli.size)?;
        let st = v.frame(&cam, cli.size, Target::Offscreen(&targets));
        row(&st)?;
        println!("{}", hud(&st, v.opts.tau_px, v.opts.look.mode));
    }
    if let Some(out) = &cli.out {
        let px = v.renderer.read_colour(&targets);
        image::save_buffer(out, &px, cli.size[0], cli.size[1], image::ExtendedColorType::Rgba8)
            .with_context(|| format!("{}: cannot write", out.display()))?;
    }
    Ok(())
}

/// The status line: τ and the frame's worst screen error, and for chunks
/// shown above τ why (children loading, not fitting the memory budget, or
/// morphing in).
fn hud(st: &FrameStats, tau: f64, mode: Mode) -> String {
    let levels: Vec<String> = st.per_level.iter().map(|n| n.to_string()).collect();
    let over = if st.over_tau == 0 {
        "all within τ".to_string()
    } else {
        format!(
            "{} over τ ({} loading, {} budget, {} morphing in)",
            st.over_tau, st.over_tau_loading, st.over_tau_budget, st.over_tau_fading
        )
    };
    format!(
        "τ {:.2} px, worst ρ {:.2} px, {over} | {mode:?} | chunks/level [{}] | {} tris | {:.1} MB | {:.1} ms | {} loading",
        tau,
        st.max_rho_px,
        levels.join(" "),
        st.triangles,
        st.resident_bytes as f64 / (1 << 20) as f64,
        st.frame_ms,
        st.pending
    )
}

/// The flight directions the held keys ask for: arrows and PageUp/PageDown
/// any time, WASD/QE while the right mouse button is held.
fn moves(keys: &HashSet<KeyCode>, look_mode: bool) -> HashSet<Move> {
    let held = |k| keys.contains(&k);
    [
        (Move::Forward, KeyCode::ArrowUp, KeyCode::KeyW),
        (Move::Back, KeyCode::ArrowDown, KeyCode::KeyS),
        (Move::Right, KeyCode::ArrowRight, KeyCode::KeyD),
        (Move::Left, KeyCode::ArrowLeft, KeyCode::KeyA),
        (Move::Up, KeyCode::PageUp, KeyCode::KeyE),
        (Move::Down, KeyCode::PageDown, KeyCode::KeyQ),
    ]
    .into_iter()
    .filter(|&(_, any, fly)| held(any) || (look_mode && held(fly)))
    .map(|(m, _, _)| m)
    .chain((held(KeyCode::ShiftLeft) || held(KeyCode::ShiftRight)).then_some(Move::Fast))
    .collect()
}

struct WinState {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    depth: wgpu::TextureView,
    viewer: Viewer,
    cam: Camera,
    last: Instant,
    hud_at: Instant,
}

struct App {
    cli: Cli,
    state: Option<WinState>,
    keys: HashSet<KeyCode>,
    /// Right mouse button held: mouse-look, and WASD/QE fly.
    look_mode: bool,
    error: Option<anyhow::Error>,
}

impl App {
    fn start(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let [w, h] = self.cli.size;
        let window = Arc::new(
            el.create_window(
                Window::default_attributes()
                    .with_title("terrachunk-view")
                    .with_inner_size(winit::dpi::PhysicalSize::new(w, h)),
            )?,
        );
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle(Box::new(window.clone())));
        let surface = instance.create_surface(window.clone())?;
        // Probe the adapter's surface formats with a throwaway renderer-free request.
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))?;
        let caps = surface.get_capabilities(&adapter);
        drop(adapter);
        let format = caps.formats.iter().copied().find(|f| !f.is_srgb()).unwrap_or(caps.formats[0]);
        let renderer = Renderer::new(&instance, Some(&surface), Some(format))?;
        let size = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            color_space: wgpu::SurfaceColorSpace::Auto,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps.alpha_modes[0],
            view_formats: vec![],
        };
        surface.configure(&renderer.device, &config);
        let depth = renderer.depth_view([config.width, config.height]);
        let ts = Tileset::open(&self.cli.dir)?;
        let opts = options(&self.cli, &ts)?;
        let cam = camera(&self.cli, &ts);
        let viewer = Viewer::open(&self.cli.dir, renderer, Some(opts))?;
        println!("terrachunk-view on {}", viewer.renderer.adapter_info);
        println!("keys: hold the right mouse button to look and fly (WASD, Q/E down/up, shift ×4);");
        println!(
            "      arrows/PageUp/PageDown fly any time; f fog, l lighting, w shaded/wireframe/both, k skirts, \
             m morph schedule, +/- τ, q quit"
        );
        self.state = Some(WinState {
            window,
            surface,
            config,
            depth,
            viewer,
            cam,
            last: Instant::now(),
            hud_at: Instant::now(),
        });
        Ok(())
    }

    fn redraw(&mut self) {
        let Some(s) = self.state.as_mut() else { return };
        let now = Instant::now();
        let dt = (now - s.last).as_secs_f64().min(0.25);
        s.last = now;
        input::fly(&mut s.cam, &moves(&self.keys, self.look_mode), dt, s.viewer.tileset.bounds.0[1]);
        let frame = match s.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            _ => {
                s.surface.configure(&s.viewer.renderer.device, &s.config);
                return;
            }
        };
        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor::default());
        let size = [s.config.width, s.config.height];
        let st = s.viewer.frame(&s.cam, size, Target::Window(&view, &s.depth));
        s.viewer.renderer.queue.present(frame);
        if (now - s.hud_at).as_secs_f64() > 0.5 {
            s.hud_at = now;
            let line = hud(&st, s.viewer.opts.tau_px, s.viewer.opts.look.mode);
            s.window.set_title(&format!("terrachunk-view | {line}"));
            println!("{line}");
        }
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.state.is_none()
            && let Err(e) = self.start(el)
        {
            self.error = Some(e);
            el.exit();
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(size) => {
                if let Some(s) = self.state.as_mut() {
                    s.config.width = size.width.max(1);
                    s.config.height = size.height.max(1);
                    s.surface.configure(&s.viewer.renderer.device, &s.config);
                    s.depth = s.viewer.renderer.depth_view([s.config.width, s.config.height]);
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Right, .. } => {
                self.look_mode = state == ElementState::Pressed;
            }
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    if event.state == ElementState::Pressed {
                        self.keys.insert(code);
                    } else {
                        self.keys.remove(&code);
                    }
                }
                if event.state != ElementState::Pressed || event.repeat || self.look_mode {
                    return;
                }
                let Some(s) = self.state.as_mut() else { return };
                if let Key::Character(c) = &event.logical_key
                    && input::key(&mut s.viewer.opts, c.as_str()) == input::Action::Quit
                {
                    el.exit();
                }
            }
            WindowEvent::RedrawRequested => self.redraw(),
            _ => {}
        }
    }

    fn device_event(&mut self, _el: &ActiveEventLoop, _id: winit::event::DeviceId, event: DeviceEvent) {
        if let (DeviceEvent::MouseMotion { delta }, true, Some(s)) = (event, self.look_mode, self.state.as_mut()) {
            input::look(&mut s.cam, delta.0, delta.1);
        }
    }

    fn about_to_wait(&mut self, _el: &ActiveEventLoop) {
        if let Some(s) = &self.state {
            s.window.request_redraw();
        }
    }
}
