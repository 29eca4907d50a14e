//! Skirts: a vertical strip hanging from each border of a chunk (Ulrich 2002,
//! §4.2) so that no crack shows between chunks of different levels.
//!
//! How deep: along a border, any neighbour at level L−1 or finer, in any
//! morph state, shows a surface within δ(L−2) of each valid sample of the
//! border line (a chunk at level L−1 blending toward its parent is within
//! δ(L−2); finer ones are closer). Each bottom vertex therefore sits at the
//! lowest of (the valid samples, the vertex heights and their parent heights)
//! between its two neighbouring border vertices, minus δ(max(L−2, 0)).
//! Between two bottom vertices the bottom is linear and each end is below
//! every sample of both windows, so the whole strip reaches below any such
//! neighbour, and no lower. Bottom vertices do not morph (delta 0): they are
//! already below every morph state.

use crate::chunk::Part;
use crate::mesh::grid::Grid;
use crate::quadtree::Span;

/// Builds the skirt of a chunk from its finished surface part, and for each
/// skirt vertex the surface vertex it hangs from ([`Hang`]).
///
/// `grid_xz[v]` are the surface vertices' grid coordinates, `parent_h[v]`
/// their heights on the parent surface; `margin_m` is δ(max(L−2, 0)).
pub fn build_skirt(
    grid: &Grid,
    footprint: (Span, Span),
    surface: &Part,
    grid_xz: &[(f64, f64)],
    parent_h: &[f64],
    margin_m: f64,
) -> (Part, Vec<Hang>) {
    let ((x0, x1), (z0, z1)) = footprint;
    // The drawn edges along the borders (both ends on the same border line).
    let on_border = |a: u32, b: u32| {
        let ((xa, za), (xb, zb)) = (grid_xz[a as usize], grid_xz[b as usize]);
        let (fx, fz) =
            (|x: f64| x == f64::from(x0) || x == f64::from(x1), |z: f64| z == f64::from(z0) || z == f64::from(z1));
        (xa == xb && fx(xa)) || (za == zb && fz(za))
    };
    let mut edge_set: Vec<(u32, u32)> = surface
        .indices
        .chunks_exact(3)
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .filter(|&(a, b)| on_border(a, b))
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edge_set.sort_unstable();
    let mut out = Part::default();
    let mut tops = Vec::new();
    // (vertical?, fixed coordinate, outward direction sign)
    let sides = [(false, z0, -1.0), (false, z1, 1.0), (true, x0, -1.0), (true, x1, 1.0)];
    for (vertical, coord, _sign) in sides {
        let c = f64::from(coord);
        let mut on: Vec<(f64, u32)> = grid_xz
            .iter()
            .enumerate()
            .filter_map(|(k, &(x, z))| {
                let (along, across) = if vertical { (z, x) } else { (x, z) };
                (across == c).then_some((along, k as u32))
            })
            .collect();
        on.sort_by(|a, b| a.0.total_cmp(&b.0));
        super::chain_ties(&mut on, |a, b| edge_set.binary_search(&(a.min(b), a.max(b))).is_ok());
        if on.len() < 2 {
            continue;
        }
        let sample = |t: i64| -> f32 {
            let (j, i) = if vertical { (coord as usize, t as usize) } else { (t as usize, coord as usize) };
            grid.heights[i * grid.width + j]
        };
        let bottoms: Vec<f64> = (0..on.len())
            .map(|k| {
                let lo = on[k.saturating_sub(1)].0;
                let hi = on[(k + 1).min(on.len() - 1)].0;
                let mut m = f64::INFINITY;
                for w in on[k.saturating_sub(1)..=(k + 1).min(on.len() - 1)].iter() {
                    m = m.min(surface.positions[w.1 as usize][1]).min(parent_h[w.1 as usize]);
                }
                for t in (lo.ceil() as i64)..=(hi.floor() as i64) {
                    let h = sample(t);
                    if !h.is_nan() {
                        m = m.min(f64::from(h));
                    }
                }
                m - margin_m
            })
            .collect();
        let base = out.positions.len() as u32;
        for (k, &(_, v)) in on.iter().enumerate() {
            let p = surface.positions[v as usize];
            let n = surface.normals[v as usize];
            out.positions.push(p);
            out.normals.push(n);
            out.morph_dy.push(surface.morph_dy[v as usize]);
            out.positions.push([p[0], bottoms[k], p[2]]);
            out.normals.push(n);
            out.morph_dy.push(0.0);
            tops.extend([Hang { surface: v, top: true }, Hang { surface: v, top: false }]);
        }
        for k in 0..on.len() - 1 {
            let (a, b) = (on[k].1, on[k + 1].1);
            if edge_set.binary_search(&(a.min(b), a.max(b))).is_err() {
                continue; // that stretch of border is over nodata: no surface, no skirt
            }
            let (ta, ba, tb, bb) =
                (base + 2 * k as u32, base + 2 * k as u32 + 1, base + 2 * k as u32 + 2, base + 2 * k as u32 + 3);
            out.indices.extend_from_slice(&[ta, ba, tb, tb, ba, bb]);
        }
    }
    // Drop vertices no triangle uses (border stretches over nodata).
    compact(out, tops)
}

/// Where a skirt vertex hangs from: its surface vertex, as the top (at the
/// same place) or as the bottom below it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hang {
    /// Index of the surface vertex.
    pub surface: u32,
    /// The top (the surface vertex's place), else the bottom.
    pub top: bool,
}

/// Removes vertices no triangle references, keeping order (and the same
/// entries of `tops`).
fn compact(mut p: Part, tops: Vec<Hang>) -> (Part, Vec<Hang>) {
    let mut remap = vec![u32::MAX; p.positions.len()];
    let mut n = 0u32;
    for &i in &p.indices {
        if remap[i as usize] == u32::MAX {
            remap[i as usize] = 0;
        }
    }
    let mut out = Part::default();
    let mut kept_tops = Vec::new();
    for (k, r) in remap.iter_mut().enumerate() {
        if *r != u32::MAX {
            *r = n;
            n += 1;
            out.push_from(&p, k);
            kept_tops.push(tops[k]);
        }
    }
    out.indices = p.indices.drain(..).map(|i| remap[i as usize]).collect();
    (out, kept_tops)
}
