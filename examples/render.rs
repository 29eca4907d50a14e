//! Renders a tileset on the CPU into a PNG, for the pictures in the README.
//!
//! - `render OUT picture.png [width_px]`: the finest chunks top-down,
//!   hillshade from the triangles' own normals with a hypsometric tint,
//!   triangle edges in dark lines and chunk borders in red.
//! - `render OUT picture.png [width_px] --textured`: the same chunks
//!   top-down, each drawn with its own texture tile (bilinear, clamp to
//!   edge, as a glTF viewer samples it), chunk borders in red.
//! - `render OUT picture.png [width_px] --chunk L/x/y`: one chunk, textured,
//!   in an oblique view from the south-east (orthographic, true vertical
//!   scale), skirts included.
//!
//! `cargo run --release --example render -- OUT/ picture.png 1024 --textured`

use std::path::{Path, PathBuf};

use terrachunk::verify::{ChunkFile, read_chunk};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let flag = |name: &str| args.iter().position(|a| a == name);
    let dir = PathBuf::from(&args[1]);
    let png = PathBuf::from(&args[2]);
    let width: u32 = args.get(3).and_then(|w| w.parse().ok()).unwrap_or(1024);
    if let Some(i) = flag("--chunk") {
        let path = dir.join(format!("tiles/{}.glb", args[i + 1]));
        oblique(&path, width).save(&png).unwrap();
        return;
    }
    let ts: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    let mut leaves = Vec::new();
    let mut stack = vec![&ts["root"]];
    while let Some(t) = stack.pop() {
        match t["children"].as_array() {
            Some(kids) => stack.extend(kids),
            None => leaves.push(dir.join(t["content"]["uri"].as_str().unwrap())),
        }
    }
    leaves.sort();
    let img = if flag("--textured").is_some() { top_down_textured(&leaves, width) } else { top_down(&leaves, width) };
    img.save(&png).unwrap();
}

/// World bounds of the chunks' surfaces.
fn bounds(chunks: &[ChunkFile]) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for c in chunks {
        for p in &c.surface.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    (lo, hi)
}

fn top_down(leaves: &[PathBuf], width: u32) -> image::RgbImage {
    let chunks: Vec<_> = leaves.iter().map(|p| read_chunk(p).unwrap()).collect();
    let (lo, hi) = bounds(&chunks);
    let scale = f64::from(width) / (hi[0] - lo[0]);
    let height = ((hi[2] - lo[2]) * scale).ceil() as u32;
    let mut img = image::RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    let px = |p: &[f64; 3]| ((p[0] - lo[0]) * scale, (p[2] - lo[2]) * scale);
    let sun = [-0.5f64, 0.7, -0.5];
    let sl = (sun[0] * sun[0] + sun[1] * sun[1] + sun[2] * sun[2]).sqrt();
    for c in &chunks {
        let pos = &c.surface.positions;
        for t in &c.surface.triangles {
            let [a, b, d] = t.map(|i| pos[i as usize]);
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [d[0] - a[0], d[1] - a[1], d[2] - a[2]];
            let mut n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
            if n[1] < 0.0 {
                n = n.map(|x| -x);
            }
            let nl = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-12);
            let shade = ((n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]) / (nl * sl)).clamp(0.0, 1.0);
            let h = ((a[1] + b[1] + d[1]) / 3.0 - lo[1]) / (hi[1] - lo[1]).max(1e-9);
            let tint = [0.35 + 0.5 * h, 0.55 + 0.2 * (1.0 - (2.0 * h - 1.0).abs()), 0.3 + 0.4 * h];
            let col = image::Rgb(tint.map(|t| (255.0 * t * (0.35 + 0.65 * shade)).clamp(0.0, 255.0) as u8));
            let (pa, pb, pd) = (px(&a), px(&b), px(&d));
            raster(&mut img, None, [pa, pb, pd], [0.0; 3], |_| col);
            for (p, q) in [(pa, pb), (pb, pd), (pd, pa)] {
                line(&mut img, p, q, image::Rgb([40, 40, 40]), 0.35);
            }
        }
        chunk_border(&mut img, c, &px);
    }
    img
}

/// A chunk file with its decoded base colour image.
fn textured(path: &Path) -> (ChunkFile, image::RgbImage) {
    let c = read_chunk(path).unwrap();
    let (_, _, images) = gltf::import(path).unwrap();
    let d = &images[0];
    let img = match d.format {
        gltf::image::Format::R8G8B8 => image::RgbImage::from_raw(d.width, d.height, d.pixels.clone()).unwrap(),
        other => panic!("{}: image format {other:?}", path.display()),
    };
    (c, img)
}

/// Bilinear, clamp to edge: what a glTF viewer's LINEAR sampler shows.
fn sample(img: &image::RgbImage, uv: [f64; 2]) -> image::Rgb<u8> {
    let (w, h) = (img.width() as f64, img.height() as f64);
    let x = (uv[0] * w - 0.5).clamp(0.0, w - 1.0);
    let y = (uv[1] * h - 0.5).clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(img.width() - 1), (y0 + 1).min(img.height() - 1));
    let (fx, fy) = (x - f64::from(x0), y - f64::from(y0));
    let mix = |a: &image::Rgb<u8>, b: &image::Rgb<u8>, f: f64| {
        [0, 1, 2].map(|c| f64::from(a[c]) * (1.0 - f) + f64::from(b[c]) * f)
    };
    let top = mix(img.get_pixel(x0, y0), img.get_pixel(x1, y0), fx);
    let bottom = mix(img.get_pixel(x0, y1), img.get_pixel(x1, y1), fx);
    image::Rgb([0, 1, 2].map(|c| (top[c] * (1.0 - fy) + bottom[c] * fy).round() as u8))
}

fn top_down_textured(leaves: &[PathBuf], width: u32) -> image::RgbImage {
    let chunks: Vec<_> = leaves.iter().map(|p| textured(p)).collect();
    let files: Vec<ChunkFile> = chunks.iter().map(|(c, _)| c.clone()).collect();
    let (lo, hi) = bounds(&files);
    let scale = f64::from(width) / (hi[0] - lo[0]);
    let height = ((hi[2] - lo[2]) * scale).ceil() as u32;
    let mut img = image::RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    let px = |p: &[f64; 3]| ((p[0] - lo[0]) * scale, (p[2] - lo[2]) * scale);
    for (c, tex) in &chunks {
        let s = &c.surface;
        for t in &s.triangles {
            let [a, b, d] = t.map(|i| i as usize);
            let uv = [a, b, d].map(|i| [f64::from(s.uv[i][0]), f64::from(s.uv[i][1])]);
            let screen = [a, b, d].map(|i| px(&s.positions[i]));
            raster(&mut img, None, screen, [0.0; 3], |w| {
                sample(tex, [0, 1].map(|k| w[0] * uv[0][k] + w[1] * uv[1][k] + w[2] * uv[2][k]))
            });
        }
        chunk_border(&mut img, c, &px);
    }
    img
}

/// One textured chunk seen from the south-east, 35° above the horizon.
fn oblique(path: &Path, width: u32) -> image::RgbImage {
    let (c, tex) = textured(path);
    let (az, el) = (135f64.to_radians(), 35f64.to_radians());
    // Screen right and up, and the viewing direction, for an orthographic
    // camera looking toward azimuth az + 180° (x east, y up, z south).
    let right = [-az.cos(), 0.0, -az.sin()];
    let fwd = [-az.sin() * el.cos(), -el.sin(), az.cos() * el.cos()];
    let up = [
        right[1] * fwd[2] - right[2] * fwd[1],
        right[2] * fwd[0] - right[0] * fwd[2],
        right[0] * fwd[1] - right[1] * fwd[0],
    ];
    let up = if up[1] < 0.0 { up.map(|v| -v) } else { up };
    let dot = |a: [f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let parts: Vec<_> = std::iter::once(&c.surface).chain(c.skirt.iter()).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in parts.iter().flat_map(|s| &s.positions) {
        let q = [dot(right, p), dot(up, p)];
        for a in 0..2 {
            lo[a] = lo[a].min(q[a]);
            hi[a] = hi[a].max(q[a]);
        }
    }
    let margin = 0.03 * (hi[0] - lo[0]);
    let scale = f64::from(width) / (hi[0] - lo[0] + 2.0 * margin);
    let height = ((hi[1] - lo[1] + 2.0 * margin) * scale).ceil() as u32;
    let mut img = image::RgbImage::from_pixel(width, height, image::Rgb([236, 240, 244]));
    let mut depth = vec![f64::INFINITY; (width * height) as usize];
    for s in parts {
        for t in &s.triangles {
            let [a, b, d] = t.map(|i| i as usize);
            let uv = [a, b, d].map(|i| [f64::from(s.uv[i][0]), f64::from(s.uv[i][1])]);
            let screen = [a, b, d].map(|i| {
                let p = &s.positions[i];
                ((dot(right, p) - lo[0] + margin) * scale, (hi[1] - dot(up, p) + margin) * scale)
            });
            let z = [a, b, d].map(|i| dot(fwd, &s.positions[i]));
            raster(&mut img, Some(&mut depth), screen, z, |w| {
                sample(&tex, [0, 1].map(|k| w[0] * uv[0][k] + w[1] * uv[1][k] + w[2] * uv[2][k]))
            });
        }
    }
    img
}

fn chunk_border(img: &mut image::RgbImage, c: &ChunkFile, px: &dyn Fn(&[f64; 3]) -> (f64, f64)) {
    let [x0, x1, z0, z1] = c.footprint.map(f64::from);
    let [sx, sz] = c.spacing_m;
    let corners = [(x0, z0), (x1, z0), (x1, z1), (x0, z1)].map(|(x, z)| px(&[x * sx, 0.0, z * sz]));
    for k in 0..4 {
        line(img, corners[k], corners[(k + 1) % 4], image::Rgb([200, 30, 30]), 1.0);
    }
}

/// Fills a screen triangle; `colour` gets the barycentric weights of the
/// pixel centre. With `depth`, keeps the nearest (smallest `z`) surface.
fn raster(
    img: &mut image::RgbImage,
    mut depth: Option<&mut Vec<f64>>,
    p: [(f64, f64); 3],
    z: [f64; 3],
    colour: impl Fn([f64; 3]) -> image::Rgb<u8>,
) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let [a, b, c] = p;
    let x0 = a.0.min(b.0).min(c.0).floor().max(0.0) as i64;
    let x1 = (a.0.max(b.0).max(c.0).ceil() as i64).min(w - 1);
    let y0 = a.1.min(b.1).min(c.1).floor().max(0.0) as i64;
    let y1 = (a.1.max(b.1).max(c.1).ceil() as i64).min(h - 1);
    let e = |p: (f64, f64), q: (f64, f64), x: f64, y: f64| (q.0 - p.0) * (y - p.1) - (q.1 - p.1) * (x - p.0);
    let area = e(a, b, c.0, c.1);
    if area == 0.0 {
        return;
    }
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (fx, fy) = (x as f64 + 0.5, y as f64 + 0.5);
            let wts = [e(b, c, fx, fy) / area, e(c, a, fx, fy) / area, e(a, b, fx, fy) / area];
            if wts.iter().all(|&v| v >= -1e-9) {
                if let Some(d) = depth.as_deref_mut() {
                    let zz = wts[0] * z[0] + wts[1] * z[1] + wts[2] * z[2];
                    let k = (y * w + x) as usize;
                    if zz >= d[k] {
                        continue;
                    }
                    d[k] = zz;
                }
                img.put_pixel(x as u32, y as u32, colour(wts));
            }
        }
    }
}

fn line(img: &mut image::RgbImage, a: (f64, f64), b: (f64, f64), col: image::Rgb<u8>, alpha: f64) {
    let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            let p = img.get_pixel_mut(x as u32, y as u32);
            for ch in 0..3 {
                p.0[ch] = (f64::from(p.0[ch]) * (1.0 - alpha) + f64::from(col.0[ch]) * alpha) as u8;
            }
        }
    }
}
