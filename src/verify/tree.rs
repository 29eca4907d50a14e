//! The index: 3D Tiles structure, δ per level, every chunk the tree implies
//! present exactly once, bounding boxes that enclose their content and sit
//! inside their parent's, and the root transform the DEM's georeference
//! gives.

use std::collections::BTreeMap;

use serde_json::Value;

use super::name;
use super::read::ChunkFile;
use crate::geodesy::{FlatFrameError, Placement};
use crate::heightfield::Heightfield;
use crate::output::tileset::{TileExtras, TilesetExtras, tile_uri};
use crate::quadtree::{ChunkKey, midpoint};

/// One content tile of the index, as the walk and the checks read it.
#[derive(Debug, Default)]
pub(super) struct Tile {
    /// Its children's keys, in the index's order, each once.
    pub children: Vec<ChunkKey>,
    /// Its bounding box, if the index gives a usable one.
    pub bbox: Option<Obb>,
}

/// A 3D Tiles oriented box: centre and three half-axes, in the tileset
/// frame (x east, y north, z up).
#[derive(Clone, Copy, Debug)]
pub(super) struct Obb {
    centre: [f64; 3],
    half: [[f64; 3]; 3],
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Obb {
    /// The box of a `boundingVolume.box` array: twelve finite numbers whose
    /// half-axes are non-zero and at right angles (otherwise a point could
    /// pass the containment test along an axis that has no length).
    fn parse(v: &[Value]) -> Result<Obb, String> {
        let n: Vec<f64> = v.iter().filter_map(Value::as_f64).filter(|x| x.is_finite()).collect();
        if n.len() != 12 {
            return Err("boundingVolume.box is not twelve finite numbers".into());
        }
        let half = [0, 1, 2].map(|a| [n[3 + 3 * a], n[4 + 3 * a], n[5 + 3 * a]]);
        let len = half.map(|h| dot(h, h).sqrt());
        let square = (0..3).all(|a| (a + 1..3).all(|b| dot(half[a], half[b]).abs() <= 1e-9 * len[a] * len[b]));
        if len.contains(&0.0) || !square {
            return Err("boundingVolume.box has a half-axis of length 0 or two that are not at right angles".into());
        }
        Ok(Obb { centre: [n[0], n[1], n[2]], half })
    }

    /// Whether `p` (tileset frame) lies in the box, or within `slack`
    /// metres of it.
    pub fn contains(&self, p: [f64; 3], slack: f64) -> bool {
        let d = [0, 1, 2].map(|a| p[a] - self.centre[a]);
        self.half.iter().all(|h| {
            let len = dot(*h, *h).sqrt();
            dot(d, *h).abs() / len <= len + slack
        })
    }

    fn corners(&self) -> impl Iterator<Item = [f64; 3]> + '_ {
        (0..8).map(move |k| {
            let s = [0, 1, 2].map(|a| if k >> a & 1 == 1 { 1.0 } else { -1.0 });
            [0, 1, 2].map(|r| self.centre[r] + (0..3).map(|a| s[a] * self.half[a][r]).sum::<f64>())
        })
    }

    /// The rounding the writer's f64 arithmetic leaves in a box this far
    /// from the origin, metres.
    fn rounding(&self) -> f64 {
        let far = self.centre.iter().chain(self.half.iter().flatten()).fold(0.0f64, |m, v| m.max(v.abs()));
        1e-6 + 1e-12 * far
    }
}

/// What walking the index found, besides its failures.
#[derive(Default)]
pub(super) struct Index {
    /// Every content tile, once.
    pub tiles: BTreeMap<ChunkKey, Tile>,
    /// How often each key the index lists more than once appears.
    duplicates: BTreeMap<ChunkKey, usize>,
}

impl Index {
    /// Reads the tree under `root` (the index's root tile), checking each
    /// tile's 3D Tiles fields, δ, content uri, that its box lies in its
    /// parent's and that no tile but the root carries a transform.
    pub fn read(root: &Value, extras: &TilesetExtras, failures: &mut Vec<String>) -> Index {
        let mut index = Index::default();
        index.tile(root, Up { key: None, bbox: None, refine: "REPLACE", root: true }, extras, failures);
        for (k, n) in &index.duplicates {
            failures.push(format!("chunk {}: listed {n} times in tileset.json (once is the contract)", name(*k)));
        }
        index
    }

    /// The tiles without a content parent, in key order.
    pub fn roots(&self) -> Vec<ChunkKey> {
        let children: std::collections::BTreeSet<ChunkKey> =
            self.tiles.values().flat_map(|t| &t.children).copied().collect();
        self.tiles.keys().filter(|k| !children.contains(k)).copied().collect()
    }

    fn tile(&mut self, t: &Value, up: Up, extras: &TilesetExtras, failures: &mut Vec<String>) {
        let refine = t["refine"].as_str().unwrap_or(up.refine);
        if refine != "REPLACE" {
            failures.push(format!("tile refine is {refine}, not REPLACE"));
        }
        let ge = t["geometricError"].as_f64();
        let bx = t["boundingVolume"]["box"].as_array();
        if ge.is_none() || bx.is_none() {
            failures.push("a tile lacks geometricError or boundingVolume.box".into());
        }
        let mut me = None;
        let mut label = if up.root { "the root tile".to_string() } else { "a tile without content".to_string() };
        if t.get("content").is_some() {
            match serde_json::from_value::<TileExtras>(t["extras"]["terrachunk"].clone()) {
                Ok(te) => {
                    let k = ChunkKey { level: te.level, x: te.x, y: te.y };
                    if self.tiles.contains_key(&k) {
                        // A second listing: counted, and its subtree not
                        // walked again (2 000 copies of one child once made
                        // `verify` read that child 2 000 times).
                        *self.duplicates.entry(k).or_insert(1) += 1;
                        return;
                    }
                    label = format!("tile {}", name(k));
                    self.content(t, k, te, ge, up.key, extras, failures);
                    me = Some((k, te.delta_m));
                }
                Err(e) => failures.push(format!("tile without valid extras.terrachunk: {e}")),
            }
        }
        if !up.root && t.get("transform").is_some() {
            failures.push(format!("{label} carries a transform; only the root tile may"));
        }
        let bbox = match bx.map(|b| Obb::parse(b)) {
            Some(Ok(b)) => Some(b),
            Some(Err(e)) => {
                failures.push(format!("{label}: {e}"));
                None
            }
            None => None,
        };
        if let (Some(b), Some(p)) = (&bbox, &up.bbox)
            // The writer gives a flat box a half-extent of 1 mm, beyond the
            // extent its parent's box was made from.
            && !b.corners().all(|c| p.contains(c, p.rounding() + b.rounding() + 1e-3))
        {
            let parent =
                up.key.map_or_else(|| "the tile above it".to_string(), |k| format!("its parent {}", name(k.0)));
            failures.push(format!("{label}: bounding box reaches outside the box of {parent}"));
        }
        if let Some((k, _)) = me {
            self.tiles.get_mut(&k).expect("inserted by content").bbox = bbox;
        }
        if let Some(children) = t["children"].as_array() {
            // A content-less tile passes its parent on: the index's root
            // over several top-level chunks has none above it.
            let key = me.or(up.key.filter(|_| me.is_some()));
            let bbox = bbox.or(up.bbox);
            for c in children {
                self.tile(c, Up { key, bbox, refine, root: false }, extras, failures);
            }
        }
    }

    /// A content tile's own fields, and its place among its parent's children.
    #[allow(clippy::too_many_arguments)]
    fn content(
        &mut self,
        t: &Value,
        k: ChunkKey,
        te: TileExtras,
        ge: Option<f64>,
        parent: Option<(ChunkKey, f64)>,
        extras: &TilesetExtras,
        failures: &mut Vec<String>,
    ) {
        if t["content"]["uri"] != tile_uri(k).as_str() {
            failures.push(format!("tile {}: content uri is {}", name(k), t["content"]["uri"]));
        }
        let want = extras.delta_m.get(k.level as usize).copied().unwrap_or(f64::NAN);
        if ge != Some(te.delta_m) || te.delta_m != want {
            failures.push(format!(
                "tile {}: geometricError {:?} / delta_m {} but level δ is {want}",
                name(k),
                ge,
                te.delta_m
            ));
        }
        if let Some((pk, pd)) = parent {
            if k.level != pk.level + 1 || (te.delta_m * 2.0 - pd).abs() > 1e-9 * pd {
                failures.push(format!(
                    "tile {}: δ {} does not halve its parent {}'s δ {pd}",
                    name(k),
                    te.delta_m,
                    name(pk)
                ));
            }
            if let Some(e) = self.tiles.get_mut(&pk) {
                e.children.push(k);
            }
        }
        // Its children, as they are found (not a copy of the tile: that
        // held each subtree once per tile above it).
        self.tiles.insert(k, Tile::default());
    }
}

/// What a tile inherits from the one above it.
#[derive(Clone, Copy)]
struct Up<'a> {
    key: Option<(ChunkKey, f64)>,
    bbox: Option<Obb>,
    refine: &'a str,
    root: bool,
}

/// Whether every position of chunk `c` lies in its tile's box (positions
/// in glTF's y-up frame, the box in the tileset's z-up frame), within the
/// f32 rounding of the positions as written.
pub(super) fn content_in_box(c: &ChunkFile, bbox: &Obb) -> Option<String> {
    let prims = std::iter::once(&c.surface).chain(c.skirt.as_ref());
    for prim in prims {
        let slack =
            bbox.rounding() + 4.0 * f64::from(f32::EPSILON) * prim.local_extent.iter().fold(0.0f64, |m, v| m.max(*v));
        if let Some(p) = prim.positions.iter().find(|p| !bbox.contains([p[0], -p[2], p[1]], slack)) {
            return Some(format!(
                "vertex at ({:.3}, {:.3}, {:.3}) m lies outside the tile's bounding box",
                p[0], p[1], p[2]
            ));
        }
    }
    None
}

/// Whether the root tile's transform is the one the DEM's georeference
/// gives (none where it gives none), entry by entry within the rounding
/// of the arithmetic that makes it.
/// Checks the root transform against the one the DEM's georeference
/// gives, and measures how far it draws the planar grid from the
/// ellipsoid: the extras must not state less.
pub(super) fn check_transform(ts: &Value, hf: &Heightfield, failures: &mut Vec<String>) -> Option<FlatFrameError> {
    let placed = Placement::of_grid(&hf.georef, hf.width, hf.height, hf.spacing_m).ok();
    let curved = ts["extras"]["terrachunk"]["placement"]["frame"] == "curved";
    let want = placed.clone().map(|p| if curved { p.curved() } else { p }.transform());
    // What the planar frame is measured by: its own transform, also for a
    // curved tileset (the extras state what the curved frame saved).
    let flat = placed.map(|p| p.transform());
    let got = &ts["root"]["transform"];
    match (want, got.as_array()) {
        (None, None) => None,
        (None, Some(_)) => {
            failures.push("the root tile carries a transform, but the DEM's georeference places it nowhere".into());
            None
        }
        (Some(_), None) => {
            failures.push("the root tile has no transform, but the DEM's georeference gives one".into());
            None
        }
        (Some(w), Some(g)) => {
            let g: Vec<f64> = g.iter().map(|v| v.as_f64().unwrap_or(f64::NAN)).collect();
            let close = g.len() == 16 && w.iter().zip(&g).all(|(w, g)| (w - g).abs() <= 1e-9 * w.abs().max(1.0));
            if !close {
                failures.push(format!(
                    "the root tile's transform {g:?} is not the one the DEM's georeference gives, {w:?}"
                ));
                return None;
            }
            let g: [f64; 16] = if curved { flat.expect("placed") } else { g.try_into().expect("16 values") };
            let measured = FlatFrameError::measure(&hf.georef, hf.width, hf.height, hf.spacing_m, &g)?;
            let stated = &ts["extras"]["terrachunk"]["placement"]["flat_frame_error"];
            let stated_m = [&stated["vertical_m"], &stated["horizontal_m"]].map(|v| v.as_f64().map(f64::abs));
            let understated = |stated: Option<f64>, m: f64| stated.is_none_or(|s| s + 1e-3 + 1e-9 * m < m);
            if understated(stated_m[0], measured.vertical_m.abs()) || understated(stated_m[1], measured.horizontal_m) {
                failures.push(format!(
                    "extras.terrachunk.placement.flat_frame_error states {stated}, but the transform draws a sample \
                     {:.3} m along the ellipsoid normal and {:.3} m across it from its place",
                    measured.vertical_m, measured.horizontal_m
                ));
            }
            Some(measured)
        }
    }
}

/// The footprints `[x0, x1, z0, z1]` a chunk's children tile: its four
/// quarters (two or one along an axis too short to cut), or itself once
/// on a level that refines in place (`split` false); `kids` are the
/// children's footprints as their files give them.
fn quarters(f: [u32; 4], split: bool, kids: &[[u32; 4]]) -> Vec<[u32; 4]> {
    // The cut along one axis: where the children put it when they all agree
    // on one line strictly inside (the bintree's cuts sit on powers of two),
    // else the midpoint the quadtree uses.
    let cut = |lo: usize, a: u32, b: u32| {
        // Every child spans the whole axis: the level cuts only the other one.
        if !kids.is_empty() && kids.iter().all(|k| k[lo] == a && k[lo + 1] == b) {
            return None;
        }
        let at: std::collections::BTreeSet<u32> = kids
            .iter()
            .filter_map(|k| match (k[lo] == a && k[lo + 1] < b, k[lo + 1] == b && k[lo] > a) {
                (true, _) => Some(k[lo + 1]),
                (_, true) => Some(k[lo]),
                _ => None,
            })
            .collect();
        match at.iter().collect::<Vec<_>>()[..] {
            [&m] if m > a && m < b => Some(m),
            _ => midpoint((a, b)),
        }
    };
    let halves = |lo: usize, a: u32, b: u32| match cut(lo, a, b).filter(|_| split) {
        Some(m) => vec![(a, m), (m, b)],
        None => vec![(a, b)],
    };
    let mut out = Vec::new();
    for (z0, z1) in halves(2, f[2], f[3]) {
        for (x0, x1) in halves(0, f[0], f[1]) {
            out.push([x0, x1, z0, z1]);
        }
    }
    out
}

/// Valid samples in the closed footprint `f`.
fn valid_in(hf: &Heightfield, f: [u32; 4]) -> usize {
    let [x0, x1, z0, z1] = f.map(|v| v as usize);
    (z0..=z1.min(hf.height - 1)).map(|i| (x0..=x1.min(hf.width - 1)).filter(|&j| !hf.get(i, j).is_nan()).count()).sum()
}

/// Every chunk the tree implies, present exactly once: each chunk's
/// children are its quarters (or itself, on a level that refines in place),
/// each at most once, and a quarter is missing only where it holds no
/// valid sample (the builder makes no chunk there); the top-level chunks
/// cover every valid sample without overlapping; and along each level a
/// column (row) index always names the same span of samples, in order.
/// `footprints`: each readable chunk's, from its file.
pub(super) fn check_tree(
    index: &Index,
    footprints: &BTreeMap<ChunkKey, [u32; 4]>,
    hf: &Heightfield,
    failures: &mut Vec<String>,
) {
    for (k, tile) in &index.tiles {
        let (Some(&f), false) = (footprints.get(k), tile.children.is_empty()) else { continue };
        let kids: Option<Vec<(ChunkKey, [u32; 4])>> =
            tile.children.iter().map(|c| footprints.get(c).map(|f| (*c, *f))).collect();
        let Some(kids) = kids else { continue }; // an unreadable child is its own failure
        let split = kids.iter().any(|(_, cf)| *cf != f);
        let kid_footprints: Vec<[u32; 4]> = kids.iter().map(|(_, cf)| *cf).collect();
        let expected = quarters(f, split, &kid_footprints);
        let mut taken: BTreeMap<[u32; 4], ChunkKey> = BTreeMap::new();
        for (c, cf) in &kids {
            if !expected.contains(cf) {
                failures.push(format!(
                    "chunk {}: footprint {cf:?} is not one of its parent {}'s {} {expected:?}",
                    name(*c),
                    name(*k),
                    if split { "quarters" } else { "footprint" }
                ));
            } else if let Some(other) = taken.insert(*cf, *c) {
                failures.push(format!(
                    "chunks {} and {}: both cover {cf:?} under their parent {}",
                    name(other),
                    name(*c),
                    name(*k)
                ));
            }
        }
        for q in expected.iter().filter(|q| !taken.contains_key(*q)) {
            let n = valid_in(hf, *q);
            if n > 0 {
                failures.push(format!(
                    "chunk {}: no child covers columns {}..={}, rows {}..={}, where {n} samples hold data",
                    name(*k),
                    q[0],
                    q[1],
                    q[2],
                    q[3]
                ));
            }
        }
    }
    check_top(index, footprints, hf, failures);
    check_spans(footprints, failures);
}

/// The top-level chunks cover every valid sample, and no two overlap.
fn check_top(index: &Index, footprints: &BTreeMap<ChunkKey, [u32; 4]>, hf: &Heightfield, failures: &mut Vec<String>) {
    let tops: Vec<(ChunkKey, [u32; 4])> =
        index.roots().into_iter().filter_map(|k| footprints.get(&k).map(|f| (k, *f))).collect();
    if tops.len() != index.roots().len() {
        return; // an unreadable top chunk is its own failure
    }
    for (a, (ka, fa)) in tops.iter().enumerate() {
        for (kb, fb) in &tops[a + 1..] {
            if fa[0] < fb[1] && fb[0] < fa[1] && fa[2] < fb[3] && fb[2] < fa[3] {
                failures.push(format!("top-level chunks {} and {} overlap", name(*ka), name(*kb)));
            }
        }
    }
    let mut covered = vec![false; hf.width * hf.height];
    for (_, f) in &tops {
        let (x0, x1) = (f[0] as usize, (f[1] as usize).min(hf.width - 1));
        for i in (f[2] as usize..=(f[3] as usize).min(hf.height - 1)).filter(|_| x0 <= x1) {
            covered[i * hf.width + x0..=i * hf.width + x1].fill(true);
        }
    }
    let lost = hf.heights.iter().zip(&covered).filter(|(h, c)| !h.is_nan() && !**c).count();
    if lost > 0 {
        failures.push(format!("{lost} samples with data lie in no top-level chunk"));
    }
}

/// Along each level, column index x always names the same span of
/// samples and a larger x a span further east (rows alike, southward).
fn check_spans(footprints: &BTreeMap<ChunkKey, [u32; 4]>, failures: &mut Vec<String>) {
    let mut spans: BTreeMap<(u32, usize, u32), ([u32; 2], ChunkKey)> = BTreeMap::new();
    for (k, f) in footprints {
        for (axis, index, span) in [(0, k.x, [f[0], f[1]]), (1, k.y, [f[2], f[3]])] {
            match spans.get(&(k.level, axis, index)) {
                Some((s, other)) if *s != span => failures.push(format!(
                    "chunks {} and {}: {} {index} spans {s:?} in one and {span:?} in the other",
                    name(*other),
                    name(*k),
                    ["column", "row"][axis]
                )),
                Some(_) => {}
                None => {
                    spans.insert((k.level, axis, index), (span, *k));
                }
            }
        }
    }
    let mut last: Option<((u32, usize, u32), [u32; 2])> = None;
    for (&(level, axis, index), (span, k)) in &spans {
        if let Some(((l, a, i), s)) = last
            && l == level
            && a == axis
            && s[1] > span[0]
        {
            failures.push(format!(
                "chunk {}: {} {index} spans {span:?}, not east/south of {} {i}'s {s:?}",
                name(*k),
                ["column", "row"][axis],
                ["column", "row"][axis]
            ));
        }
        last = Some(((level, axis, index), *span));
    }
}
