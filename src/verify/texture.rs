//! The texture checks: texel size against δ/τ_max and the source, texture
//! coordinates against the footprint, the material and sampler, and the
//! border texels neighbours share.

use super::TextureCheck;
use super::read::{ChunkFile, ImageEdges, Prim};
use crate::output::tileset::TilesetExtras;
use crate::texture::{Limit, TextureExtras};

/// Why a tile may exceed T_g ≤ δ/τ_max.
#[derive(Clone, Copy, PartialEq, PartialOrd)]
pub(super) enum Texel {
    Bound,
    AtSource,
    Capped,
}

/// How far neighbours' border texels may differ: `(largest channel
/// difference, largest RMS over one edge)`. PNG: not at all. JPEG: each
/// side carries its own compression error, which grows with the texel-to-
/// texel contrast; the bands are the worst measured on the fixtures (2.4 km
/// topo-bathymetry in 31-texel tiles: max 19 / RMS 6.7 at quality 95,
/// 64 / 17.9 at 80, 84 / 20.2 at 50, 97 / 27.5 at 20) with a third or more
/// to spare. They catch a wrong or shifted image on smooth ground, not a
/// one-texel slip on rough ground; the texel positions themselves are the
/// PNG check's to prove, the encoding being the only difference.
pub(super) fn seam_tolerance(tx: &TextureExtras) -> (u8, f64) {
    match tx.jpeg_quality {
        None => (0, 0.0),
        Some(q) if q >= 90 => (48, 12.0),
        Some(q) if q >= 70 => (96, 24.0),
        Some(q) if q >= 50 => (112, 28.0),
        Some(_) => (144, 36.0),
    }
}

/// The texture of one chunk: texel size against δ/τ_max and the source,
/// TEXCOORDs against the footprint, material and sampler. Returns T_g and
/// why it may exceed the bound.
pub(super) fn check_texture(
    c: &ChunkFile,
    ex: &TilesetExtras,
    tx: &TextureExtras,
    problems: &mut Vec<String>,
) -> Option<(f64, Texel)> {
    let Some(t) = &c.texture else {
        problems.push("has no base colour texture, but the tileset says its chunks are textured".into());
        return None;
    };
    problems.extend(t.contract.iter().cloned());
    let [x0, x1, z0, z1] = c.footprint;
    let extents = [f64::from(x1 - x0) * ex.spacing_m[0], f64::from(z1 - z0) * ex.spacing_m[1]];
    let bound_m = c.delta_m / ex.tau_max_px;
    let level = tx.levels.iter().find(|l| l.level == c.key.level);
    let cap_stated = level.is_some_and(|l| l.limit == Limit::MaxTexturePx && !l.bound_holds);
    let judge = |what: &str, img: &ImageEdges, source_m: [f64; 2], problems: &mut Vec<String>| {
        let mut worst = (0.0f64, Texel::Bound);
        for (a, n) in [img.width, img.height].into_iter().enumerate() {
            let texel_m = extents[a] / f64::from(n - 1);
            let axis = ["across", "down"][a];
            if n > 2 && texel_m < source_m[a] * (1.0 - 1e-9) {
                problems.push(format!(
                    "{what} texels {axis} are {texel_m:.4} m apart, finer than the source's {:.4} m",
                    source_m[a]
                ));
            }
            let why = if texel_m <= bound_m * (1.0 + 1e-9) {
                Texel::Bound
            } else if extents[a] / f64::from(n) < source_m[a] * (1.0 + 1e-9) {
                Texel::AtSource // one more texel would be finer than the source
            } else if n == tx.max_texture_px && cap_stated {
                Texel::Capped
            } else {
                problems.push(format!(
                    "{what} T_g {axis} = {texel_m:.4} m exceeds δ/τ_max = {bound_m:.4} m with {n} texels,                      though neither its source nor a stated max_texture_px stops a larger tile"
                ));
                Texel::Bound
            };
            if texel_m > worst.0 {
                worst.0 = texel_m;
            }
            worst.1 = if why > worst.1 { why } else { worst.1 };
        }
        worst
    };
    let found = judge("colour", &t.colour, tx.source_texel_m, problems);
    let mut sets = vec![(0u32, [t.colour.width, t.colour.height])];
    if let Some((nm, set)) = &t.normal {
        judge("normal map", nm, ex.spacing_m, problems);
        if *set == 0 && [nm.width, nm.height] != [t.colour.width, t.colour.height] {
            problems.push("the normal map uses TEXCOORD_0 but differs in size from the colour".into());
        }
        if *set == 1 {
            sets.push((1, [nm.width, nm.height]));
        }
    }
    for (role, prim) in std::iter::once(("surface", &c.surface)).chain(c.skirt.iter().map(|s| ("skirt", s))) {
        for &(set, texels) in &sets {
            let uv = if set == 0 { &prim.uv } else { &prim.uv1 };
            // u16 normalized coordinates round by half of 1/65535. (The
            // coordinate is made from the position as written, on the grid:
            // `Frame::on_grid`.)
            let rounding = c.quantization_m.map_or(0.0, |_| 0.5 / 65535.0);
            if let Some(p) = check_uv(prim, uv, c.footprint, ex.spacing_m, texels, rounding) {
                problems.push(format!("{role} TEXCOORD_{set}: {p}"));
            }
        }
    }
    Some(found)
}

/// Every vertex's TEXCOORD lies in [0, 1] at
/// `(½ + (n − 1)·(x − x0)/(x1 − x0)) / n` (and likewise for z): the
/// footprint mapped exactly onto the texel centres.
fn check_uv(
    prim: &Prim,
    uv: &[[f32; 2]],
    fp: [u32; 4],
    spacing: [f64; 2],
    texels: [u32; 2],
    rounding: f64,
) -> Option<String> {
    if uv.len() != prim.positions.len() {
        return Some(format!("{} coordinates for {} vertices", uv.len(), prim.positions.len()));
    }
    let [x0, x1, z0, z1] = fp;
    let spans = [(x0, x1), (z0, z1)];
    // f32 rounding of the chunk-local position, then of the coordinate.
    let tol = |a: usize| {
        let cells = f64::from(spans[a].1 - spans[a].0);
        1e-6 + rounding + 8.0 * f64::from(f32::EPSILON) * prim.local_extent[2 * a] / spacing[a] / cells
    };
    for (p, t) in prim.positions.iter().zip(uv) {
        for a in 0..2 {
            let (lo, hi) = spans[a];
            let n = f64::from(texels[a]);
            let g = p[2 * a] / spacing[a];
            let want = (0.5 + (n - 1.0) * (g - f64::from(lo)) / f64::from(hi - lo)) / n;
            let got = f64::from(t[a]);
            if !(0.0..=1.0).contains(&got) || (got - want).abs() > tol(a) {
                return Some(format!(
                    "vertex at ({:.3}, {:.3}) m has {} = {got}, expected {want} (footprint onto the texel centres)",
                    p[0],
                    p[2],
                    ["u", "v"][a]
                ));
            }
        }
    }
    None
}

/// The border texels of `a` and its east or south neighbour `b`: the same
/// number, and equal within the format's tolerance.
pub(super) fn compare_seam(a: &ChunkFile, b: &ChunkFile, east: bool, tc: &mut TextureCheck) -> Result<(), String> {
    let (Some(ta), Some(tb)) = (&a.texture, &b.texture) else {
        return Ok(()); // reported per chunk
    };
    let mut pairs = vec![("colour", &ta.colour, &tb.colour, tc.seam_tolerance, tc.seam_rms_tolerance)];
    if let (Some((na, _)), Some((nb, _))) = (&ta.normal, &tb.normal) {
        pairs.push(("normal map", na, nb, 0, 0.0)); // always PNG
    }
    for (what, ia, ib, tol, rms_tol) in pairs {
        let (ea, eb) = if east { (&ia.east, &ib.west) } else { (&ia.south, &ib.north) };
        if ea.len() != eb.len() {
            return Err(format!("{what}: {} vs {} texels along the shared edge", ea.len(), eb.len()));
        }
        let diffs: Vec<u8> = ea.iter().zip(eb).flat_map(|(p, q)| (0..3).map(|c| p[c].abs_diff(q[c]))).collect();
        let diff = diffs.iter().copied().max().unwrap_or(0);
        let rms = (diffs.iter().map(|&d| f64::from(d).powi(2)).sum::<f64>() / diffs.len().max(1) as f64).sqrt();
        if what == "colour" {
            tc.max_seam_diff = tc.max_seam_diff.max(diff);
            tc.max_seam_rms = tc.max_seam_rms.max(rms);
        }
        if diff > tol || rms > rms_tol {
            return Err(format!(
                "{what}: border texels differ by up to {diff}, RMS {rms:.2} (allowed {tol}, RMS {rms_tol:.2})"
            ));
        }
    }
    Ok(())
}
