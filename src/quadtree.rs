//! Plan: the error-bounded quadtree's footprints and δ per level.
//!
//! The grid's cells (`width − 1` × `height − 1`) are cut into near-square
//! top-level chunks (one, unless the grid is at least 1.5 times as wide as
//! it is tall or vice versa, or `root_cells` bounds their width: then as
//! many as that takes, each the top of its own tree), then every chunk is cut at its integer midpoint along
//! each axis that is at least 2 cells long. The cuts along x depend only on x
//! and those along z only on z, so each level's chunks form a tensor-product
//! grid: same-level neighbours always share a whole edge, and a chunk's key
//! `(L, x, y)` is just the index of its column and row interval at level L.
//!
//! Level `D` is the first at which no chunk is wider than `leaf_cells`, so a
//! leaf at full sample density still fits `max_chunk_vertices` (for leaves
//! of at most `config::dense_leaf_cells`). Where a coarse chunk cannot meet
//! its δ within `max_chunk_vertices` (rough ground against a small
//! error), the planner adds levels at the bottom that keep their parent's
//! footprint and only halve δ: every δ above doubles, the leaves keep their
//! size, and the pyramid still reaches its top chunks. δ(L) = max_error·2^(D−L)
//! (Ulrich 2002, §3: each level halves the error of the one above). Which
//! chunks exist is decided later, by the mesher: a chunk whose TIN already
//! meets `max_error` has no children, and a footprint with no valid sample is
//! never made.
//!
//! How wide the leaves are and how many refine levels to start with, when
//! the settings leave them to the data, is [`estimate`]'s choice.

pub mod estimate;

/// A closed interval of grid cells `[a, b]` along one axis (sample indices).
pub type Span = (u32, u32);

/// Identifies a chunk: level `L` (0 = top), column `x` (east), row `y` (south).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ChunkKey {
    /// Level, 0 at the top.
    pub level: u32,
    /// Column index among this level's column spans.
    pub x: u32,
    /// Row index among this level's row spans.
    pub y: u32,
}

/// Most refine levels a plan takes (see [`ChunkTree::plan`]); a build that
/// still has a chunk too dense gives up there.
pub const MAX_REFINE_LEVELS: u32 = 24;

/// Per-axis spans for every level, plus δ per level.
#[derive(Clone, Debug)]
pub struct ChunkTree {
    /// `xs[L]`: the column spans of level L, west to east.
    pub xs: Vec<Vec<Span>>,
    /// `zs[L]`: the row spans of level L, north to south.
    pub zs: Vec<Vec<Span>>,
    /// δ(L) in metres, halving with each level; the last equals `max_error_m`.
    pub delta_m: Vec<f64>,
}

impl ChunkTree {
    /// Plans the tree for a `width` × `height` grid (samples, both ≥ 2).
    ///
    /// `leaf_cells`: the widest a chunk of the last splitting level may be,
    /// in cells (≥ 1). `refine_levels`: levels added below it that keep
    /// their parent's footprint and only halve δ. They are used when a coarse
    /// chunk cannot meet its δ within the u16 vertex limit: every level's δ
    /// doubles while the footprints stay, so the leaves keep their size.
    pub fn plan(width: usize, height: usize, max_error_m: f64, leaf_cells: u32, refine_levels: u32) -> Self {
        Self::plan_rooted(width, height, max_error_m, None, leaf_cells, refine_levels)
    }

    /// [`Self::plan`] with top-level chunks at most `root_cells` wide along
    /// either axis (`None`: as few as the aspect rule gives): the grid is
    /// cut evenly into as many top-level chunks as that takes, each the top
    /// of its own tree, so the tree has fewer levels above the leaves.
    pub fn plan_rooted(
        width: usize,
        height: usize,
        max_error_m: f64,
        root_cells: Option<u32>,
        leaf_cells: u32,
        refine_levels: u32,
    ) -> Self {
        let wc = (width - 1) as u32;
        let hc = (height - 1) as u32;
        // Near-square top cells: no top chunk has an aspect ratio over 2.
        let mut nx = if wc >= hc { (f64::from(wc) / f64::from(hc)).round().max(1.0) as u32 } else { 1 };
        let mut nz = if hc > wc { (f64::from(hc) / f64::from(wc)).round().max(1.0) as u32 } else { 1 };
        if let Some(r) = root_cells {
            let r = r.max(1);
            nx = nx.max(wc.div_ceil(r));
            nz = nz.max(hc.div_ceil(r));
        }
        let mut xs = vec![split_even(wc, nx)];
        let mut zs = vec![split_even(hc, nz)];
        loop {
            let (x, z) = (xs.last().unwrap(), zs.last().unwrap());
            if widest(x).max(widest(z)) <= leaf_cells || (widest(x) < 2 && widest(z) < 2) {
                break;
            }
            let nx = x.iter().flat_map(|&s| split_span(s)).collect();
            let nz = z.iter().flat_map(|&s| split_span(s)).collect();
            xs.push(nx);
            zs.push(nz);
        }
        for _ in 0..refine_levels.min(MAX_REFINE_LEVELS) {
            xs.push(xs.last().unwrap().clone());
            zs.push(zs.last().unwrap().clone());
        }
        let depth = xs.len() - 1;
        let delta_m = (0..=depth).map(|l| max_error_m * f64::from(1u32 << (depth - l).min(31))).collect();
        ChunkTree { xs, zs, delta_m }
    }

    /// Whether the chunks of `level` are cut into smaller children (so their
    /// TINs must keep the dividing lines), rather than refined in place.
    pub fn splits(&self, level: u32) -> bool {
        let l = level as usize;
        l + 1 < self.xs.len() && (self.xs[l + 1] != self.xs[l] || self.zs[l + 1] != self.zs[l])
    }

    /// The widest chunk of `level` in cells, `[along x, along z]`.
    pub fn widest_cells(&self, level: u32) -> [u32; 2] {
        [widest(&self.xs[level as usize]), widest(&self.zs[level as usize])]
    }

    /// Deepest level index.
    pub fn depth(&self) -> u32 {
        (self.xs.len() - 1) as u32
    }

    /// The top-level chunks, row-major.
    pub fn roots(&self) -> Vec<ChunkKey> {
        let mut v = Vec::new();
        for y in 0..self.zs[0].len() as u32 {
            for x in 0..self.xs[0].len() as u32 {
                v.push(ChunkKey { level: 0, x, y });
            }
        }
        v
    }

    /// Footprint of a chunk in sample indices: `((x0, x1), (z0, z1))`, closed.
    pub fn footprint(&self, k: ChunkKey) -> (Span, Span) {
        (self.xs[k.level as usize][k.x as usize], self.zs[k.level as usize][k.y as usize])
    }

    /// The chunks one level down that tile `k`'s footprint (1, 2 or 4), in
    /// row-major order; empty at the deepest level.
    pub fn children(&self, k: ChunkKey) -> Vec<ChunkKey> {
        let l = k.level as usize;
        if l + 1 >= self.xs.len() {
            return Vec::new();
        }
        let cx = child_range(&self.xs[l + 1], self.xs[l][k.x as usize]);
        let cz = child_range(&self.zs[l + 1], self.zs[l][k.y as usize]);
        let mut v = Vec::new();
        for y in cz.clone() {
            for x in cx.clone() {
                v.push(ChunkKey { level: k.level + 1, x, y });
            }
        }
        v
    }

    /// The chunk one level up whose footprint contains `k`'s.
    pub fn parent(&self, k: ChunkKey) -> Option<ChunkKey> {
        if k.level == 0 {
            return None;
        }
        let l = k.level as usize - 1;
        let (sx, sz) = self.footprint(k);
        let px = self.xs[l].iter().position(|s| s.0 <= sx.0 && sx.1 <= s.1)?;
        let pz = self.zs[l].iter().position(|s| s.0 <= sz.0 && sz.1 <= s.1)?;
        Some(ChunkKey { level: k.level - 1, x: px as u32, y: pz as u32 })
    }
}

/// Where a span is cut for the next level (its integer midpoint), if at all.
pub fn midpoint(s: Span) -> Option<u32> {
    (s.1 - s.0 >= 2).then(|| s.0 + (s.1 - s.0) / 2)
}

/// The widest of `spans`, in cells.
fn widest(spans: &[Span]) -> u32 {
    spans.iter().map(|s| s.1 - s.0).max().unwrap_or(0)
}

fn split_span(s: Span) -> Vec<Span> {
    match midpoint(s) {
        Some(m) => vec![(s.0, m), (m, s.1)],
        None => vec![s],
    }
}

fn split_even(n: u32, parts: u32) -> Vec<Span> {
    let parts = parts.min(n).max(1);
    let cut = |k: u32| ((u64::from(n) * u64::from(k) + u64::from(parts) / 2) / u64::from(parts)) as u32;
    (0..parts).map(|k| (cut(k), cut(k + 1))).collect()
}

fn child_range(level: &[Span], parent: Span) -> std::ops::Range<u32> {
    let first = level.partition_point(|s| s.0 < parent.0);
    let last = level.partition_point(|s| s.1 <= parent.1);
    first as u32..last as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_grid_has_one_root_and_halving_delta() {
        let t = ChunkTree::plan(513, 513, 1.0, 128, 0);
        assert_eq!(t.roots().len(), 1);
        assert_eq!(t.depth(), 2);
        assert_eq!(t.delta_m, vec![4.0, 2.0, 1.0]);
        assert_eq!(t.xs[2], vec![(0, 128), (128, 256), (256, 384), (384, 512)]);
    }

    #[test]
    fn top_chunks_at_most_root_cells_wide_make_a_forest_over_the_same_leaves() {
        let one = ChunkTree::plan(4097, 4097, 5.0, 128, 0);
        let forest = ChunkTree::plan_rooted(4097, 4097, 5.0, Some(512), 128, 0);
        assert_eq!(one.depth(), 5);
        assert_eq!((forest.roots().len(), forest.widest_cells(0)), (64, [512, 512]));
        // Three levels instead of six, the same leaves at the same δ.
        assert_eq!(forest.delta_m, vec![20.0, 10.0, 5.0]);
        assert_eq!((forest.xs.last(), forest.zs.last()), (one.xs.last(), one.zs.last()));
        // Unset, or wider than the grid, it is the one-root plan.
        for r in [None, Some(4096), Some(65_536)] {
            let t = ChunkTree::plan_rooted(4097, 4097, 5.0, r, 128, 0);
            assert_eq!((t.xs, t.zs, t.delta_m), (one.xs.clone(), one.zs.clone(), one.delta_m.clone()));
        }
        // An elongated grid keeps its near-square top cells where those are
        // narrower; a bound cuts only what is wider.
        let wide = ChunkTree::plan_rooted(1001, 201, 1.0, Some(300), 128, 0);
        assert_eq!((wide.xs[0].len(), wide.zs[0].len()), (5, 1));
        let cut = ChunkTree::plan_rooted(1001, 201, 1.0, Some(150), 128, 0);
        assert_eq!((cut.xs[0].len(), cut.zs[0].len()), (7, 2));
    }

    #[test]
    fn wide_grid_starts_from_near_square_cells() {
        let t = ChunkTree::plan(1001, 201, 1.0, 128, 0);
        assert_eq!(t.xs[0].len(), 5);
        assert_eq!(t.zs[0].len(), 1);
        for l in 0..=t.depth() as usize {
            for x in &t.xs[l] {
                for z in &t.zs[l] {
                    let (w, h) = (x.1 - x.0, z.1 - z.0);
                    assert!(w.max(h) <= 2 * w.min(h).max(1), "aspect {w}x{h} at level {l}");
                }
            }
        }
    }

    #[test]
    fn children_tile_parent_and_point_back() {
        let t = ChunkTree::plan(1025, 700, 0.5, 100, 0);
        for l in 0..t.depth() {
            for y in 0..t.zs[l as usize].len() as u32 {
                for x in 0..t.xs[l as usize].len() as u32 {
                    let k = ChunkKey { level: l, x, y };
                    let kids = t.children(k);
                    assert!(!kids.is_empty());
                    let area: u64 = kids
                        .iter()
                        .map(|&c| {
                            assert_eq!(t.parent(c), Some(k));
                            let (a, b) = t.footprint(c);
                            u64::from(a.1 - a.0) * u64::from(b.1 - b.0)
                        })
                        .sum();
                    let (a, b) = t.footprint(k);
                    assert_eq!(area, u64::from(a.1 - a.0) * u64::from(b.1 - b.0));
                }
            }
        }
    }

    #[test]
    fn two_by_two_grid_is_a_single_leaf() {
        let t = ChunkTree::plan(2, 2, 1.0, 200, 0);
        assert_eq!(t.depth(), 0);
        assert_eq!(t.footprint(t.roots()[0]), ((0, 1), (0, 1)));
    }

    #[test]
    fn refine_levels_keep_the_leaf_footprints_and_double_every_delta() {
        let base = ChunkTree::plan(1025, 1025, 1.0, 128, 0);
        let deep = ChunkTree::plan(1025, 1025, 1.0, 128, 2);
        assert_eq!(deep.depth(), base.depth() + 2);
        assert_eq!(deep.xs[deep.depth() as usize], base.xs[base.depth() as usize]);
        assert_eq!(deep.delta_m[0], 4.0 * base.delta_m[0]);
        assert!(deep.splits(0) && !deep.splits(base.depth()) && !deep.splits(deep.depth()));
        let leaf = ChunkKey { level: deep.depth(), x: 3, y: 5 };
        let up = deep.parent(leaf).unwrap();
        assert_eq!(deep.footprint(up), deep.footprint(leaf));
        assert_eq!(deep.children(up), vec![leaf]);
    }

    #[test]
    fn strip_grid_makes_unit_cells() {
        let t = ChunkTree::plan(2, 50, 1.0, 200, 0);
        assert_eq!(t.zs[0].len(), 49);
        assert_eq!(t.depth(), 0);
    }
}
