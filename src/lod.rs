//! Runtime level-of-detail decisions for a written tileset: which chunks to
//! draw for a viewpoint, and how far to morph each toward its parent.
//!
//! This is the part of Ulrich's Chunked LOD (2002, §3–4; DESIGN.md "The
//! numbers") that a client runs every frame, kept here as plain f64 maths so
//! that it is unit-tested without a GPU and any client (the `terrachunk-view`
//! crate, a test, another renderer) uses the same code.
//!
//! - Screen-space error: ρ = δ·K/D with K = viewport_width / (2·tan(hfov/2))
//!   and D the distance from the eye to the nearest point of the chunk's
//!   bounding box ([`screen_error`]). That is the shift of a point straight
//!   ahead; off the view axis by θ the same δ moves a point by up to
//!   1/cos²θ as much, so a client that promises "no point moves more than τ
//!   pixels anywhere in the image" multiplies K by [`off_axis_factor`]
//!   ([`screen_k_bound`]).
//! - Selection, top down ([`select`]): a chunk is drawn when ρ ≤ τ, else its
//!   children, but only once all of them are resident; until then the chunk
//!   itself stays drawn and the missing children are requested with priority ρ.
//! - Prefetch (Ulrich §4, "request the children of every drawn chunk"): the
//!   children of each drawn chunk are asked for before the chunk needs to
//!   split, by the chunk's ρ at the eye or at where the eye is heading, and
//!   the grandchildren too where that predicted ρ is about to cross τ, so
//!   that a moving camera finds them resident.
//! - Morph ([`morph_weight`]): the blend weight toward the parent shape.
//!   [`MorphSchedule::Bounded`] keeps the blended surface's screen error ≤ τ;
//!   [`MorphSchedule::Ulrich`] is the paper's schedule, which reaches 9/8·τ.

use serde_json::Value;

use crate::quadtree::ChunkKey;

/// K = viewport_width / (2·tan(hfov/2)): pixels per unit of (size / distance).
///
/// `viewport_width_px` > 0; `hfov_rad` is the horizontal field of view in
/// radians, in (0, π).
pub fn screen_k(viewport_width_px: f64, hfov_rad: f64) -> f64 {
    viewport_width_px / (2.0 * (hfov_rad / 2.0).tan())
}

/// How much more than on the view axis a vertical error can move a point
/// anywhere in the image: 1 + tan²θ at the corner, the largest off-axis
/// angle θ, with tan²θ = tan²(hfov/2)·(1 + (height/width)²).
///
/// A displacement v of a point at depth z and off-axis angle θ moves its
/// image by at most K·|v|·√(1 + tan²θ)/z (the projection's Jacobian has
/// singular values 1 and √(1 + tan²θ)), and z = D·cos θ, so the shift is at
/// most K·|v|·(1 + tan²θ)/D: 1.44 at the corners of a 16:9, 60° view.
pub fn off_axis_factor(viewport_px: [f64; 2], hfov_rad: f64) -> f64 {
    let t = (hfov_rad / 2.0).tan();
    let r = viewport_px[1] / viewport_px[0];
    1.0 + t * t * (1.0 + r * r)
}

/// K · [`off_axis_factor`]: with it, ρ = δ·K/D bounds the shift of every
/// point of the image, not only those on the view axis.
pub fn screen_k_bound(viewport_px: [f64; 2], hfov_rad: f64) -> f64 {
    screen_k(viewport_px[0], hfov_rad) * off_axis_factor(viewport_px, hfov_rad)
}

/// Distance in metres from `eye` to the nearest point of the box `[min, max]`
/// (0 inside it).
pub fn distance_to_box(eye: [f64; 3], min: [f64; 3], max: [f64; 3]) -> f64 {
    let mut d2 = 0.0;
    for a in 0..3 {
        let d = (min[a] - eye[a]).max(eye[a] - max[a]).max(0.0);
        d2 += d * d;
    }
    d2.sqrt()
}

/// ρ = δ·K/D in pixels for a chunk of geometric error `delta_m` at distance
/// `distance_m`; infinite when the eye is inside the box (D = 0, δ > 0).
pub fn screen_error(delta_m: f64, distance_m: f64, k: f64) -> f64 {
    if delta_m <= 0.0 {
        0.0
    } else if distance_m <= 0.0 {
        f64::INFINITY
    } else {
        delta_m * k / distance_m
    }
}

/// How a drawn chunk's morph weight follows its screen error.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MorphSchedule {
    /// Weight toward the parent w = clamp((τ·D/K − δ)/(δ_p − δ), 0, 1), which
    /// is w = clamp(τ/ρ − 1, 0, 1) when δ_p = 2δ (DESIGN.md). The blended
    /// surface is within (1−w)·δ + w·δ_p of the terrain, and that is exactly
    /// τ·D/K while 0 < w < 1: its screen error never exceeds τ. w = 1 (the
    /// parent's shape) when the parent has just split (ρ ≤ τ/2), w = 0 at ρ = τ.
    #[default]
    Bounded,
    /// Ulrich's t = clamp(2ρ/τ − 1, 0, 1) as own-shape weight, i.e.
    /// w = 1 − t. The blend carries both errors: ρ·(1 + w) peaks at 9/8·τ
    /// (at ρ = 3τ/4).
    Ulrich,
}

/// Blend weight toward the parent shape (0 = the chunk's own shape, 1 = its
/// morph target on the parent surface) for a chunk drawn at screen error
/// `rho` (px) under tolerance `tau` (px), with `delta_parent_m / delta_m` the
/// ratio of the parent's geometric error to this chunk's (2 in a terrachunk
/// tileset). A chunk without a parent has weight 0.
pub fn morph_weight(schedule: MorphSchedule, rho: f64, tau: f64, delta_m: f64, delta_parent_m: Option<f64>) -> f64 {
    let Some(dp) = delta_parent_m else { return 0.0 };
    if !rho.is_finite() || rho <= 0.0 || tau <= 0.0 {
        // At D = 0 the chunk shows its own shape; at ρ = 0 (δ = 0) either shape is exact.
        return if rho.is_finite() && rho <= 0.0 { 1.0 } else { 0.0 };
    }
    let w = match schedule {
        MorphSchedule::Bounded => {
            if dp <= delta_m {
                // A parent no coarser than the child: its shape is as good.
                1.0
            } else {
                // (1−w)·δ + w·δ_p = τ·D/K = δ·τ/ρ.
                (delta_m * tau / rho - delta_m) / (dp - delta_m)
            }
        }
        MorphSchedule::Ulrich => 1.0 - (2.0 * rho / tau - 1.0),
    };
    w.clamp(0.0, 1.0)
}

/// Bound in metres on the blended surface's error, (1−w)·δ + w·δ_p: the two
/// surfaces' errors, since the morphed chunk is their per-point blend.
pub fn blended_error_m(w: f64, delta_m: f64, delta_parent_m: f64) -> f64 {
    (1.0 - w) * delta_m + w * delta_parent_m
}

/// Screen error (px) of a chunk drawn at ρ and morphed by `w` toward its
/// parent: ρ scaled by the blended surface's bound over its own δ.
pub fn shown_error_px(rho: f64, w: f64, delta_m: f64, delta_parent_m: Option<f64>) -> f64 {
    match delta_parent_m {
        Some(dp) if delta_m > 0.0 && w > 0.0 => rho * blended_error_m(w, delta_m, dp) / delta_m,
        _ => rho,
    }
}

/// The weight a chunk morphing in from its parent's shape (it replaced its
/// parent late: its scheduled weight `scheduled` < 1) is drawn at next,
/// coming from weight `from` (1: the parent's shape, drawn the frame
/// before): the largest weight at which it is shown within τ, where getting
/// there moves no vertex by more than τ/2 pixels, an invisible step;
/// otherwise the weight that moves them τ/2. A morph delta is at most δ_p,
/// `rho`/δ pixels a metre.
pub fn late_weight(rho: f64, tau_px: f64, (delta_m, delta_parent_m): (f64, f64), from: f64, scheduled: f64) -> f64 {
    let from = from.clamp(0.0, 1.0);
    if !(rho > 0.0 && delta_m > 0.0 && delta_parent_m > delta_m) {
        return from;
    }
    let within = (tau_px / rho - 1.0) * delta_m / (delta_parent_m - delta_m);
    let step = from - tau_px / 2.0 * delta_m / (rho * delta_parent_m);
    within.max(step).clamp(scheduled.clamp(0.0, from), from)
}

/// One chunk of the tree, as the selection needs it.
#[derive(Clone, Debug, PartialEq)]
pub struct LodNode {
    /// Which chunk.
    pub key: ChunkKey,
    /// Bounding box (glTF frame: x east, y up, z south; metres), min corner.
    pub min: [f64; 3],
    /// Max corner.
    pub max: [f64; 3],
    /// Geometric error δ, metres.
    pub delta_m: f64,
    /// Index of the parent node, if any.
    pub parent: Option<usize>,
    /// Indices of the children (empty for a leaf).
    pub children: Vec<usize>,
    /// Content path relative to the tileset directory (`tiles/L/x/y.glb`).
    pub uri: String,
}

/// The chunk tree of a tileset, flattened; parents before children.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LodTree {
    /// All chunks.
    pub nodes: Vec<LodNode>,
    /// The top chunks (no parent).
    pub roots: Vec<usize>,
}

/// What is wrong with a tileset.json, for a client.
#[derive(Debug, thiserror::Error)]
pub enum LodTreeError {
    /// A tile lacks a field the tree needs.
    #[error("tileset.json: tile {path} has no {field}")]
    Missing {
        /// Where in the tree (child indices from the root).
        path: String,
        /// The missing field.
        field: &'static str,
    },
    /// There is no chunk at all.
    #[error("tileset.json has no tile with content")]
    Empty,
}

impl LodTree {
    /// Reads the tree from a parsed `tileset.json` (3D Tiles boxes are z-up;
    /// they are turned back into the glTF frame, see `output::tileset`).
    /// Content-less tiles (the root over several top cells) are skipped:
    /// their content children become roots.
    pub fn from_tileset_json(ts: &Value) -> Result<Self, LodTreeError> {
        let mut tree = LodTree::default();
        let mut stack = vec![(&ts["root"], None::<usize>, String::from("root"))];
        while let Some((t, parent, path)) = stack.pop() {
            let missing = |field| LodTreeError::Missing { path: path.clone(), field };
            let b: Vec<f64> = t["boundingVolume"]["box"]
                .as_array()
                .ok_or_else(|| missing("boundingVolume.box"))?
                .iter()
                .filter_map(Value::as_f64)
                .collect();
            if b.len() != 12 {
                return Err(missing("12-number boundingVolume.box"));
            }
            let mut me = parent;
            if let Some(uri) = t["content"]["uri"].as_str() {
                let ex = &t["extras"]["terrachunk"];
                let field = |name: &'static str| ex[name].as_u64().map(|v| v as u32).ok_or_else(|| missing(name));
                let key = ChunkKey { level: field("level")?, x: field("x")?, y: field("y")? };
                let delta_m = t["geometricError"].as_f64().ok_or_else(|| missing("geometricError"))?;
                // Tiles frame (east, north, up) → glTF (x, y = up, z = −north).
                let (c, h) = ([b[0], b[2], -b[1]], [b[3].abs(), b[11].abs(), b[7].abs()]);
                let id = tree.nodes.len();
                tree.nodes.push(LodNode {
                    key,
                    min: [0, 1, 2].map(|a| c[a] - h[a]),
                    max: [0, 1, 2].map(|a| c[a] + h[a]),
                    delta_m,
                    parent,
                    children: Vec::new(),
                    uri: uri.to_string(),
                });
                match parent {
                    Some(p) => tree.nodes[p].children.push(id),
                    None => tree.roots.push(id),
                }
                me = Some(id);
            }
            if let Some(kids) = t["children"].as_array() {
                for (i, k) in kids.iter().enumerate().rev() {
                    stack.push((k, me, format!("{path}.children[{i}]")));
                }
            }
        }
        if tree.nodes.is_empty() {
            return Err(LodTreeError::Empty);
        }
        Ok(tree)
    }

    /// δ of a node's parent, if it has one.
    pub fn parent_delta(&self, node: usize) -> Option<f64> {
        self.nodes[node].parent.map(|p| self.nodes[p].delta_m)
    }

    /// The leaves (chunks without children): the full-detail cut.
    pub fn leaves(&self) -> Vec<usize> {
        (0..self.nodes.len()).filter(|&i| self.nodes[i].children.is_empty()).collect()
    }
}

/// The viewpoint as the selection sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LodView {
    /// Eye position, world metres (glTF frame).
    pub eye: [f64; 3],
    /// K from [`screen_k`] (or [`screen_k_bound`] to bound the whole
    /// image), pixels.
    pub k: f64,
    /// Where the eye is expected to be shortly (the last frames' motion
    /// carried forward): prefetch ranks by the larger ρ of the two eyes.
    /// `None` for a still camera.
    pub eye_ahead: Option<[f64; 3]>,
    /// Where the eye will be next frame, if it moves: a chunk whose ρ will
    /// pass τ by then splits now (its children resident), so the screen
    /// error stays within τ however far a frame moves.
    pub eye_next: Option<[f64; 3]>,
    /// Screen-space error tolerance τ, pixels.
    pub tau_px: f64,
    /// Morph schedule for the drawn chunks.
    pub schedule: MorphSchedule,
}

/// A chunk to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Draw {
    /// Node index.
    pub node: usize,
    /// Its screen error ρ, pixels.
    pub rho: f64,
    /// Blend weight toward the parent shape, from [`morph_weight`].
    pub weight: f64,
    /// Whether ρ ≤ τ holds, or the chunk is drawn above τ because it is a
    /// leaf or its children are not all resident yet.
    pub within_tau: bool,
}

/// The outcome of one selection.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Selection {
    /// Chunks to draw this frame.
    pub draws: Vec<Draw>,
    /// Chunks wanted but not resident, with their priority (the screen error
    /// of the chunk that waits for them; infinite for a missing root). Each
    /// node appears once; highest priority first.
    pub requests: Vec<(usize, f64)>,
    /// Every resident node the traversal passed through (drawn or split),
    /// and the resident children of a chunk that waits for its others: a
    /// cache must keep these, or the cut above the drawn chunks breaks (or
    /// siblings evict each other for ever).
    pub touched: Vec<usize>,
    /// Chunks the cut does not need yet but soon may (children of drawn
    /// chunks, and grandchildren where the predicted ρ approaches τ), not
    /// resident, with their priority (the predicted ρ of the chunk that will
    /// split into them); none of them is in `requests`. Highest first.
    pub prefetch: Vec<(usize, f64)>,
    /// Resident chunks kept for the same reason: a cache should evict them
    /// only after everything else not in `touched`.
    pub kept: Vec<usize>,
}

/// Chooses the cut for one frame, top down.
///
/// `resident(n)`: node `n`'s mesh is ready to draw. `visible(n)`: its box
/// meets the view frustum (culled chunks are neither drawn nor descended
/// into). A chunk is drawn when ρ ≤ τ, when it is a leaf, or when some of
/// its children are not resident (they are requested, and it stays drawn
/// until all are): so every drawn chunk with resident children has ρ ≤ τ.
pub fn select(
    tree: &LodTree,
    view: &LodView,
    resident: impl Fn(usize) -> bool,
    visible: impl Fn(usize) -> bool,
) -> Selection {
    let mut sel = Selection::default();
    let rho_at = |n: usize, eye: [f64; 3]| {
        let node = &tree.nodes[n];
        screen_error(node.delta_m, distance_to_box(eye, node.min, node.max), view.k)
    };
    // The larger ρ of the eye now and the eye ahead, and whether it grows.
    let predicted = |n: usize| {
        let now = rho_at(n, view.eye);
        match view.eye_ahead {
            Some(a) => {
                let ahead = rho_at(n, a);
                (now.max(ahead), ahead > now)
            }
            None => (now, false),
        }
    };
    let mut stack: Vec<usize> = tree.roots.iter().rev().copied().collect();
    while let Some(n) = stack.pop() {
        if !visible(n) {
            // Out of view now, but a turn can bring it in: a resident one
            // about to split gets its children ahead of time too.
            if resident(n) && view.eye_ahead.is_some() {
                sel.kept.push(n);
                let (rho_n, _) = predicted(n);
                if rho_n > view.tau_px / 2.0 {
                    let kids = tree.nodes[n].children.iter().filter(|&&c| !resident(c));
                    sel.prefetch.extend(kids.map(|&c| (c, rho_n / 2.0)));
                }
            }
            continue;
        }
        if !resident(n) {
            // Only roots get here: children are visited once all are resident.
            sel.requests.push((n, f64::INFINITY));
            continue;
        }
        sel.touched.push(n);
        let node = &tree.nodes[n];
        let rho = screen_error(node.delta_m, distance_to_box(view.eye, node.min, node.max), view.k);
        // Split where ρ passes τ now or by the next frame: a fast camera
        // then meets the children near the parent's shape (w ≈ 1), not past it.
        let rho_next = view.eye_next.map_or(rho, |e| rho.max(rho_at(n, e)));
        if rho_next > view.tau_px && !node.children.is_empty() {
            let mut all = true;
            for &c in &node.children {
                if resident(c) {
                    // Kept too: evicting one sibling to load another never ends.
                    sel.touched.push(c);
                } else {
                    all = false;
                    sel.requests.push((c, rho));
                }
            }
            if all {
                stack.extend(node.children.iter().rev());
                continue;
            }
        }
        let dp = tree.parent_delta(n);
        let weight = morph_weight(view.schedule, rho, view.tau_px, node.delta_m, dp);
        sel.draws.push(Draw { node: n, rho, weight, within_tau: rho <= view.tau_px });
        if rho <= view.tau_px {
            prefetch_below(tree, view, n, &predicted, &resident, &mut sel);
        }
    }
    let by_priority = |a: &(usize, f64), b: &(usize, f64)| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0));
    sel.requests.sort_by(by_priority);
    sel.requests.dedup_by_key(|r| r.0);
    sel.prefetch.sort_by(by_priority);
    sel.prefetch.dedup_by_key(|r| r.0);
    sel
}

/// The prefetch of one drawn chunk `n` (within τ): its children, and where
/// the eye approaches it and a child's predicted ρ passes τ/2 (the child
/// will itself split soon after it is drawn) that child's children.
fn prefetch_below(
    tree: &LodTree,
    view: &LodView,
    n: usize,
    predicted: &impl Fn(usize) -> (f64, bool),
    resident: &impl Fn(usize) -> bool,
    sel: &mut Selection,
) {
    let (rho_n, nearing) = predicted(n);
    for &c in &tree.nodes[n].children {
        if !resident(c) {
            sel.prefetch.push((c, rho_n));
            continue;
        }
        sel.kept.push(c);
        let (rho_c, _) = predicted(c);
        if nearing && rho_c > view.tau_px / 2.0 {
            for &g in &tree.nodes[c].children {
                if resident(g) {
                    sel.kept.push(g);
                } else {
                    sel.prefetch.push((g, rho_c));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A complete quadtree over a `size`-metre square, `levels` deep, flat
    /// boxes `h` metres high; δ halves per level from `delta0`.
    fn square_tree(levels: u32, size: f64, delta0: f64) -> LodTree {
        let mut tree = LodTree::default();
        fn add(t: &mut LodTree, key: ChunkKey, parent: Option<usize>, levels: u32, size: f64, delta0: f64) -> usize {
            let n = f64::from(1u32 << key.level);
            let w = size / n;
            let (x0, z0) = (f64::from(key.x) * w, f64::from(key.y) * w);
            let id = t.nodes.len();
            t.nodes.push(LodNode {
                key,
                min: [x0, 0.0, z0],
                max: [x0 + w, 10.0, z0 + w],
                delta_m: delta0 / n,
                parent,
                children: vec![],
                uri: String::new(),
            });
            if key.level + 1 < levels {
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let k = ChunkKey { level: key.level + 1, x: key.x * 2 + dx, y: key.y * 2 + dy };
                    let c = add(t, k, Some(id), levels, size, delta0);
                    t.nodes[id].children.push(c);
                }
            }
            id
        }
        let r = add(&mut tree, ChunkKey { level: 0, x: 0, y: 0 }, None, levels, size, delta0);
        tree.roots.push(r);
        tree
    }

    fn view(eye: [f64; 3], tau: f64) -> LodView {
        LodView {
            eye,
            k: screen_k(640.0, 60f64.to_radians()),
            eye_ahead: None,
            eye_next: None,
            tau_px: tau,
            schedule: MorphSchedule::Bounded,
        }
    }

    #[test]
    fn k_and_rho_follow_the_formula() {
        // 90° fov: tan(45°) = 1, K = w/2.
        assert!((screen_k(640.0, std::f64::consts::FRAC_PI_2) - 320.0).abs() < 1e-9);
        assert_eq!(distance_to_box([0.0, 0.0, 0.0], [3.0, -1.0, 4.0], [5.0, 1.0, 6.0]), 5.0);
        assert_eq!(distance_to_box([4.0, 0.0, 5.0], [3.0, -1.0, 4.0], [5.0, 1.0, 6.0]), 0.0);
        assert_eq!(screen_error(2.0, 100.0, 320.0), 6.4);
        assert_eq!(screen_error(2.0, 0.0, 320.0), f64::INFINITY);
        assert_eq!(screen_error(0.0, 0.0, 320.0), 0.0);
    }

    #[test]
    fn the_cut_never_exceeds_tau_where_children_are_resident() {
        let tree = square_tree(5, 1000.0, 16.0);
        let eyes = [
            [500.0, 20.0, 500.0],
            [0.0, 5.0, 0.0],
            [-300.0, 200.0, 1500.0],
            [250.0, 1.0, 250.0],
            [999.0, 3000.0, 10.0],
        ];
        for eye in eyes {
            for tau in [0.5, 1.0, 2.0, 3.0, 8.0] {
                let v = view(eye, tau);
                let sel = select(&tree, &v, |_| true, |_| true);
                assert!(sel.requests.is_empty());
                let mut area = 0.0;
                for d in &sel.draws {
                    let n = &tree.nodes[d.node];
                    area += (n.max[0] - n.min[0]) * (n.max[2] - n.min[2]);
                    assert!(d.rho <= tau || n.children.is_empty(), "{eye:?} τ {tau}: {:?} ρ {}", n.key, d.rho);
                    assert_eq!(d.within_tau, d.rho <= tau);
                    // The parent was split, so its ρ exceeded τ.
                    if let Some(p) = n.parent {
                        let pn = &tree.nodes[p];
                        assert!(screen_error(pn.delta_m, distance_to_box(eye, pn.min, pn.max), v.k) > tau);
                    }
                }
                // The drawn chunks tile the square exactly once.
                assert!((area - 1e6).abs() < 1e-6, "{eye:?} τ {tau}: area {area}");
            }
        }
    }

    #[test]
    fn a_parent_stays_drawn_until_all_its_children_are_resident() {
        let tree = square_tree(3, 1000.0, 16.0);
        let v = view([500.0, 20.0, 500.0], 1.0);
        // Root and three of its four children resident.
        let missing = tree.nodes[0].children[3];
        let resident = |n: usize| n == 0 || (tree.nodes[n].parent == Some(0) && n != missing);
        let sel = select(&tree, &v, resident, |_| true);
        assert_eq!(sel.draws.len(), 1);
        assert_eq!(sel.draws[0].node, 0);
        assert!(!sel.draws[0].within_tau);
        assert_eq!(sel.draws[0].weight, 0.0, "a chunk above τ shows its own shape");
        assert_eq!(sel.requests, vec![(missing, sel.draws[0].rho)]);
        let mut touched = sel.touched.clone();
        touched.sort();
        let mut want = vec![0];
        want.extend(tree.nodes[0].children.iter().copied().filter(|&c| c != missing));
        want.sort();
        assert_eq!(touched, want, "the root and its resident children are kept");
        // Nothing resident: the root is requested first, nothing drawn.
        let sel = select(&tree, &v, |_| false, |_| true);
        assert!(sel.draws.is_empty());
        assert_eq!(sel.requests, vec![(0, f64::INFINITY)]);
    }

    #[test]
    fn culled_chunks_are_neither_drawn_nor_descended_into() {
        let tree = square_tree(3, 1000.0, 16.0);
        let v = view([500.0, 20.0, 500.0], 1.0);
        let west = |n: usize| tree.nodes[n].min[0] < 500.0;
        let sel = select(&tree, &v, |_| true, west);
        assert!(!sel.draws.is_empty());
        assert!(sel.draws.iter().all(|d| tree.nodes[d.node].min[0] < 500.0));
    }

    #[test]
    fn requests_are_ordered_by_screen_error() {
        let tree = square_tree(3, 1000.0, 16.0);
        let v = view([10.0, 20.0, 10.0], 1.0);
        let level1 = |n: usize| tree.nodes[n].key.level <= 1;
        let sel = select(&tree, &v, level1, |_| true);
        assert!(sel.requests.len() > 4);
        assert!(sel.requests.windows(2).all(|w| w[0].1 >= w[1].1));
        // The nearest level-1 chunk (north-west) waits with the largest ρ.
        let first = tree.nodes[sel.requests[0].0].parent.unwrap();
        assert_eq!(tree.nodes[first].key, ChunkKey { level: 1, x: 0, y: 0 });
    }

    #[test]
    fn bounded_morph_keeps_the_blended_error_within_tau() {
        let (delta, dp) = (1.5, 3.0);
        let k = screen_k(1920.0, 1.0);
        for tau in [0.5, 1.0, 3.0, 10.0] {
            // Every distance at which the chunk can be drawn under τ.
            for i in 1..=4000 {
                let d = f64::from(i) * 5.0;
                let rho = screen_error(delta, d, k);
                if rho > tau {
                    continue;
                }
                let w = morph_weight(MorphSchedule::Bounded, rho, tau, delta, Some(dp));
                let err = blended_error_m(w, delta, dp);
                assert!(err <= tau * d / k * (1.0 + 1e-12), "τ {tau} D {d}: {err} > {}", tau * d / k);
                // Just after the parent split (ρ ≤ τ/2) the chunk has the parent's shape.
                if rho <= tau / 2.0 {
                    assert_eq!(w, 1.0);
                }
            }
            // At ρ = τ the chunk is about to split: its own shape.
            assert_eq!(morph_weight(MorphSchedule::Bounded, tau, tau, delta, Some(dp)), 0.0);
            // The simple form of DESIGN.md when δ_p = 2δ.
            for rho in [0.3 * tau, 0.6 * tau, 0.8 * tau, tau] {
                let w = morph_weight(MorphSchedule::Bounded, rho, tau, delta, Some(dp));
                assert!((w - (tau / rho - 1.0).clamp(0.0, 1.0)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn ulrich_morph_reaches_nine_eighths_of_tau() {
        let (delta, dp, tau) = (1.0, 2.0, 4.0);
        let mut worst: f64 = 0.0;
        for i in 0..=1000 {
            let rho = tau * f64::from(i) / 1000.0;
            let w = morph_weight(MorphSchedule::Ulrich, rho, tau, delta, Some(dp));
            assert!((w - (1.0 - (2.0 * rho / tau - 1.0).clamp(0.0, 1.0))).abs() < 1e-12);
            // Screen error of the blend: ρ·(blended error / δ).
            worst = worst.max(rho * blended_error_m(w, delta, dp) / delta);
        }
        assert!((worst - 9.0 / 8.0 * tau).abs() < 1e-9, "{worst}");
    }

    #[test]
    fn morph_weight_edge_cases() {
        assert_eq!(morph_weight(MorphSchedule::Bounded, 0.5, 1.0, 1.0, None), 0.0, "a root has no parent");
        assert_eq!(morph_weight(MorphSchedule::Bounded, f64::INFINITY, 1.0, 1.0, Some(2.0)), 0.0);
        assert_eq!(morph_weight(MorphSchedule::Bounded, 2.0, 1.0, 1.0, Some(2.0)), 0.0);
        assert_eq!(morph_weight(MorphSchedule::Ulrich, 0.1, 1.0, 1.0, Some(2.0)), 1.0);
    }

    /// The off-axis factor is the worst shift of a point anywhere in the
    /// image per unit of δ·K/D: sampled over displacement directions at the
    /// corner it is reached, and nowhere exceeded.
    #[test]
    fn off_axis_factor_bounds_the_shift_at_the_corner() {
        let (w, h, hfov) = (1920.0, 1080.0, 60f64.to_radians());
        let f = off_axis_factor([w, h], hfov);
        assert!((f - 1.4398).abs() < 1e-3, "{f}");
        let k = screen_k(w, hfov);
        let t = (hfov / 2.0).tan();
        // The corner pixel's direction, at depth z; pixel = K·(x/z, y/z).
        let z = 1000.0;
        let p = [t * z, t * h / w * z, z];
        let (d, eps) = ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt(), 1e-4);
        let mut worst: f64 = 0.0;
        for i in 0..200 {
            for j in 0..100 {
                let (az, el) =
                    (f64::from(i) * std::f64::consts::TAU / 200.0, (f64::from(j) / 99.0 - 0.5) * std::f64::consts::PI);
                let v = [el.cos() * az.cos(), el.sin(), el.cos() * az.sin()].map(|c| c * eps);
                let q = [p[0] + v[0], p[1] + v[1], p[2] + v[2]];
                let shift = ((q[0] / q[2] - p[0] / p[2]).powi(2) + (q[1] / q[2] - p[1] / p[2]).powi(2)).sqrt() * k;
                worst = worst.max(shift / (eps * k / d));
            }
        }
        assert!(worst <= f * (1.0 + 1e-3) && worst > f * 0.995, "worst {worst}, factor {f}");
        // On the axis nothing is added: a square view at 90° doubles at the corner's tan² = 2.
        assert!((off_axis_factor([1.0, 1.0], std::f64::consts::FRAC_PI_2) - 3.0).abs() < 1e-12);
        assert!((screen_k_bound([w, h], hfov) - k * f).abs() < 1e-9);
    }

    /// Every drawn chunk's missing children are prefetched, at the drawn
    /// chunk's ρ, and its resident ones kept; nothing prefetched is also a
    /// request.
    #[test]
    fn children_of_every_drawn_chunk_are_prefetched() {
        let tree = square_tree(4, 1000.0, 16.0);
        let v = view([500.0, 3000.0, 500.0], 2.0);
        let upto_level1 = |n: usize| tree.nodes[n].key.level <= 1;
        let sel = select(&tree, &v, upto_level1, |_| true);
        let drawn_inner: Vec<usize> = sel
            .draws
            .iter()
            .filter(|d| d.within_tau && !tree.nodes[d.node].children.is_empty())
            .map(|d| d.node)
            .collect();
        assert!(!drawn_inner.is_empty());
        for &d in &drawn_inner {
            for &c in &tree.nodes[d].children {
                let p = sel.prefetch.iter().find(|r| r.0 == c).unwrap_or_else(|| panic!("child {c} of {d}"));
                assert!((p.1 - sel.draws.iter().find(|x| x.node == d).unwrap().rho).abs() < 1e-12);
            }
        }
        assert!(sel.prefetch.windows(2).all(|w| w[0].1 >= w[1].1));
        assert!(sel.prefetch.iter().all(|p| sel.requests.iter().all(|r| r.0 != p.0)));
        // Everything resident: nothing to fetch, the drawn chunks' children kept.
        let sel = select(&tree, &v, |_| true, |_| true);
        assert!(sel.prefetch.is_empty() && sel.requests.is_empty());
        for d in sel.draws.iter().filter(|d| !tree.nodes[d.node].children.is_empty()) {
            assert!(tree.nodes[d.node].children.iter().all(|c| sel.kept.contains(c)));
        }
    }

    /// Grandchildren are prefetched only where the eye approaches, and by the
    /// ρ predicted at the eye ahead.
    #[test]
    fn grandchildren_are_prefetched_where_the_eye_is_heading() {
        let tree = square_tree(4, 1000.0, 16.0);
        let level = |n: usize| tree.nodes[n].key.level;
        let resident = |n: usize| level(n) <= 1;
        // High enough that the root is within τ (ρ = 16·554/4990 = 1.78 px).
        let mut v = view([500.0, 5000.0, 500.0], 2.0);
        let still = select(&tree, &v, resident, |_| true);
        assert!(still.draws.iter().all(|d| level(d.node) == 0), "{:?}", still.draws);
        assert!(still.prefetch.is_empty(), "the root's children are resident");
        // Descending fast toward the middle: the level-1 chunks' ρ ahead passes τ/2.
        v.eye_ahead = Some([500.0, 2000.0, 500.0]);
        let moving = select(&tree, &v, resident, |_| true);
        assert!(moving.draws.iter().all(|d| level(d.node) == 0));
        assert!(!moving.prefetch.is_empty());
        assert!(moving.prefetch.iter().all(|p| level(p.0) == 2), "{:?}", moving.prefetch);
        // Climbing away instead: nothing more.
        v.eye = [500.0, 4500.0, 500.0];
        v.eye_ahead = Some([500.0, 6000.0, 500.0]);
        let sel = select(&tree, &v, resident, |_| true);
        assert!(sel.draws.iter().all(|d| level(d.node) == 0));
        assert!(sel.prefetch.is_empty(), "{:?}", sel.prefetch);
    }

    /// A chunk whose ρ passes τ by the next frame splits now; a resident
    /// chunk out of view that is about to split has its children prefetched.
    #[test]
    fn the_next_frame_splits_early_and_out_of_view_chunks_prefetch() {
        let tree = square_tree(3, 1000.0, 16.0);
        let level = |n: usize| tree.nodes[n].key.level;
        // The root within τ (ρ = 1.78 px) now, past it (2.23 px) a frame on.
        let mut v = view([500.0, 5000.0, 500.0], 2.0);
        assert!(select(&tree, &v, |_| true, |_| true).draws.iter().all(|d| level(d.node) == 0));
        v.eye_next = Some([500.0, 4000.0, 500.0]);
        let sel = select(&tree, &v, |_| true, |_| true);
        assert!(sel.draws.iter().all(|d| level(d.node) == 1), "{:?}", sel.draws);
        // Out of view: nothing drawn; with a motion the resident root's children are prefetched.
        let v = view([500.0, 3000.0, 500.0], 2.0);
        let root_only = |n: usize| n == 0;
        assert!(select(&tree, &v, root_only, |_| false).prefetch.is_empty(), "still: nothing");
        let v = LodView { eye_ahead: Some([500.0, 2900.0, 500.0]), ..v };
        let sel = select(&tree, &v, root_only, |_| false);
        assert!(sel.draws.is_empty() && sel.kept == vec![0]);
        assert_eq!(sel.prefetch.iter().map(|p| p.0).collect::<Vec<_>>(), tree.nodes[0].children);
    }

    #[test]
    fn shown_error_scales_by_the_blend() {
        assert_eq!(shown_error_px(0.8, 0.0, 1.0, Some(2.0)), 0.8);
        assert!((shown_error_px(0.8, 0.25, 1.0, Some(2.0)) - 1.0).abs() < 1e-12);
        assert_eq!(shown_error_px(3.0, 1.0, 1.0, None), 3.0);
    }

    #[test]
    fn tree_from_a_tileset_json() {
        let tile = |l: u32, x: u32, y: u32, b: [f64; 12], kids: Vec<Value>| {
            serde_json::json!({
                "boundingVolume": {"box": b}, "geometricError": 4.0 / f64::from(1 << l),
                "content": {"uri": format!("tiles/{l}/{x}/{y}.glb")},
                "extras": {"terrachunk": {"level": l, "x": x, "y": y, "delta_m": 4.0 / f64::from(1 << l)}},
                "children": kids,
            })
        };
        // Centre (east 50, north −50, up 5): glTF (50, 5, 50).
        let b = [50.0, -50.0, 5.0, 50.0, 0.0, 0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 5.0];
        let kid = tile(1, 1, 0, [75.0, -25.0, 5.0, 25.0, 0.0, 0.0, 0.0, 25.0, 0.0, 0.0, 0.0, 5.0], vec![]);
        let ts = serde_json::json!({"root": tile(0, 0, 0, b, vec![kid])});
        let t = LodTree::from_tileset_json(&ts).unwrap();
        assert_eq!(t.roots, vec![0]);
        assert_eq!(t.nodes[0].min, [0.0, 0.0, 0.0]);
        assert_eq!(t.nodes[0].max, [100.0, 10.0, 100.0]);
        assert_eq!(t.nodes[1].key, ChunkKey { level: 1, x: 1, y: 0 });
        assert_eq!(t.nodes[1].min, [50.0, 0.0, 0.0]);
        assert_eq!(t.nodes[1].parent, Some(0));
        assert_eq!(t.parent_delta(1), Some(4.0));
        assert_eq!(t.leaves(), vec![1]);
        assert!(LodTree::from_tileset_json(&serde_json::json!({"root": {}})).is_err());
    }

    /// A child that comes late starts within τ where that is an invisible
    /// step from its parent's shape, else steps τ/2 and fades from there;
    /// never below its schedule nor above where it was.
    #[test]
    fn a_late_child_starts_within_tau_where_the_step_is_invisible() {
        let shown = |rho: f64, w: f64| shown_error_px(rho, w, 1.0, Some(2.0));
        let moved = |rho: f64, from: f64, w: f64| (from - w) * rho * 2.0;
        // The parent was drawn at 1.07 px at τ = 1: its child starts at τ.
        let w = late_weight(0.535, 1.0, (1.0, 2.0), 1.0, 0.0);
        assert!((shown(0.535, w) - 1.0).abs() < 1e-12 && moved(0.535, 1.0, w) <= 0.5, "{w}");
        // Far over τ: a step of τ/2, still above τ, left to the fade.
        let w = late_weight(3.0, 1.0, (1.0, 2.0), 1.0, 0.0);
        assert!((moved(3.0, 1.0, w) - 0.5).abs() < 1e-12 && shown(3.0, w) > 1.0, "{w}");
        // The next frame, nearer: again within τ by an invisible step.
        let next = late_weight(0.55, 1.0, (1.0, 2.0), 0.87, 0.0);
        assert!((shown(0.55, next) - 1.0).abs() < 1e-12 && moved(0.55, 0.87, next) <= 0.5, "{next}");
        // Never below the schedule, never above where it was.
        assert_eq!(late_weight(0.2, 1.0, (1.0, 2.0), 1.0, 0.0), 1.0, "the parent's shape is within τ");
        assert_eq!(late_weight(0.2, 1.0, (1.0, 2.0), 0.7, 0.0), 0.7);
        assert_eq!(late_weight(0.6, 1.0, (1.0, 2.0), 1.0, 0.9), 0.9);
        assert_eq!(late_weight(0.6, 1.0, (1.0, 1.0), 1.0, 0.0), 1.0);
    }
}
