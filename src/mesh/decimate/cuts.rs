//! Steps 1–3: the parent's triangles cut along the dividing lines, and
//! the border and dividing lines refined in 1-D from their own samples.

use super::*;

/// Counter-clockwise triangles over a vertex list, with a fixed flag per edge.
pub(super) struct Soup {
    pub(super) pts: Vec<V>,
    pub(super) tris: Vec<[u32; 3]>,
    pub(super) fixed: Vec<[bool; 3]>,
    /// The parent triangle each one is, unchanged (`u32::MAX`: a piece of a
    /// cut one, or the top level's).
    pub(super) origin: Vec<u32>,
}

/// The starting triangulation: the parent's triangles inside the footprint
/// with every parent edge fixed (the top level: its four corners), cut along
/// the dividing lines, whose pieces are fixed too.
pub(super) fn initial_tin(
    grid: &Window,
    spec: &ChunkSpec,
    mx: Option<u32>,
    mz: Option<u32>,
    nested: Targeting,
) -> (Tin, Vec<u32>) {
    let ((x0, x1), (z0, z1)) = spec.footprint;
    let mut soup = match spec.parent {
        Some(p) => {
            let inside = |v: &MeshVertex| {
                v.x >= f64::from(x0) && v.x <= f64::from(x1) && v.z >= f64::from(z0) && v.z <= f64::from(z1)
            };
            let mut remap = vec![u32::MAX; p.vertices.len()];
            let mut pts = Vec::new();
            for (k, v) in p.vertices.iter().enumerate() {
                if inside(v) {
                    remap[k] = pts.len() as u32;
                    pts.push(V { x: v.x, z: v.z, h: v.h, ph: v.h });
                }
            }
            // Stored clockwise in grid space (see `finish`): turn them back.
            let (tris, origin): (Vec<[u32; 3]>, Vec<u32>) = p
                .triangles
                .iter()
                .enumerate()
                .map(|(k, t)| ([remap[t[0] as usize], remap[t[2] as usize], remap[t[1] as usize]], k as u32))
                .filter(|(t, _)| !t.contains(&u32::MAX))
                .unzip();
            let fixed = vec![[spec.keep_parent_edges; 3]; tris.len()];
            Soup { pts, tris, fixed, origin }
        }
        None => {
            // The corners, and with lines for parts the samples where they
            // meet the borders and each other: a rectangle between each
            // pair, halved on the diagonal the four corners' pair takes.
            let (mut xs, mut zs) = (vec![x0], vec![z0]);
            if spec.dividing_lines == DividingLines::Parts {
                xs.extend(mx);
                zs.extend(mz);
            }
            xs.push(x1);
            zs.push(z1);
            let mut pts = Vec::with_capacity(xs.len() * zs.len());
            for &i in &zs {
                for &j in &xs {
                    let h = grid.vertex_height(i as usize, j as usize);
                    pts.push(V { x: f64::from(j), z: f64::from(i), h, ph: h });
                }
            }
            let n = xs.len() as u32;
            let mut tris = Vec::new();
            for r in 0..zs.len() as u32 - 1 {
                for c in 0..n - 1 {
                    let k = r * n + c;
                    tris.extend([[k, k + 1, k + n + 1], [k, k + n + 1, k + n]]);
                }
            }
            let count = tris.len();
            Soup { pts, tris, fixed: vec![[false; 3]; count], origin: vec![u32::MAX; count] }
        }
    };
    let inherited = soup.pts.len();
    for (vertical, line) in [(true, mx), (false, mz)] {
        if let Some(coord) = line {
            cut_along_line(&mut soup, grid, Line { vertical, coord }, (nested, inherited), spec.lattice());
        }
    }
    (Tin::from_soup(soup.pts, &soup.tris, &soup.fixed), soup.origin)
}

/// A dividing line: `x = coord` (`vertical`) or `z = coord`.
#[derive(Clone, Copy)]
pub(super) struct Line {
    pub(super) vertical: bool,
    pub(super) coord: u32,
}

/// Cuts every triangle `line` crosses, at points on the crossed edges, so
/// that the line becomes a chain of fixed edges. A cut point's morph target
/// is the parent surface's height there; its own height is the line's
/// profile (the sample's, where a crossing falls on a sample). A crossing
/// shared by two triangles is computed once.
///
/// With `lattice` > 1 (quantized output) each crossing then moves along the
/// line to the nearest of `lattice` steps per cell, where the file holds it
/// exactly, so the mesher measures the surface the file will draw. Rounding
/// it only at write time moved it by up to half a step after the mesher had
/// judged the triangles around it: on steep ground, next to a sliver of the
/// parent, that tilted them far past δ (California at 1 m: 151 chunks over
/// δ as written, up to 10 m at δ 1 m). The morph target of a crossing of a
/// parent edge stays the parent's height at the exact crossing, so the
/// pieces' morph planes are the parent triangle's to within the slope times
/// half a step, as `verify` allows; a crossing of a piece edge (the second
/// line's, across the first's pieces) and every vertex placed later take
/// the parent's height where they are ([`Targeting`]).
/// Crossings closer together than a step (a fan of parent edges from a
/// vertex just off the line) land on one point as separate vertices with
/// flat pieces between them, as the file would draw them anyway; a crossing
/// whose move would turn a piece over tries the other neighbouring step,
/// then stays where it is and keeps the mesher's margin.
pub(super) fn cut_along_line(soup: &mut Soup, grid: &Window, line: Line, nested: (Targeting, usize), lattice: f64) {
    let base = soup.pts.len();
    // Per crossing (edge key), how many of its lattice points folded a piece:
    // the nearest first, then the other neighbour, then none (it stays).
    let mut tried: HashMap<(u32, u32), u8> = HashMap::new();
    loop {
        soup.pts.truncate(base);
        let (tris, fixed, origin, moved) = cut_pieces(soup, grid, line, nested, lattice, &tried);
        // Crossings closer together than a step land on one point: the
        // pieces between them are flat, which the file cannot avoid and the
        // mesh carries (each crossing keeps its own morph target, so no
        // piece's morph is wrong; the TIN looks past flat triangles). A
        // piece turned over, or flattened onto a line, sends one of its
        // crossings on, the one tried least.
        // Flat is allowed only where two corners are one point; three
        // distinct corners in a line make a wall with no area under it, the
        // surface two-valued along it (California at 1 m: a child's morph
        // targets read three heights there, one 2.4 m off every parent plane).
        let mut folded: Vec<(u32, u32)> = tris
            .iter()
            .filter(|t| t.iter().any(|v| moved.contains_key(v)))
            .filter(|t| turned(&soup.pts, t))
            .filter_map(|t| {
                t.iter().filter_map(|v| moved.get(v)).copied().min_by_key(|k| (tried.get(k).copied().unwrap_or(0), *k))
            })
            .collect();
        if folded.is_empty() {
            soup.tris = tris;
            soup.fixed = fixed;
            soup.origin = origin;
            return;
        }
        folded.sort_unstable();
        folded.dedup();
        for k in folded {
            *tried.entry(k).or_insert(0) += 1;
        }
    }
}

/// Whether piece `t` is turned over, or flattened onto a line through
/// three distinct points (flat is allowed only where two corners are one
/// point).
pub(super) fn turned(pts: &[V], t: &[u32; 3]) -> bool {
    let pos = |v: u32| {
        let v = &pts[v as usize];
        Coord { x: v.x, y: v.z }
    };
    let o = robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2]));
    let same = |a: u32, b: u32| pos(a).x == pos(b).x && pos(a).y == pos(b).y;
    o < 0.0 || (o == 0.0 && !same(t[0], t[1]) && !same(t[1], t[2]) && !same(t[2], t[0]))
}

/// The pieces of [`cut_along_line`], each crossing (edge key) on the
/// nearest lattice point, or the other neighbour after `tried` 1 fold, or
/// left exact after 2; and the crossings moved onto the lattice (vertex →
/// edge key).
#[allow(clippy::type_complexity)]
pub(super) fn cut_pieces(
    soup: &mut Soup,
    grid: &Window,
    Line { vertical, coord }: Line,
    (nested, inherited): (Targeting, usize),
    lattice: f64,
    tried: &HashMap<(u32, u32), u8>,
) -> (Vec<[u32; 3]>, Vec<[bool; 3]>, Vec<u32>, HashMap<u32, (u32, u32)>) {
    let c = f64::from(coord);
    let across = |v: &V| if vertical { v.x } else { v.z };
    let along = |v: &V| if vertical { v.z } else { v.x };
    let side = |v: &V| across(v).total_cmp(&c) as i8;
    let mut cuts: HashMap<(u32, u32), u32> = HashMap::new();
    let mut moved: HashMap<u32, (u32, u32)> = HashMap::new();
    let mut cut = |pts: &mut Vec<V>, a: u32, b: u32| -> u32 {
        let key = (a.min(b), a.max(b));
        *cuts.entry(key).or_insert_with(|| {
            let (p, q) = (pts[key.0 as usize], pts[key.1 as usize]);
            let s = (c - across(&p)) / (across(&q) - across(&p));
            let mut t = along(&p) + s * (along(&q) - along(&p));
            let ph = p.ph + s * (q.ph - p.ph);
            let at = |t: f64| {
                let (j, i) = if vertical { (coord, t as u32) } else { (t as u32, coord) };
                grid.vertex_height(i as usize, j as usize)
            };
            let mut on_lattice = false;
            let attempt = tried.get(&key).copied().unwrap_or(0);
            if (t - t.round()).abs() >= 1e-6 && lattice > 1.0 {
                // The nearest grid point, then the other neighbour; never a
                // sample's (a vertex may be there already: the border's
                // midpoint, forced where the line meets it).
                let (nearest, y) = ((t * lattice).round(), t * lattice);
                let other = if y > nearest { nearest + 1.0 } else { nearest - 1.0 };
                let mut candidates = [nearest, other].into_iter().map(|n| n / lattice).filter(|t| !whole_f(*t));
                if let Some(r) = candidates.nth(usize::from(attempt)) {
                    t = r;
                    on_lattice = true;
                }
            }
            // A crossing that falls on a sample takes the sample itself (its
            // fill over nodata), so a border crossing (always on a sample) is
            // the same vertex the neighbour across that border makes. Between
            // samples it takes the line's own profile, not the parent's
            // height there: that can be δ away, and where the line's
            // refinement puts a sample a hair from the crossing, the two
            // would make a near-vertical wall that the next level's cuts
            // shred into slivers no f32 file can place. Only the
            // morph target must lie on the parent surface.
            let h = if (t - t.round()).abs() < 1e-6 {
                t = t.round();
                at(t)
            } else {
                let (lo, hi) = (t.floor(), t.ceil());
                at(lo) + (t - lo) * (at(hi) - at(lo))
            };
            let (x, z) = if vertical { (c, t) } else { (t, c) };
            // A crossing of an edge an earlier line's cut made (a piece
            // edge, inside one parent triangle, from a crossing the grid
            // may have moved off the parent's planes) takes the parent's
            // height where it lands ([`Targeting`]); a crossing of a parent
            // edge keeps the height at the exact crossing, right for the
            // parent triangles on both sides of that edge.
            let ph = match nested.parent {
                _ if !nested.nested => h,
                Some(parent) if key.1 as usize >= inherited => parent.locate(x, z, 1e-6).map_or(ph, |(_, ph)| ph),
                _ => ph,
            };
            pts.push(V { x, z, h, ph });
            let v = (pts.len() - 1) as u32;
            if on_lattice {
                moved.insert(v, key);
            }
            v
        })
    };
    let mut tris = Vec::with_capacity(soup.tris.len() + soup.tris.len() / 8);
    let mut fixed = Vec::with_capacity(tris.capacity());
    let mut origin = Vec::with_capacity(tris.capacity());
    for ((&t, &f), &o) in soup.tris.iter().zip(&soup.fixed).zip(&soup.origin) {
        let s = t.map(|v| side(&soup.pts[v as usize]));
        let crosses = |k: usize| s[k] * s[(k + 1) % 3] < 0;
        if let Some(k) = (0..3).find(|&k| crosses(k) && crosses((k + 2) % 3)) {
            // Corner k alone on its side: cut edges k and k + 2.
            let (a, b, cc) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (fab, fbc, fca) = (f[k], f[(k + 1) % 3], f[(k + 2) % 3]);
            let p = cut(&mut soup.pts, a, b);
            let q = cut(&mut soup.pts, cc, a);
            tris.push([a, p, q]);
            fixed.push([fab, true, fca]);
            origin.extend([u32::MAX; 3]);
            // The quadrilateral p, b, c, q: the Delaunay diagonal.
            let pos = |v: u32| {
                let v = &soup.pts[v as usize];
                Coord { x: v.x, y: v.z }
            };
            if robust::incircle(pos(p), pos(b), pos(cc), pos(q)) > 0.0 {
                tris.extend([[p, b, q], [b, cc, q]]);
                fixed.extend([[fab, false, true], [fbc, fca, false]]);
            } else {
                tris.extend([[p, b, cc], [p, cc, q]]);
                fixed.extend([[fab, fbc, false], [false, fca, true]]);
            }
        } else if let Some(k) = (0..3).find(|&k| s[k] == 0 && crosses((k + 1) % 3)) {
            // Through corner k and across the opposite edge.
            let (a, b, cc) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (fab, fbc, fca) = (f[k], f[(k + 1) % 3], f[(k + 2) % 3]);
            let p = cut(&mut soup.pts, b, cc);
            tris.extend([[a, b, p], [a, p, cc]]);
            fixed.extend([[fab, fbc, true], [true, fbc, fca]]);
            origin.extend([u32::MAX; 2]);
        } else {
            // Not crossed; an edge lying on the line becomes fixed.
            let on = |k: usize| s[k] == 0 && s[(k + 1) % 3] == 0;
            tris.push(t);
            fixed.push([f[0] || on(0), f[1] || on(1), f[2] || on(2)]);
            origin.push(o);
        }
    }
    (tris, fixed, origin, moved)
}

/// Inserts interior sample (i, j), queued from triangle `t`. A sample within
/// `within` cells of a fixed edge splits that edge instead of leaving a sliver
/// beside it: within rounding (10⁻⁷), a zero-width sliver would make the
/// surface two-valued along the edge; with quantized output, within one
/// step of the lattice, the sliver's far corners are cut points the file
/// may move by a step, and a later level's crossing of the edge, placed on
/// the lattice, turned it over (Sierra 3 × 3 at 5 m, 32-cell leaves: 34
/// triangles, samples 10⁻⁴ cells from a parent edge).
pub(super) fn insert_interior(
    tin: &mut Tin,
    grid: &Window,
    t: u32,
    (j, i): (u32, u32),
    nested: Targeting,
    within: f64,
) {
    let p = Coord { x: f64::from(j), y: f64::from(i) };
    let h = grid.vertex_height(i as usize, j as usize);
    match tin.locate_from(t, p) {
        Position::Face(f) => {
            let near = (0..3).map(|k| 3 * f + k).find(|&e| {
                if !tin.is_fixed(e) {
                    return false;
                }
                let (a, b) = tin.ends(e);
                beside(&tin.pts[a as usize], &tin.pts[b as usize], p, within)
                    && tin.splits_cleanly(e, p)
                    && data_across(tin, grid, e)
            });
            match near {
                Some(e) => {
                    let ph = nested.on_edge(tin, e, p, h);
                    let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
                    tin.split_edge(e, v);
                }
                None => {
                    let ph = nested.in_triangle(tin, f, p, h);
                    let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
                    tin.split_triangle(f, v);
                }
            }
        }
        Position::Edge(e) => {
            let ph = nested.on_edge(tin, e, p, h);
            let v = tin.add_vertex(V { x: p.x, z: p.y, h, ph });
            tin.split_edge(e, v);
        }
        Position::Vertex(_) | Position::Outside => {}
    }
}

/// Whether `p` lies within `within` cells of the segment a–b, its foot
/// strictly between the ends.
pub(super) fn beside(a: &V, b: &V, p: Coord<f64>, within: f64) -> bool {
    let (dx, dz) = (b.x - a.x, b.z - a.z);
    let len2 = dx * dx + dz * dz;
    let cross = dx * (p.y - a.z) - dz * (p.x - a.x);
    let along = (dx * (p.x - a.x) + dz * (p.y - a.z)) / len2;
    cross.abs() <= within * len2.sqrt() && along > 0.0 && along < 1.0
}

/// Whether the triangle across half-edge `e` covers a valid sample (or no
/// triangle is across, or the DEM has no voids). A sample split onto `e`
/// becomes a corner of the triangles across, and a corner with data keeps
/// a triangle written ([`finish`]); across a parent edge over a void, the
/// parent's triangle is not written and the child's would stand outside
/// the parent's surface (Seamount `quantize` at 5 m, 16-cell leaves).
pub(super) fn data_across(tin: &Tin, grid: &Window, e: u32) -> bool {
    if grid.grid.filled.is_none() {
        return true;
    }
    let Some(tri) = tin.across(e) else { return true };
    let (x1, z1) = grid.last();
    let clip = ((grid.x0 as u32, x1 as u32), (grid.z0 as u32, z1 as u32));
    let mut any = false;
    scan_triangle(grid, clip, &tri, |_, _, _| {
        any = true;
        f64::INFINITY
    });
    any
}

/// Where a new vertex's morph target, the parent surface's height at it,
/// comes from: interpolated over the triangle or edge of this TIN it falls
/// in (with f32 output every triangle refines one parent triangle, linear
/// there), or, with quantized output, read from the parent itself.
///
/// A quantized file moves each crossing along its line onto its grid. The
/// crossing keeps the parent's height at the exact crossing, which the
/// planes of the parent triangles beside it miss at the moved point by
/// their slope times the move, and the pieces' edges move with it, so a
/// sample may fall on the wrong side of a parent edge by that much: on a
/// parent sliver either is metres for a thousandth of a cell. Interpolated,
/// that went on into every vertex placed against the crossing, and from
/// them into the next, inside ordinary parent triangles whose gentle slope
/// allows no such miss (Provence at 5 m, 16-cell leaves: a sample 0.75 m
/// off its parent; Sierra 3 × 3 at 5 m, 16-cell leaves: 7.3 m, two
/// samples from the crossing). Reading the parent costs quantized builds'
/// mesher about 45 % more time (Sierra 3 × 3 at 5 m: 8.5 → 12.6
/// thread-seconds, the whole build 9.0 → 11.1 s).
#[derive(Clone, Copy)]
pub(super) struct Targeting<'a> {
    /// The chunk has a parent (at the top level a target is the height).
    pub(super) nested: bool,
    /// The parent's surface, given for quantized output.
    pub(super) parent: Option<&'a SurfaceLocator<'a>>,
}

impl Targeting<'_> {
    /// The target at `p`, of height `h`, whose parent height interpolates
    /// as `interpolated`.
    pub(super) fn target(&self, p: Coord<f64>, h: f64, interpolated: impl FnOnce() -> f64) -> f64 {
        match self.parent {
            _ if !self.nested => h,
            Some(parent) => parent.locate(p.x, p.y, 1e-6).map_or_else(interpolated, |(_, ph)| ph),
            None => interpolated(),
        }
    }

    /// The target at `p` of height `h` in triangle `t`.
    pub(super) fn in_triangle(&self, tin: &Tin, t: u32, p: Coord<f64>, h: f64) -> f64 {
        let [a, b, c] = tin.corners(t);
        self.target(p, h, || match plane_weights(&a, &b, &c, p.x, p.y) {
            Some([_, l1, l2]) => (1.0 - l1 - l2) * a.ph + l1 * b.ph + l2 * c.ph,
            None => a.ph,
        })
    }

    /// The target at `p` of height `h` on (or next to) half-edge `e`.
    pub(super) fn on_edge(&self, tin: &Tin, e: u32, p: Coord<f64>, h: f64) -> f64 {
        let (a, b) = tin.ends(e);
        let (a, b) = (tin.pts[a as usize], tin.pts[b as usize]);
        self.target(p, h, || {
            let (dx, dz) = (b.x - a.x, b.z - a.z);
            let s = (((p.x - a.x) * dx + (p.y - a.z) * dz) / (dx * dx + dz * dz)).clamp(0.0, 1.0);
            a.ph + s * (b.ph - a.ph)
        })
    }
}

/// 1-D greedy refinement of the line `x = coord` (`vertical`) or `z = coord`
/// over `span`, a chain of edges: split every interval at its worst valid
/// sample until all are within `target`.
pub(super) fn refine_line(
    tin: &mut Tin,
    grid: &Window,
    vertical: bool,
    coord: u32,
    span: Span,
    target: Targets,
    nested: Targeting,
) {
    let c = f64::from(coord);
    let (lo, hi) = (f64::from(span.0), f64::from(span.1));
    let mut pts: Vec<(f64, u32)> = tin
        .pts
        .iter()
        .enumerate()
        .filter_map(|(k, v)| {
            let (along, across) = if vertical { (v.z, v.x) } else { (v.x, v.z) };
            (across == c && along >= lo && along <= hi).then_some((along, k as u32))
        })
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    chain_ties(&mut pts, |a, b| tin.find_edge(a, b).is_some());
    let sample = |t: u32| if vertical { (coord, t) } else { (t, coord) };
    let mut stack: Vec<((f64, u32), (f64, u32))> = pts.windows(2).map(|w| (w[0], w[1])).collect();
    while let Some((a, b)) = stack.pop() {
        let (ha, hb) = (tin.pts[a.1 as usize].h, tin.pts[b.1 as usize].h);
        let target = target.over(&[tin.pts[a.1 as usize], tin.pts[b.1 as usize]]);
        let first = (a.0 + 1e-9).ceil() as i64;
        let last = (b.0 - 1e-9).floor() as i64;
        let mut worst: Option<(f64, u32, f64)> = None;
        for t in first..=last {
            let (j, i) = sample(t as u32);
            let h = grid.sample(i as usize, j as usize);
            if h.is_nan() {
                continue;
            }
            let h = f64::from(h);
            let s = (t as f64 - a.0) / (b.0 - a.0);
            let err = (h - (ha + s * (hb - ha))).abs();
            if err > target && worst.is_none_or(|w| err > w.0) {
                worst = Some((err, t as u32, h));
            }
        }
        let Some((_, t, h)) = worst else { continue };
        let Some(e) = tin.find_edge(a.1, b.1) else {
            unreachable!("a line is a chain of edges");
        };
        let s = (f64::from(t) - a.0) / (b.0 - a.0);
        let (j, i) = sample(t);
        let (pa, pb) = (tin.pts[a.1 as usize], tin.pts[b.1 as usize]);
        let ph = nested.target(Coord { x: f64::from(j), y: f64::from(i) }, h, || pa.ph + s * (pb.ph - pa.ph));
        let v = tin.add_vertex(V { x: f64::from(j), z: f64::from(i), h, ph });
        tin.split_edge(e, v);
        let m = (f64::from(t), v);
        stack.push((a, m));
        stack.push((m, b));
    }
}

/// The samples step 4 leaves alone: those on borders and dividing lines
/// (decided in 1-D), and those that are already vertices. The latter matters
/// where a vertex sits (within rounding) on an edge split at a non-sample
/// point: the zero-width sliver there makes the neighbouring triangle's plane
/// look wrong at the vertex, which is exact.
pub(super) struct Lines {
    pub(super) xs: [Option<u32>; 3],
    pub(super) zs: [Option<u32>; 3],
    pub(super) origin: (u32, u32),
    pub(super) width: usize,
    pub(super) vertex: Vec<bool>,
}

impl Lines {
    pub(super) fn new(tin: &Tin, footprint: (Span, Span), xs: [Option<u32>; 3], zs: [Option<u32>; 3]) -> Self {
        let ((x0, x1), (z0, z1)) = footprint;
        let width = (x1 - x0 + 1) as usize;
        let mut l = Lines { xs, zs, origin: (x0, z0), width, vertex: vec![false; width * (z1 - z0 + 1) as usize] };
        for p in &tin.pts {
            if whole(p.x) && whole(p.z) {
                l.mark_vertex(p.z as u32, p.x as u32);
            }
        }
        l
    }
    #[inline]
    pub(super) fn mark_vertex(&mut self, i: u32, j: u32) {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize] = true;
    }
    #[inline]
    pub(super) fn unmark_vertex(&mut self, i: u32, j: u32) {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize] = false;
    }
    #[inline]
    pub(super) fn is_vertex(&self, i: u32, j: u32) -> bool {
        self.vertex[(i - self.origin.1) as usize * self.width + (j - self.origin.0) as usize]
    }
    #[inline]
    pub(super) fn row_is_line(&self, i: u32) -> bool {
        self.zs.contains(&Some(i))
    }
    #[inline]
    pub(super) fn col_is_line(&self, j: u32) -> bool {
        self.xs.contains(&Some(j))
    }
}
