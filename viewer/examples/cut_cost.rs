//! What a viewer draws along a flythrough, with every chunk resident: the
//! cost side of a tileset's chunk size (docs/settings.md, "Chunk size").
//!
//!     cargo run --release -p terrachunk-view --example cut_cost -- DIR FLYTHROUGH.json [TAU] [WxH]
//!
//! Each frame's cut is `terrachunk::lod::select` (ρ = δ·K/D ≤ τ, else the
//! children) with the viewer's frustum culling (`Camera::frustum`), as the
//! viewer chooses it once everything is loaded. Per frame it counts the
//! drawn chunks, their surface and skirt triangles and their file bytes (a
//! chunk's triangle counts come from its .glb's JSON: the index accessors of
//! the primitives by `extras.role`), and prints the median and the mean.

use std::collections::HashMap;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use terrachunk::lod::{self, LodView, MorphSchedule};
use terrachunk_view::camera::Camera;
use terrachunk_view::flythrough::Flythrough;
use terrachunk_view::scene::Tileset;

/// Surface triangles, skirt triangles and file bytes of one chunk.
#[derive(Clone, Copy, Default)]
struct Cost {
    surface: u64,
    skirt: u64,
    bytes: u64,
}

fn chunk_cost(path: &std::path::Path) -> Result<Cost> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let glb = gltf::Glb::from_slice(&bytes).with_context(|| format!("{}: not a .glb", path.display()))?;
    let json: serde_json::Value =
        serde_json::from_slice(&glb.json).with_context(|| format!("{}: JSON chunk", path.display()))?;
    let mut cost = Cost { bytes: bytes.len() as u64, ..Cost::default() };
    for p in json["meshes"][0]["primitives"].as_array().into_iter().flatten() {
        let count = p["indices"].as_u64().and_then(|i| json["accessors"][i as usize]["count"].as_u64()).unwrap_or(0);
        match p["extras"]["role"].as_str() {
            Some("skirt") => cost.skirt += count / 3,
            _ => cost.surface += count / 3,
        }
    }
    Ok(cost)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        bail!("usage: cut_cost DIR FLYTHROUGH.json [TAU] [WxH]");
    }
    let dir = PathBuf::from(&args[0]);
    let tau: f64 = args.get(2).map_or(Ok(2.0), |s| s.parse()).context("TAU")?;
    let size: [u32; 2] = match args.get(3).and_then(|s| s.split_once('x')) {
        Some((w, h)) => [w.parse()?, h.parse()?],
        None => [1280, 720],
    };
    let ts = Tileset::open(&dir)?;
    let base = Camera { eye: [0.0; 3], yaw_deg: 0.0, pitch_deg: 0.0, hfov_deg: 60.0, near_m: 1.0 };
    let frames = Flythrough::read(std::path::Path::new(&args[1]))?.frames(&base);
    let aspect = f64::from(size[0]) / f64::from(size[1]);
    // The viewer's K: ρ bounds the shift anywhere in the image.
    let k = lod::screen_k_bound([f64::from(size[0]), f64::from(size[1])], base.hfov_deg.to_radians());
    let mut costs: HashMap<usize, Cost> = HashMap::new();
    let mut columns: [Vec<f64>; 4] = Default::default();
    for cam in &frames {
        let frustum = cam.frustum(aspect);
        let view =
            LodView { eye: cam.eye, k, eye_ahead: None, eye_next: None, tau_px: tau, schedule: MorphSchedule::Bounded };
        let sel = lod::select(
            &ts.tree,
            &view,
            |_| true,
            |n| frustum.intersects_box(ts.tree.nodes[n].min, ts.tree.nodes[n].max),
        );
        let mut sum = Cost::default();
        for d in &sel.draws {
            let c = match costs.get(&d.node) {
                Some(&c) => c,
                None => *costs.entry(d.node).or_insert(chunk_cost(&ts.chunk_path(d.node))?),
            };
            sum.surface += c.surface;
            sum.skirt += c.skirt;
            sum.bytes += c.bytes;
        }
        for (col, v) in columns.iter_mut().zip([sel.draws.len() as u64, sum.surface, sum.skirt, sum.bytes]) {
            col.push(v as f64);
        }
    }
    println!("{}: {} frames at τ {tau} px, {}x{}, hfov 60°", dir.display(), frames.len(), size[0], size[1]);
    for (name, col) in ["chunks drawn", "surface triangles", "skirt triangles", "bytes drawn"].iter().zip(&mut columns)
    {
        let mean = col.iter().sum::<f64>() / col.len().max(1) as f64;
        println!("  {name}: median {:.0}, mean {mean:.0}", median(col));
    }
    Ok(())
}
