//! Renders a tileset's finest chunks top-down into a PNG: hillshade from the
//! triangles' own normals with a hypsometric tint, triangle edges in dark
//! lines and chunk borders in red. Used for the picture in the README.
//!
//! `cargo run --release --example render -- OUT/ picture.png [width_px]`

use std::path::PathBuf;

use terrachunk::verify::read_chunk;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = PathBuf::from(&args[1]);
    let png = PathBuf::from(&args[2]);
    let width: u32 = args.get(3).and_then(|w| w.parse().ok()).unwrap_or(1024);
    let ts: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
    let mut leaves = Vec::new();
    let mut stack = vec![&ts["root"]];
    while let Some(t) = stack.pop() {
        match t["children"].as_array() {
            Some(kids) => stack.extend(kids),
            None => leaves.push(dir.join(t["content"]["uri"].as_str().unwrap())),
        }
    }
    let chunks: Vec<_> = leaves.iter().map(|p| read_chunk(p).unwrap()).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for c in &chunks {
        for p in &c.surface.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
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
            fill(&mut img, pa, pb, pd, col);
            for (p, q) in [(pa, pb), (pb, pd), (pd, pa)] {
                line(&mut img, p, q, image::Rgb([40, 40, 40]), 0.35);
            }
        }
        let sp = c
            .surface
            .positions
            .iter()
            .fold((f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY), |m, p| {
                (m.0.min(p[0]), m.1.min(p[2]), m.2.max(p[0]), m.3.max(p[2]))
            });
        let corners = [(sp.0, sp.1), (sp.2, sp.1), (sp.2, sp.3), (sp.0, sp.3)].map(|(x, z)| px(&[x, 0.0, z]));
        for k in 0..4 {
            line(&mut img, corners[k], corners[(k + 1) % 4], image::Rgb([200, 30, 30]), 1.0);
        }
    }
    img.save(&png).unwrap();
}

fn fill(img: &mut image::RgbImage, a: (f64, f64), b: (f64, f64), c: (f64, f64), col: image::Rgb<u8>) {
    let (w, h) = (img.width() as i64, img.height() as i64);
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
            let (w0, w1, w2) = (e(b, c, fx, fy) / area, e(c, a, fx, fy) / area, e(a, b, fx, fy) / area);
            if w0 >= -1e-9 && w1 >= -1e-9 && w2 >= -1e-9 {
                img.put_pixel(x as u32, y as u32, col);
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
