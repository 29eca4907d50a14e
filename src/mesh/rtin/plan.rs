//! The chunk tree the bintree needs, and the top squares that fit.

use std::collections::HashMap;

use super::tri::{P, Place, place, split_at};
use crate::quadtree::{ChunkTree, Span};

/// Plans the chunk tree the bintree needs: every chunk of a level is a
/// square of 2^k cells aligned to 2^k (clipped to the grid), and each level
/// halves the square. `leaf_cells` (≥ 2) bounds the leaves' side, which is
/// the largest power of two within it; `root_cells`, where set, the top
/// squares' side in the same way (otherwise one square covers the grid).
/// `refine_levels` are added at the bottom with the leaves' footprint, each
/// halving δ, as in [`ChunkTree::plan`].
pub fn plan(
    width: usize,
    height: usize,
    max_error_m: f64,
    root_cells: Option<u32>,
    leaf_cells: u32,
    refine_levels: u32,
) -> ChunkTree {
    let (wc, hc) = ((width - 1) as u32, (height - 1) as u32);
    let mut top = wc.max(hc).max(1).next_power_of_two();
    if let Some(r) = root_cells {
        top = top.min(floor_pow2(r.max(2)));
    }
    let leaf = floor_pow2(leaf_cells.max(2)).min(top);
    let spans = |cells: u32, side: u32| -> Vec<Span> {
        (0..cells.div_ceil(side)).map(|k| (k * side, ((k + 1) * side).min(cells))).collect()
    };
    let (mut xs, mut zs) = (Vec::new(), Vec::new());
    let mut side = top;
    loop {
        xs.push(spans(wc, side));
        zs.push(spans(hc, side));
        if side <= leaf {
            break;
        }
        side /= 2;
    }
    for _ in 0..refine_levels.min(crate::quadtree::MAX_REFINE_LEVELS) {
        xs.push(xs.last().expect("one level").clone());
        zs.push(zs.last().expect("one level").clone());
    }
    let depth = xs.len() - 1;
    let delta_m = (0..=depth).map(|l| max_error_m * f64::from(1u32 << (depth - l).min(31))).collect();
    ChunkTree { xs, zs, delta_m }
}

pub(super) fn floor_pow2(n: u32) -> u32 {
    1 << (31 - n.leading_zeros())
}

/// The side, in cells, of the squares a level of a [`plan`]ned tree cuts
/// the grid into (its spans are those squares clipped to the grid).
pub fn square_side(tree: &ChunkTree, level: u32) -> u32 {
    let [wx, wz] = tree.widest_cells(level);
    wx.max(wz).max(1).next_power_of_two()
}

/// The samples where the pass's error is infinite on a grid of `wc` × `hc`
/// cells, up to squares of `top`: a triangle there reaches past the grid,
/// or one below it does. They depend on the grid's size alone and lie
/// along its last column and row, as many as its cell counts are odd:
/// with an odd count every triangle along that side splits down to one
/// cell, at every level.
pub(super) fn forced_points(wc: u32, hc: u32, top: u32) -> std::collections::HashSet<P> {
    let mut forced = std::collections::HashSet::new();
    let mut c = 2;
    while c <= top {
        for square in [false, true] {
            let h = c / 2;
            // A triangle split at m, and everything below it, lies within
            // 2c of m: farther from the last column and row, m is finite.
            let near = |x: u32, z: u32| x + 2 * c > wc || z + 2 * c > hc;
            let mut z = if square { h } else { 0 };
            while z <= hc {
                let first = if square || z.is_multiple_of(c) { h } else { 0 };
                // Only the columns near the last one, unless the row is near the last.
                let mut x = if z + 2 * c > hc { first } else { first.max(wc.saturating_sub(2 * c)) };
                x = first + (x - first) / c * c;
                while x <= wc {
                    if near(x, z)
                        && split_at(c, square, (x, z)).into_iter().flatten().any(|t| match place(&t, wc, hc) {
                            Place::Outside => false,
                            Place::Straddles => true,
                            Place::Inside => {
                                t.children((x, z)).iter().any(|k| k.midpoint().is_some_and(|km| forced.contains(&km)))
                            }
                        })
                    {
                        forced.insert((x, z));
                    }
                    x += c;
                }
                z += if square { c } else { h };
            }
        }
        c *= 2;
    }
    forced
}

/// The top squares' side (as `root_cells`) a bintree tree over `width` ×
/// `height` samples needs so that no top chunk spends more than half of
/// `max_vertices` on [`forced_points`]: `root_cells` itself where it
/// already does. Grids whose cell counts are odd, or divisible by only a
/// small power of two, get narrower top chunks when large.
pub fn fitting_root(width: usize, height: usize, root_cells: Option<u32>, max_vertices: usize) -> Option<u32> {
    let (wc, hc) = ((width - 1) as u32, (height - 1) as u32);
    let mut top = wc.max(hc).max(1).next_power_of_two();
    if let Some(r) = root_cells {
        top = top.min(floor_pow2(r.max(2)));
    }
    let forced = forced_points(wc, hc, top);
    let natural = top;
    while top > 2 {
        // Each forced point counts in every closed square it lies in.
        let mut counts: HashMap<P, usize> = HashMap::new();
        for &(x, z) in &forced {
            let (i, j) = (x / top, z / top);
            let is = [Some(i), (x.is_multiple_of(top) && i > 0).then(|| i - 1)];
            let js = [Some(j), (z.is_multiple_of(top) && j > 0).then(|| j - 1)];
            for jj in js.into_iter().flatten() {
                for ii in is.into_iter().flatten() {
                    *counts.entry((ii, jj)).or_default() += 1;
                }
            }
        }
        if counts.values().max().map_or(0, |&n| n + 4) <= max_vertices / 2 {
            break;
        }
        top /= 2;
    }
    if top == natural { root_cells } else { Some(top) }
}
