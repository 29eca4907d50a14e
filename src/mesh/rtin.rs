//! Right-triangle bintree (RTIN) mesher: the binary triangle tree of the
//! seeds' own chunker (Lindstrom et al. 1996, as in `chunklod-demo-readme`;
//! the 4-8 mesh that martini also uses), with true errors.
//!
//! Every triangle is right-isosceles: a square of `c` cells is cut by one
//! diagonal (main where its column plus row index, in squares of `c`, is
//! even, else the other one), each half by the square's centre into four
//! triangles whose hypotenuses are the square's sides, and each of those by
//! its side's midpoint into two halves of the squares of `c/2`. So the
//! pattern depends only on a triangle's place, not on any chunk or grid,
//! and chunks whose footprints are squares of 2^k cells aligned to 2^k
//! ([`plan`]) are unions of its triangles.
//!
//! One bottom-up pass ([`Rtin::new`]) gives every vertex `m` the largest
//! *true* error of the triangles split at `m`: the maximum over every valid
//! sample a triangle covers of |plane − sample| (plus what its corners'
//! heights round by in quantized output), and the same of the vertices its
//! children are split at. A triangle is split where that exceeds δ, so a
//! mesh at δ keeps every sample within δ, the two triangles that share a
//! hypotenuse split together (no crack), and a mesh at a smaller δ refines
//! one at a larger δ (nesting). A chunk of level L is the mesh at δ(L) of
//! the triangles inside its square: same-level neighbours draw one border,
//! and each child vertex's morph target is its parent's surface exactly
//! (the midpoint of the parent triangle's edge it splits, interpolated).
//!
//! The grid need not be 2^k + 1 samples: a triangle reaching past the
//! grid's last column or row is always split, until each piece lies inside
//! the grid or outside it (pieces outside are dropped), so the grid's edge is
//! made of triangle edges. Nodata is handled as the greedy TIN does: errors
//! count valid samples only, a vertex on nodata takes the void fill, and a
//! triangle that covers no valid sample is not written.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use rayon::prelude::*;

use super::grid::Grid;
use super::{ChunkMesh, MeshError, MeshVertex, ParentPoint};
use crate::geodesy::Globe;
use crate::quadtree::{ChunkKey, ChunkTree, Span};
use crate::store::{self, Big, Memory};

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

fn floor_pow2(n: u32) -> u32 {
    1 << (31 - n.leading_zeros())
}

/// The side, in cells, of the squares a level of a [`plan`]ned tree cuts
/// the grid into (its spans are those squares clipped to the grid).
pub fn square_side(tree: &ChunkTree, level: u32) -> u32 {
    let [wx, wz] = tree.widest_cells(level);
    wx.max(wz).max(1).next_power_of_two()
}

/// A vertex's place on the grid: column, row.
type P = (u32, u32);

/// A bintree triangle: hypotenuse `a`–`b`, right angle at `r`.
#[derive(Clone, Copy, Debug)]
struct Tri {
    a: P,
    b: P,
    r: P,
}

impl Tri {
    /// Where it is split (its hypotenuse's midpoint), if that is a sample.
    #[inline]
    fn midpoint(&self) -> Option<P> {
        let (sx, sz) = (self.a.0 + self.b.0, self.a.1 + self.b.1);
        (sx.is_multiple_of(2) && sz.is_multiple_of(2)).then_some((sx / 2, sz / 2))
    }

    /// The two halves it splits into at `m`.
    #[inline]
    fn children(&self, m: P) -> [Tri; 2] {
        [Tri { a: self.r, b: self.a, r: m }, Tri { a: self.b, b: self.r, r: m }]
    }

    /// Squared hypotenuse, in cells².
    #[inline]
    fn hyp2(&self) -> u64 {
        let dx = u64::from(self.a.0.abs_diff(self.b.0));
        let dz = u64::from(self.a.1.abs_diff(self.b.1));
        dx * dx + dz * dz
    }

    /// Bounding box: (x0, x1, z0, z1).
    #[inline]
    fn bbox(&self) -> (u32, u32, u32, u32) {
        let (a, b, r) = (self.a, self.b, self.r);
        (a.0.min(b.0).min(r.0), a.0.max(b.0).max(r.0), a.1.min(b.1).min(r.1), a.1.max(b.1).max(r.1))
    }
}

/// A vertex's grid place (its coordinates are whole samples).
fn point(v: &MeshVertex) -> P {
    (v.x as u32, v.z as u32)
}

/// Where a bintree triangle with corners `c` (in any order) would split:
/// the midpoint of its longest side, if that is a sample.
fn split_point(c: [P; 3]) -> Option<P> {
    let d2 = |p: P, q: P| {
        let (dx, dz) = (u64::from(p.0.abs_diff(q.0)), u64::from(p.1.abs_diff(q.1)));
        dx * dx + dz * dz
    };
    let (a, b) = [(c[0], c[1]), (c[1], c[2]), (c[2], c[0])].into_iter().max_by_key(|&(p, q)| d2(p, q))?;
    Tri { a, b, r: a }.midpoint()
}

/// Hashes grid places for a chunk's vertex index: a multiply per word, as
/// places are few and not chosen by anyone hostile.
#[derive(Default)]
struct PointHasher(u64);

impl Hasher for PointHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u32(u32::from(b));
        }
    }

    fn write_u32(&mut self, i: u32) {
        self.0 = (self.0.rotate_left(5) ^ u64::from(i)).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

/// Where a triangle lies against the grid `[0, xmax] × [0, zmax]`.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Place {
    Inside,
    /// Its box reaches past the grid's last column or row from inside:
    /// always split. (A box is a superset, so a few triangles that lie
    /// wholly outside are split too; that costs nothing the output keeps.)
    Straddles,
    Outside,
}

/// What the curved frame adds to a triangle's error: how far its chord,
/// written between the world positions of its corners, may stray from the
/// surface its heights describe ([`Globe::margin_m`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sag {
    /// The globe's curvature bounds, along the normal and across it.
    pub curvature: [f64; 2],
    /// The grid spacing, metres.
    pub spacing: [f64; 2],
}

impl Sag {
    /// The sag of the frame of `globe` on a grid `spacing` apart.
    pub fn of(globe: &Globe, spacing: [f64; 2]) -> Sag {
        Sag { curvature: globe.curvature, spacing }
    }

    /// The sag bound of the triangle with these corners (grid units, with
    /// their heights): [`Globe::margin_m`] for the smallest circle holding
    /// it and its planar slope.
    fn of_triangle(&self, c: &[MeshVertex; 3]) -> f64 {
        let s = self.spacing;
        let p = c.map(|v| [v.x * s[0], v.z * s[1], v.h]);
        let d = |a: usize, b: usize| [p[b][0] - p[a][0], p[b][1] - p[a][1], p[b][2] - p[a][2]];
        let (u, v, w) = (d(0, 1), d(0, 2), d(1, 2));
        let (a2, b2, c2) = (u[0] * u[0] + u[1] * u[1], v[0] * v[0] + v[1] * v[1], w[0] * w[0] + w[1] * w[1]);
        // On its longest side where the angle there is right or obtuse,
        // else its circumcircle (R² = a²b²c² / 16 area²).
        let longest = a2.max(b2).max(c2);
        let r2 = if 2.0 * longest >= a2 + b2 + c2 {
            longest / 4.0
        } else {
            a2 * b2 * c2 / (2.0 * (a2 * b2 + b2 * c2 + c2 * a2) - (a2 * a2 + b2 * b2 + c2 * c2))
        };
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let slope = ((n[0] * n[0] + n[1] * n[1]) / (n[2] * n[2])).sqrt();
        let slope = if slope.is_finite() { slope } else { 0.0 };
        Globe::margin_m(self.curvature, r2, slope)
    }
}

/// The error field: what every chunk of one build is cut from, for any
/// tree it [`serves`](Rtin::serves).
pub struct Rtin {
    width: usize,
    height: usize,
    /// Per sample (row-major): the largest true error of the triangles split
    /// there and of everything below them, in metres, rounded up to f32 (or
    /// a bound on the same rung).
    errors: Big<f32>,
    /// The side of the top squares the pass went up to.
    top: u32,
    /// The smallest δ (every level's is it times a power of two).
    ladder: f64,
    /// The height step the errors include.
    step: Option<f64>,
    /// The curved frame's chord sag the errors include.
    sag: Option<Sag>,
    /// [`Rtin::densest_squares`] per square side, kept: the refine count
    /// asks again for the same sides with one more level each time.
    densest: Mutex<HashMap<u32, Vec<usize>>>,
}

impl Rtin {
    /// The bottom-up pass over the whole grid, for the levels of `tree`
    /// (planned by [`plan`]). `height_step`: quantized output rounds every
    /// height to multiples of it, which each triangle's error then includes.
    /// `sag`: in the curved frame each triangle's error also holds how far
    /// its chord may sag ([`Sag`]); held in the field, it grows with the
    /// triangles as the errors do, so the meshes still conform and nest.
    pub fn new(grid: &Grid, tree: &ChunkTree, height_step: Option<f64>, sag: Option<Sag>) -> Self {
        Self::with_scans(grid, tree, height_step, sag, false, None).expect("in memory")
    }

    /// [`Rtin::new`], the field in a scratch file where `memory` says an
    /// array of its size goes to one (which can fail, naming the file).
    pub fn new_in(
        grid: &Grid,
        tree: &ChunkTree,
        height_step: Option<f64>,
        sag: Option<Sag>,
        memory: Option<&Memory>,
    ) -> std::io::Result<Self> {
        Self::with_scans(grid, tree, height_step, sag, false, memory)
    }

    /// [`Rtin::new_in`], scanning every triangle when `exact` (else only
    /// those whose bounds straddle a δ).
    fn with_scans(
        grid: &Grid,
        tree: &ChunkTree,
        height_step: Option<f64>,
        sag: Option<Sag>,
        exact: bool,
        memory: Option<&Memory>,
    ) -> std::io::Result<Self> {
        let top = square_side(tree, 0);
        let ladder = *tree.delta_m.last().expect("a tree has a level");
        let mut errors = Big::filled(grid.width * grid.height, 0.0f32, memory)?;
        let field = Field {
            grid,
            xmax: (grid.width - 1) as u32,
            zmax: (grid.height - 1) as u32,
            step: height_step.unwrap_or(0.0),
            ladder,
            exact,
            sag,
            errors: store::as_atomic(&mut errors),
        };
        let mut c = 2;
        while c <= top {
            field.level(c, false);
            field.level(c, true);
            c *= 2;
        }
        Ok(Rtin {
            width: grid.width,
            height: grid.height,
            errors,
            top,
            ladder,
            step: height_step,
            sag,
            densest: Mutex::default(),
        })
    }

    /// Whether this field meshes `tree`'s chunks with heights rounded to
    /// `height_step`: the same top squares, smallest δ and step (refine
    /// levels change neither).
    pub fn serves(&self, tree: &ChunkTree, height_step: Option<f64>, sag: Option<Sag>) -> bool {
        square_side(tree, 0) == self.top
            && tree.delta_m.last() == Some(&self.ladder)
            && height_step.map(f64::to_bits) == self.step.map(f64::to_bits)
            && sag == self.sag
    }

    /// The deepest level of `tree` (one this field serves) with a chunk that
    /// may have more than `max_vertices` vertices, from the field alone: a
    /// chunk's vertices are its square's corners and the samples in it
    /// whose error exceeds its δ. `None` where every chunk fits, or where
    /// the count would need more than 4 M squares × rungs of tables (tiny
    /// leaves on a huge grid): the build then finds out.
    pub fn densest_over(&self, tree: &ChunkTree, max_vertices: usize) -> Option<u32> {
        let depth = tree.depth();
        let sides: Vec<u32> = (0..=depth).map(|l| square_side(tree, l)).collect();
        let mut distinct = sides.clone();
        distinct.dedup();
        let squares = |s: u32| (((self.width - 1) / s as usize) + 1) * (((self.height - 1) / s as usize) + 1);
        if distinct.iter().map(|&s| squares(s) * RUNGS).sum::<usize>() > 1 << 22 {
            return None;
        }
        let mut known = self.densest.lock().unwrap_or_else(|e| e.into_inner());
        let missing: Vec<u32> = distinct.iter().copied().filter(|s| !known.contains_key(s)).collect();
        if !missing.is_empty() {
            known.extend(missing.iter().copied().zip(self.densest_squares(&missing)));
        }
        (0..=depth).rev().find(|&level| {
            // Samples above rung `depth − level` exceed this level's δ.
            let k = ((depth - level) as usize).min(RUNGS - 1);
            known[&sides[level as usize]][k] + 4 > max_vertices
        })
    }

    /// Per side in `sides` and per rung k, the most samples any closed
    /// square of that side (aligned to it) holds above rung k: one pass over
    /// the field, rows in parallel.
    fn densest_squares(&self, sides: &[u32]) -> Vec<Vec<usize>> {
        let (wc, hc) = ((self.width - 1) as u32, (self.height - 1) as u32);
        let shape: Vec<(u32, usize)> = sides.iter().map(|&s| (s, wc.div_ceil(s).max(1) as usize)).collect();
        let tables = || -> Vec<Vec<u32>> {
            shape.iter().map(|&(s, nx)| vec![0u32; nx * hc.div_ceil(s).max(1) as usize * RUNGS]).collect()
        };
        let rows: Vec<u32> = (0..=hc).collect();
        let sums = rows
            .par_chunks(64)
            .fold(tables, |mut t, chunk| {
                for &z in chunk {
                    let row = &self.errors[z as usize * self.width..][..self.width];
                    for (x, &e) in row.iter().enumerate() {
                        if f64::from(e) <= self.ladder {
                            continue;
                        }
                        let k = (rung(e, self.ladder) as usize).min(RUNGS - 1);
                        let x = x as u32;
                        for (table, &(s, nx)) in t.iter_mut().zip(&shape) {
                            // Every closed square the sample lies in.
                            let (i, j) = ((x / s) as usize, (z / s) as usize);
                            let nz = table.len() / (nx * RUNGS);
                            let is = [Some(i), (x.is_multiple_of(s) && i > 0).then(|| i - 1)];
                            let js = [Some(j), (z.is_multiple_of(s) && j > 0).then(|| j - 1)];
                            for jj in js.into_iter().flatten().filter(|&jj| jj < nz) {
                                for ii in is.into_iter().flatten().filter(|&ii| ii < nx) {
                                    table[(jj * nx + ii) * RUNGS + k] += 1;
                                }
                            }
                        }
                    }
                }
                t
            })
            .reduce(tables, |mut a, b| {
                for (ta, tb) in a.iter_mut().zip(&b) {
                    for (x, y) in ta.iter_mut().zip(tb) {
                        *x += y;
                    }
                }
                a
            });
        sums.iter()
            .map(|table| {
                let mut most = vec![0usize; RUNGS];
                for sq in table.chunks(RUNGS) {
                    let mut above = 0usize;
                    for k in (0..RUNGS).rev() {
                        most[k] = most[k].max(above);
                        above += sq[k] as usize;
                    }
                }
                most
            })
            .collect()
    }

    /// The error stored at a vertex (0 for a leaf vertex, ∞ where a
    /// triangle split there reaches past the grid).
    pub fn error_at(&self, x: u32, z: u32) -> f32 {
        self.errors[z as usize * self.width + x as usize]
    }

    /// Meshes chunk `key` of `tree` at its level's δ: the bintree's
    /// triangles inside its square, with each vertex's parent-surface height.
    /// `max_vertices`: more makes [`MeshError::TooDense`]; `cancel`: set
    /// when another chunk failed. With a `globe` (the curved frame, and the
    /// grid's spacing in metres) a
    /// triangle is also split where its chord's sag ([`Globe::margin_m`])
    /// would take it past δ, and each vertex gets its parent-surface point.
    pub fn build_chunk(
        &self,
        grid: &Grid,
        tree: &ChunkTree,
        key: ChunkKey,
        max_vertices: usize,
        cancel: Option<&AtomicBool>,
        globe: Option<(&Globe, [f64; 2])>,
    ) -> Result<ChunkMesh, MeshError> {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            return Err(MeshError::Cancelled);
        }
        let level = key.level as usize;
        let footprint = tree.footprint(key);
        let delta_m = tree.delta_m[level];
        let side = square_side(tree, key.level);
        let ((x0, _), (z0, _)) = footprint;
        // Descend from the parent's square (its corners are parent vertices,
        // so their parent-surface height is their own), or the chunk's own.
        let (from, parent) = match level {
            0 => ((x0, z0, side), None),
            _ => {
                let ps = square_side(tree, key.level - 1);
                (((x0 / ps) * ps, (z0 / ps) * ps, ps), Some((ps, tree.delta_m[level - 1])))
            }
        };
        let mut m = Mesher {
            rtin: self,
            grid,
            side,
            square: (x0, z0),
            delta_m,
            parent,
            index: VertexIndex::over(side),
            vertices: Vec::new(),
            triangles: Vec::new(),
            globe,
            parent_points: Vec::new(),
            curved_error_m: 0.0,
            splits: 0,
        };
        for (t, ph) in square_triangles(from.0, from.1, from.2) {
            match globe {
                None => m.descend(t, ph.map(|p| vertex_height(grid, p))),
                Some(_) => m.descend(t, ph.map(|p| OnGlobe::own(globe, p, vertex_height(grid, p)))),
            }
        }
        if m.vertices.len() > max_vertices {
            return Err(MeshError::TooDense { level: key.level, x: key.x, y: key.y, delta_m, limit: max_vertices });
        }
        let Mesher { vertices, triangles, parent_points, curved_error_m, .. } = m;
        // A triangle with a valid corner covers a valid sample; one with
        // none is scanned to see. The largest error is measured by scanning
        // in falling order of each triangle's stored bound (the error at
        // its split point, 0 where it has none: it covers its corners
        // alone) until no bound is above what was found.
        let mut kept = vec![true; triangles.len()];
        let mut max_error_m: f64 = 0.0;
        // Bounds in a heap (only the few largest are ever taken), as f32
        // bits, which order as the values do from +0 up, with NaN first.
        let order = |b: f32| {
            if b.is_nan() {
                u32::MAX
            } else if b > 0.0 {
                b.to_bits()
            } else {
                0
            }
        };
        let mut bounds: Vec<(u32, std::cmp::Reverse<usize>)> = Vec::with_capacity(triangles.len());
        for (k, t) in triangles.iter().enumerate() {
            let corners = t.map(|v| vertices[v as usize]);
            let at = |v: &MeshVertex| grid.heights[v.z as usize * grid.width + v.x as usize];
            if grid.has_nodata && corners.iter().all(|v| at(v).is_nan()) {
                let scan = scan_triangle(grid, &corners);
                kept[k] = scan.valid;
                max_error_m = max_error_m.max(scan.error);
                continue;
            }
            if let Some(m) = split_point(corners.map(|v| point(&v))) {
                bounds.push((order(self.error_at(m.0, m.1)), std::cmp::Reverse(k)));
            }
        }
        let mut bounds = std::collections::BinaryHeap::from(bounds);
        while let Some((bound, std::cmp::Reverse(k))) = bounds.pop() {
            if f64::from(f32::from_bits(bound)) <= max_error_m {
                break;
            }
            let corners = triangles[k].map(|v| vertices[v as usize]);
            max_error_m = max_error_m.max(scan_triangle(grid, &corners).error);
        }
        // The chunk is final only where its sag is inside the leaves' δ too.
        max_error_m = max_error_m.max(curved_error_m.min(delta_m));
        let n = triangles.len();
        Ok(ChunkMesh {
            key,
            footprint,
            delta_m,
            vertices,
            triangles,
            kept,
            max_error_m,
            max_error_near_cuts_m: 0.0,
            // Only cut points' targets read it, and the bintree has none.
            relief_m: 0.0,
            scans: vec![None; n],
            locator_index: std::sync::OnceLock::new(),
            parent_points,
        })
    }

    /// Whether the mesh at `delta` splits triangle `t` (whose box lies
    /// inside or straddles the grid).
    #[inline]
    fn splits(&self, t: &Tri, place: Place, delta: f64) -> Option<P> {
        let m = t.midpoint()?;
        (place == Place::Straddles || f64::from(self.error_at(m.0, m.1)) > delta).then_some(m)
    }

    fn place(&self, t: &Tri) -> Place {
        place(t, (self.width - 1) as u32, (self.height - 1) as u32)
    }
}

fn place(t: &Tri, xmax: u32, zmax: u32) -> Place {
    let (x0, x1, z0, z1) = t.bbox();
    if x0 >= xmax || z0 >= zmax {
        Place::Outside
    } else if x1 > xmax || z1 > zmax {
        Place::Straddles
    } else {
        Place::Inside
    }
}

/// The two triangles of the square of side `c` at (x0, z0), with their
/// corners in `[a, b, r]` order.
fn square_triangles(x0: u32, z0: u32, c: u32) -> [(Tri, [P; 3]); 2] {
    let (p00, p10, p01, p11) = ((x0, z0), (x0 + c, z0), (x0, z0 + c), (x0 + c, z0 + c));
    let tris = if ((x0 / c) + (z0 / c)).is_multiple_of(2) {
        [Tri { a: p00, b: p11, r: p01 }, Tri { a: p11, b: p00, r: p10 }]
    } else {
        [Tri { a: p10, b: p01, r: p00 }, Tri { a: p01, b: p10, r: p11 }]
    };
    tris.map(|t| (t, [t.a, t.b, t.r]))
}

/// The height a vertex at a sample takes: the sample, or the void fill
/// (NaN past the grid, where no written triangle has a corner).
#[inline]
fn vertex_height(grid: &Grid, (x, z): P) -> f64 {
    if x as usize >= grid.width || z as usize >= grid.height {
        return f64::NAN;
    }
    grid.vertex_height(z as usize, x as usize)
}

/// What a triangle's samples say against its plane.
struct Scan {
    /// Largest |plane − sample| over its valid samples, metres.
    error: f64,
    /// It covers at least one valid sample.
    valid: bool,
}

/// Scans every sample inside or on a triangle whose corners lie on samples;
/// rows in parallel for a large one.
fn scan_triangle(grid: &Grid, corners: &[MeshVertex; 3]) -> Scan {
    let [a, b, c] = corners;
    // Plane h = a.h + gx·(x − a.x) + gz·(z − a.z), from the two edges at a.
    let (ux, uz, uh) = (b.x - a.x, b.z - a.z, b.h - a.h);
    let (vx, vz, vh) = (c.x - a.x, c.z - a.z, c.h - a.h);
    let det = ux * vz - uz * vx;
    let gx = (uh * vz - uz * vh) / det;
    let gz = (ux * vh - uh * vx) / det;
    let z0 = a.z.min(b.z).min(c.z) as u32;
    let z1 = a.z.max(b.z).max(c.z) as u32;
    let edges = [(a, b), (b, c), (c, a)];
    let large = z1 - z0 >= 512;
    let row = |z: u32| -> (f64, bool) {
        if large && z.is_multiple_of(RELIEF_STEPS / 16) {
            grid.relieve();
        }
        let zf = f64::from(z);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (p, q) in edges {
            if (p.z - zf) * (q.z - zf) > 0.0 {
                continue;
            }
            if p.z == q.z {
                lo = lo.min(p.x.min(q.x));
                hi = hi.max(p.x.max(q.x));
            } else {
                // Edges run at 0°, 45° or 90°: the crossing is a whole column.
                let x = p.x + (zf - p.z) * (q.x - p.x) / (q.z - p.z);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
        let (mut err, mut valid) = (0.0f64, false);
        let base = z as usize * grid.width;
        let plane_row = a.h + gz * (zf - a.z);
        for x in lo as usize..=hi as usize {
            let s = grid.heights[base + x];
            if !s.is_nan() {
                valid = true;
                err = err.max((plane_row + gx * (x as f64 - a.x) - f64::from(s)).abs());
            }
        }
        (err, valid)
    };
    let join = |(e1, v1): (f64, bool), (e2, v2): (f64, bool)| (e1.max(e2), v1 || v2);
    let (error, valid) = if large {
        (z0..=z1).into_par_iter().map(row).reduce(|| (0.0, false), join)
    } else {
        (z0..=z1).map(row).fold((0.0, false), join)
    };
    Scan { error, valid }
}

/// Steps (splits, vertices, or rows of a scan) between looks at the memory
/// limit in a chunk at least [`RELIEF_SIDE`] cells wide: a coarse chunk of
/// a large grid touches pages all over its square (each fault maps the
/// pages around it too) faster than the limit's governor thread wakes.
pub(crate) const RELIEF_STEPS: u32 = 512;

/// The narrowest chunk, cells, whose passes look at the memory limit
/// themselves; a narrower one touches too few rows to outrun the governor.
pub(crate) const RELIEF_SIDE: u32 = 2048;

/// The bottom-up pass's state: the grid and the errors found so far.
struct Field<'g> {
    grid: &'g Grid<'g>,
    xmax: u32,
    zmax: u32,
    step: f64,
    /// The smallest δ of the build; every level's δ is it times a power of
    /// two, so only where an error lies between those matters ([`rung`]).
    ladder: f64,
    /// Scan every triangle (to test the bounds against).
    exact: bool,
    sag: Option<Sag>,
    /// f32 bits; each level writes only its own vertices and reads those of
    /// the level below, so relaxed loads and stores suffice.
    errors: &'g [AtomicU32],
}

impl Field<'_> {
    /// Fills the vertices of one level: the side midpoints of the squares
    /// of `c` (`square` false: triangles whose hypotenuse is a side) or
    /// their centres (`square` true: the halves of a square).
    fn level(&self, c: u32, square: bool) {
        let h = c / 2;
        // Rows holding this level's vertices: (z, first x, x step).
        let mut rows: Vec<(u32, u32)> = Vec::new();
        let mut z = if square { h } else { 0 };
        while z <= self.zmax {
            let first = if square || z.is_multiple_of(c) { h } else { 0 };
            rows.push((z, first));
            z += if square { c } else { h };
        }
        rows.par_iter().for_each(|&(z, first)| {
            let mut x = first;
            while x <= self.xmax {
                let e = self.vertex(c, square, (x, z));
                self.errors[z as usize * self.grid.width + x as usize].store(e.to_bits(), Ordering::Relaxed);
                x += c;
            }
        });
    }

    /// The error of vertex `m`: the largest over the (one or two) triangles
    /// split there that reach into the grid.
    fn vertex(&self, c: u32, square: bool, m: P) -> f32 {
        let mut e = 0.0f32;
        for t in split_at(c, square, m).into_iter().flatten() {
            match place(&t, self.xmax, self.zmax) {
                Place::Outside => {}
                Place::Straddles => return f32::INFINITY,
                Place::Inside => {
                    let corners = [t.a, t.b, t.r].map(|p| {
                        let h = vertex_height(self.grid, p);
                        MeshVertex { x: f64::from(p.0), z: f64::from(p.1), h, ph: h }
                    });
                    let rounding = corners.iter().map(|v| rounds_by(v.h, self.step)).fold(0.0, f64::max)
                        + self.sag.map_or(0.0, |s| s.of_triangle(&corners));
                    // Bounds on the scan: at least the sample at m is off the
                    // plane by `off`; at most that plus the children's own
                    // errors (on a child, the two planes differ by a linear
                    // function that is 0 at its other corners). Only the
                    // rung decides a split, so the scan is needed only when
                    // the bounds straddle one.
                    let off = ((corners[0].h + corners[1].h) / 2.0 - vertex_height(self.grid, m)).abs();
                    // (A relative 10⁻¹² each way covers how the scan's own
                    // arithmetic rounds.)
                    let lower = if self.grid.heights[m.1 as usize * self.grid.width + m.0 as usize].is_nan() {
                        0.0
                    } else {
                        off * (1.0 - 1e-12)
                    };
                    let mut below = 0.0f32;
                    for k in t.children(m) {
                        if let Some(km) = k.midpoint() {
                            let b =
                                self.errors[km.1 as usize * self.grid.width + km.0 as usize].load(Ordering::Relaxed);
                            below = below.max(f32::from_bits(b));
                        }
                    }
                    let upper = up_f32((f64::from(below) + off + rounding) * (1.0 + 1e-12));
                    let own = if !self.exact && rung(up_f32(lower + rounding), self.ladder) == rung(upper, self.ladder)
                    {
                        upper
                    } else {
                        up_f32(scan_triangle(self.grid, &corners).error + rounding)
                    };
                    e = e.max(own).max(below);
                }
            }
        }
        e
    }
}

/// The (one or two) triangles of the squares of `c` split at `m`: the
/// halves of the square centred there (`square`), or the two whose
/// hypotenuse is the side through it.
fn split_at(c: u32, square: bool, m: P) -> [Option<Tri>; 2] {
    let h = c / 2;
    if square {
        // The square of side c centred at m, cut by its diagonal.
        let (x0, z0) = (m.0 - h, m.1 - h);
        square_triangles(x0, z0, c).map(|(t, _)| Some(t))
    } else if m.1.is_multiple_of(c) {
        // A horizontal side: apexes at the centres above and below.
        let (p, q) = ((m.0 - h, m.1), (m.0 + h, m.1));
        [m.1.checked_sub(h).map(|zu| Tri { a: q, b: p, r: (m.0, zu) }), Some(Tri { a: p, b: q, r: (m.0, m.1 + h) })]
    } else {
        let (p, q) = ((m.0, m.1 - h), (m.0, m.1 + h));
        [m.0.checked_sub(h).map(|xl| Tri { a: p, b: q, r: (xl, m.1) }), Some(Tri { a: q, b: p, r: (m.0 + h, m.1) })]
    }
}

/// The samples where the pass's error is infinite on a grid of `wc` × `hc`
/// cells, up to squares of `top`: a triangle there reaches past the grid,
/// or one below it does. They depend on the grid's size alone and lie
/// along its last column and row, as many as its cell counts are odd:
/// with an odd count every triangle along that side splits down to one
/// cell, at every level.
fn forced_points(wc: u32, hc: u32, top: u32) -> std::collections::HashSet<P> {
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

/// Rungs [`Rtin::densest_over`] tells apart; higher ones count as the last
/// (a tree of more levels is not planned).
const RUNGS: usize = 48;

/// How many of the δs `ladder`·2^k (k = 0..64) `e` exceeds: two errors on
/// one rung split the same triangles at every level.
#[inline]
fn rung(e: f32, ladder: f64) -> u32 {
    let e = f64::from(e);
    if e <= ladder {
        return 0;
    }
    if e.is_infinite() {
        return 64;
    }
    // The smallest k with e ≤ ladder·2^k: ⌈log2(e / ladder)⌉ from the
    // quotient's exponent bits, then made exact against the products (the
    // quotient rounds; multiplying by a power of two does not).
    let r = (e / ladder).to_bits();
    let exponent = ((r >> 52) & 0x7ff) as i64 - 1023;
    let mut k = (exponent + i64::from(r & ((1 << 52) - 1) != 0)).clamp(1, 64) as u32;
    let step = |k: u32| ladder * f64::from_bits((1023 + u64::from(k)) << 52);
    while k > 1 && e <= step(k - 1) {
        k -= 1;
    }
    while k < 64 && e > step(k) {
        k += 1;
    }
    k
}

/// How far rounding `h` to a multiple of `step` moves it (0 without a step).
fn rounds_by(h: f64, step: f64) -> f64 {
    if step > 0.0 { (h - (h / step).round() * step).abs() } else { 0.0 }
}

/// The smallest f32 at or above `v`.
fn up_f32(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v { f.next_up() } else { f }
}

/// One chunk's descent through the bintree.
struct Mesher<'a> {
    rtin: &'a Rtin,
    grid: &'a Grid<'a>,
    /// The chunk's square: side and north-west corner.
    side: u32,
    square: P,
    delta_m: f64,
    /// The parent level's square side and δ (None at the top).
    parent: Option<(u32, f64)>,
    index: VertexIndex,
    vertices: Vec<MeshVertex>,
    triangles: Vec<[u32; 3]>,
    /// The curved frame and the grid spacing (metres), if it is written in it.
    globe: Option<(&'a Globe, [f64; 2])>,
    /// Per vertex, its parent-surface point (the curved frame only).
    parent_points: Vec<ParentPoint>,
    /// The largest error bound plus sag of a written triangle (the curved
    /// frame only).
    curved_error_m: f64,
    /// Triangles split so far: every few thousand the grid's memory limit
    /// is looked at ([`Grid::relieve`]).
    splits: u32,
}

/// What the descent carries to each corner: the parent surface there, as
/// a height (the flat frame) or also as a world point (the curved one).
trait ParentSurface: Copy {
    /// A vertex the parent has too: its own height `h` at `p`.
    fn own(globe: Option<(&Globe, [f64; 2])>, p: P, h: f64) -> Self;
    /// The middle of a parent edge: the parent's surface is linear along it.
    fn middle(a: Self, b: Self) -> Self;
    fn height(&self) -> f64;
    fn point(&self) -> Option<ParentPoint>;
}

impl ParentSurface for f64 {
    #[inline]
    fn own(_: Option<(&Globe, [f64; 2])>, _: P, h: f64) -> f64 {
        h
    }
    #[inline]
    fn middle(a: f64, b: f64) -> f64 {
        (a + b) / 2.0
    }
    #[inline]
    fn height(&self) -> f64 {
        *self
    }
    #[inline]
    fn point(&self) -> Option<ParentPoint> {
        None
    }
}

/// The parent surface in the curved frame: its chord triangles are linear
/// between their corners' world points, so the middle of an edge is the
/// middle of its ends' points.
#[derive(Clone, Copy)]
struct OnGlobe {
    h: f64,
    p: [f64; 3],
    /// A vertex of the parent (not the middle of its edge).
    shared: bool,
}

impl ParentSurface for OnGlobe {
    fn own(globe: Option<(&Globe, [f64; 2])>, p: P, h: f64) -> OnGlobe {
        let (g, _) = globe.expect("the curved frame carries its globe");
        OnGlobe { h, p: g.world(f64::from(p.0), f64::from(p.1), h), shared: true }
    }
    fn middle(a: OnGlobe, b: OnGlobe) -> OnGlobe {
        OnGlobe { h: (a.h + b.h) / 2.0, p: [0, 1, 2].map(|k| (a.p[k] + b.p[k]) / 2.0), shared: false }
    }
    fn height(&self) -> f64 {
        self.h
    }
    fn point(&self) -> Option<ParentPoint> {
        Some(ParentPoint { at: self.p, shared: self.shared })
    }
}

impl Mesher<'_> {
    /// `ph`: the parent surface at `t`'s corners a, b, r.
    fn descend<S: ParentSurface>(&mut self, t: Tri, ph: [S; 3]) {
        let (x0, x1, z0, z1) = t.bbox();
        let (sx, sz, c) = (self.square.0, self.square.1, self.side);
        // Only what reaches into the chunk's square.
        if x1 <= sx || x0 >= sx + c || z1 <= sz || z0 >= sz + c {
            return;
        }
        let place = self.rtin.place(&t);
        if place == Place::Outside {
            return;
        }
        let coarser = |side: u32| t.hyp2() > 2 * u64::from(side) * u64::from(side);
        let split = if coarser(c) { t.midpoint() } else { self.splits(&t, place, self.delta_m, c) };
        let Some(m) = split else {
            debug_assert_eq!(place, Place::Inside, "a triangle past the grid always splits");
            self.emit(t, ph);
            return;
        };
        // The parent's surface at m: m itself where the parent splits here
        // too, else the middle of the hypotenuse it lies on.
        let pm = match self.parent {
            None => S::own(self.globe, m, vertex_height(self.grid, m)),
            Some((ps, pd)) => {
                if coarser(ps) || self.splits(&t, place, pd, ps).is_some() {
                    S::own(self.globe, m, vertex_height(self.grid, m))
                } else {
                    S::middle(ph[0], ph[1])
                }
            }
        };
        self.splits += 1;
        if self.side >= RELIEF_SIDE && self.splits.is_multiple_of(RELIEF_STEPS) {
            self.grid.relieve();
        }
        let [k0, k1] = t.children(m);
        self.descend(k0, [ph[2], ph[0], pm]);
        self.descend(k1, [ph[1], ph[2], pm]);
    }

    /// Whether the mesh at `delta` (a level of squares of `side` cells)
    /// splits `t`. In the curved frame the field's errors hold each
    /// triangle's sag, and δ is lessened by what f32 rounds positions by in
    /// a chunk of that size: one threshold per level, so the meshes conform
    /// and nest as they do flat.
    #[inline]
    fn splits(&self, t: &Tri, place: Place, delta: f64, side: u32) -> Option<P> {
        self.rtin.splits(t, place, delta - self.rounding(side))
    }

    /// How far f32 may round chunk-local positions in a chunk of `side`
    /// cells, metres (0 in the flat frame, where samples are written exactly).
    #[inline]
    fn rounding(&self, side: u32) -> f64 {
        self.globe.map_or(0.0, |(_, s)| 4.0 * f64::from(f32::EPSILON) * f64::from(side) * s[0].max(s[1]))
    }

    fn emit<S: ParentSurface>(&mut self, t: Tri, ph: [S; 3]) {
        // In the curved frame a triangle's error bound holds its sag too,
        // which decides whether the chunk needs children.
        if let (Some(_), Some(m)) = (self.globe, t.midpoint()) {
            let bound = f64::from(self.rtin.error_at(m.0, m.1)) + self.rounding(self.side);
            self.curved_error_m = self.curved_error_m.max(bound);
        }
        let mut v = [(t.a, ph[0]), (t.b, ph[1]), (t.r, ph[2])].map(|(p, ph)| self.vertex(p, ph));
        // Counter-clockwise seen from above (y up), as the TIN's are stored:
        // clockwise in x-east, z-south grid space.
        let [a, b, c] = [t.a, t.b, t.r].map(|p| (i64::from(p.0), i64::from(p.1)));
        if (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0) > 0 {
            v.swap(1, 2);
        }
        self.triangles.push(v);
    }

    fn vertex<S: ParentSurface>(&mut self, p: P, ph: S) -> u32 {
        let local = (p.0 - self.square.0, p.1 - self.square.1);
        let next = self.vertices.len() as u32;
        let v = self.index.entry(local, next);
        if v == next {
            let h = vertex_height(self.grid, p);
            self.vertices.push(MeshVertex { x: f64::from(p.0), z: f64::from(p.1), h, ph: ph.height() });
            if let Some(point) = ph.point() {
                self.parent_points.push(point);
            }
        }
        v
    }
}

/// A chunk's vertex numbers by position within its square: a table for the
/// common small squares, a hash map for the few large ones.
enum VertexIndex {
    Table { row: usize, slots: Vec<u32> },
    Map(HashMap<P, u32, BuildHasherDefault<PointHasher>>),
}

impl VertexIndex {
    /// Squares up to this side get a table ((side + 1)² slots).
    const TABLE_SIDE: u32 = 256;

    fn over(side: u32) -> Self {
        if side <= Self::TABLE_SIDE {
            let row = side as usize + 1;
            VertexIndex::Table { row, slots: vec![u32::MAX; row * row] }
        } else {
            VertexIndex::Map(HashMap::default())
        }
    }

    /// The number of the vertex at `local` (offset from the square's
    /// corner), given `next` if it has none yet.
    #[inline]
    fn entry(&mut self, local: P, next: u32) -> u32 {
        match self {
            VertexIndex::Table { row, slots } => {
                let slot = &mut slots[local.1 as usize * *row + local.0 as usize];
                if *slot == u32::MAX {
                    *slot = next;
                }
                *slot
            }
            VertexIndex::Map(map) => *map.entry(local).or_insert(next),
        }
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::quadtree::ChunkTree;

    /// Every chunk of a grid's tree, parents before children.
    fn meshes(w: usize, h: usize, heights: &[f32], max_error_m: f64, leaf: u32) -> (ChunkTree, Vec<ChunkMesh>) {
        let grid = Grid::new(w, h, heights, None);
        let tree = plan(w, h, max_error_m, None, leaf, 0);
        let rtin = Rtin::new(&grid, &tree, None, None);
        let mut out = Vec::new();
        for l in 0..=tree.depth() {
            for y in 0..tree.zs[l as usize].len() as u32 {
                for x in 0..tree.xs[l as usize].len() as u32 {
                    let key = ChunkKey { level: l, x, y };
                    out.push(rtin.build_chunk(&grid, &tree, key, usize::MAX, None, None).unwrap());
                }
            }
        }
        (tree, out)
    }

    /// The surface of `mesh` at (x, z), by `pick` (h: its own, ph: its
    /// morph target), if a triangle covers the point.
    fn surface_at(mesh: &ChunkMesh, x: f64, z: f64, pick: fn(&MeshVertex) -> f64) -> Option<f64> {
        mesh.triangles.iter().find_map(|t| {
            let [a, b, c] = t.map(|v| mesh.vertices[v as usize]);
            let d = (b.x - a.x) * (c.z - a.z) - (b.z - a.z) * (c.x - a.x);
            let wb = ((x - a.x) * (c.z - a.z) - (z - a.z) * (c.x - a.x)) / d;
            let wc = ((b.x - a.x) * (z - a.z) - (b.z - a.z) * (x - a.x)) / d;
            let wa = 1.0 - wb - wc;
            (wa >= -1e-12 && wb >= -1e-12 && wc >= -1e-12).then(|| wa * pick(&a) + wb * pick(&b) + wc * pick(&c))
        })
    }

    /// The structure every chunk keeps: right-isosceles triangles,
    /// counter-clockwise seen from above, that tile its footprint exactly, every sample within δ.
    fn check(mesh: &ChunkMesh, w: usize, heights: &[f32]) {
        let ((x0, x1), (z0, z1)) = mesh.footprint;
        let mut area = 0.0;
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|v| mesh.vertices[v as usize]);
            let cross = (b.x - a.x) * (c.z - a.z) - (b.z - a.z) * (c.x - a.x);
            assert!(cross < 0.0, "{:?}: triangle {t:?} not counter-clockwise seen from above", mesh.key);
            area -= cross / 2.0;
            let mut l2 = [(a, b), (b, c), (c, a)].map(|(p, q)| (q.x - p.x).powi(2) + (q.z - p.z).powi(2));
            l2.sort_by(f64::total_cmp);
            assert!(l2[0] == l2[1] && l2[0] + l2[1] == l2[2], "{:?}: {t:?} not right-isosceles", mesh.key);
            for v in [a, b, c] {
                assert!((x0 as f64..=x1 as f64).contains(&v.x) && (z0 as f64..=z1 as f64).contains(&v.z));
            }
        }
        assert_eq!(area, f64::from((x1 - x0) * (z1 - z0)), "{:?}: the triangles do not tile the footprint", mesh.key);
        for z in z0..=z1 {
            for x in x0..=x1 {
                let s = f64::from(heights[z as usize * w + x as usize]);
                let on = surface_at(mesh, f64::from(x), f64::from(z), |v| v.h).expect("every sample is covered");
                assert!((on - s).abs() <= mesh.delta_m, "{:?}: sample ({x}, {z}) is {} off", mesh.key, (on - s).abs());
            }
        }
    }

    #[test]
    fn forced_points_are_where_the_pass_finds_infinite_errors() {
        for (w, h) in [(3, 3), (4, 4), (37, 21), (64, 33), (100, 100), (129, 65), (200, 7)] {
            let heights = vec![5.0f32; w * h];
            let grid = Grid::new(w, h, &heights, None);
            let tree = plan(w, h, 1.0, None, 2, 0);
            let rtin = Rtin::new(&grid, &tree, None, None);
            let top = square_side(&tree, 0);
            let forced = forced_points((w - 1) as u32, (h - 1) as u32, top);
            for z in 0..h as u32 {
                for x in 0..w as u32 {
                    assert_eq!(
                        rtin.error_at(x, z).is_infinite(),
                        forced.contains(&(x, z)),
                        "{w}×{h}: sample ({x}, {z})"
                    );
                }
            }
        }
    }

    #[test]
    fn a_grid_of_odd_cell_counts_gets_top_chunks_that_fit_their_vertex_limit() {
        // 999 cells each way: every triangle along the last column and row
        // splits down to one cell, so one top chunk over all of it would
        // carry both sides at full resolution even on flat ground.
        let (w, h) = (1000, 1000);
        let heights = vec![5.0f32; w * h];
        let grid = Grid::new(w, h, &heights, None);
        let limit = 2000;
        let whole = plan(w, h, 1.0, None, 64, 0);
        let rtin = Rtin::new(&grid, &whole, None, None);
        let root = rtin.build_chunk(&grid, &whole, ChunkKey { level: 0, x: 0, y: 0 }, usize::MAX, None, None);
        assert!(root.unwrap().vertices.len() > limit, "the grid needs narrower top chunks");
        let root_cells = fitting_root(w, h, None, limit).expect("narrower than the grid");
        assert!(root_cells < 1024);
        let tree = plan(w, h, 1.0, Some(root_cells), 64, 0);
        let rtin = Rtin::new(&grid, &tree, None, None);
        for y in 0..tree.zs[0].len() as u32 {
            for x in 0..tree.xs[0].len() as u32 {
                let key = ChunkKey { level: 0, x, y };
                let mesh = rtin.build_chunk(&grid, &tree, key, limit, None, None).unwrap();
                check(&mesh, w, &heights);
            }
        }
        // Even cell counts with a large power of two keep one top chunk.
        assert_eq!(fitting_root(1025, 1025, None, limit), None);
        assert_eq!(fitting_root(1025, 1025, Some(512), limit), Some(512));
    }

    #[test]
    fn flat_3x3_is_two_triangles_at_every_level() {
        let heights = [7.0f32; 9];
        let (_, meshes) = meshes(3, 3, &heights, 0.5, 2);
        for m in &meshes {
            check(m, 3, &heights);
            assert_eq!(m.triangles.len(), 2);
            assert_eq!(m.max_error_m, 0.0);
        }
    }

    #[test]
    fn a_spike_in_3x3_is_the_centre_vertex_of_four_triangles() {
        let mut heights = [0.0f32; 9];
        heights[4] = 10.0;
        let (tree, meshes) = meshes(3, 3, &heights, 1.0, 2);
        assert_eq!(tree.depth(), 0);
        let m = &meshes[0];
        check(m, 3, &heights);
        assert_eq!(m.triangles.len(), 4);
        assert!(m.vertices.iter().any(|v| (v.x, v.z, v.h) == (1.0, 1.0, 10.0)));
        assert_eq!(m.max_error_m, 0.0);
    }

    #[test]
    fn a_spike_under_a_large_delta_is_left_out_and_measured() {
        let mut heights = [0.0f32; 25];
        heights[2 * 5 + 1] = 3.0;
        let grid = Grid::new(5, 5, &heights, None);
        let tree = plan(5, 5, 4.0, None, 4, 0);
        let rtin = Rtin::new(&grid, &tree, None, None);
        let m = rtin.build_chunk(&grid, &tree, ChunkKey { level: 0, x: 0, y: 0 }, usize::MAX, None, None).unwrap();
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.max_error_m, 3.0);
        // The vertex it would take carries the true error (or a bound on
        // the same side of δ), not the midpoint's.
        assert_eq!(Rtin::with_scans(&grid, &tree, None, None, true, None).unwrap().error_at(2, 2), 3.0);
        assert!((3.0..=4.0).contains(&rtin.error_at(2, 2)), "{}", rtin.error_at(2, 2));
    }

    #[test]
    fn a_step_is_followed_down_to_its_cells_and_nests() {
        // A 2 m step between columns 2 and 3 of a 9 × 9 grid.
        let heights: Vec<f32> = (0..81).map(|k| if k % 9 >= 3 { 2.0 } else { 0.0 }).collect();
        let (tree, meshes) = meshes(9, 9, &heights, 0.5, 2);
        assert_eq!(tree.depth(), 2);
        for m in &meshes {
            check(m, 9, &heights);
        }
        let leaf_triangles: usize = meshes.iter().filter(|m| m.key.level == 2).map(|m| m.triangles.len()).sum();
        // Flat on both sides: the fine triangles stay along the step.
        assert!(leaf_triangles < 2 * 64, "{leaf_triangles}");
    }

    #[test]
    fn a_grid_of_no_power_of_two_is_tiled_to_its_edges() {
        let heights: Vec<f32> = (0..7 * 5).map(|k| ((k * 37) % 11) as f32).collect();
        let (_, meshes) = meshes(7, 5, &heights, 0.5, 2);
        for m in &meshes {
            check(m, 7, &heights);
        }
    }

    #[test]
    fn the_plan_squares_are_aligned_powers_of_two() {
        let t = plan(8401, 4801, 1.0, None, 250, 1);
        assert_eq!(t.xs[0], vec![(0, 8400)]);
        assert_eq!(t.xs[1], vec![(0, 8192), (8192, 8400)]);
        assert_eq!(t.zs[1], vec![(0, 4800)]);
        assert_eq!(square_side(&t, 1), 8192);
        assert_eq!(t.widest_cells(t.depth() - 1), [128, 128]);
        assert_eq!(t.xs[t.depth() as usize], t.xs[t.depth() as usize - 1], "a refine level keeps the leaves");
        let rooted = plan(8401, 4801, 1.0, Some(1000), 250, 0);
        assert_eq!(rooted.xs[0].len(), 17);
        assert_eq!(square_side(&rooted, 0), 512);
    }

    fn heights_strategy() -> impl Strategy<Value = (usize, usize, Vec<f32>, f64, u32)> {
        (2usize..=19, 2usize..=19, prop_oneof![Just(0.05), Just(1.0), Just(30.0)], 0.01f64..20.0, 2u32..=8)
            .prop_flat_map(|(w, h, amp, err, leaf)| {
                (Just(w), Just(h), proptest::collection::vec(0.0..1.0f64, w * h), Just(amp), Just(err), Just(leaf))
            })
            .prop_map(|(w, h, u, amp, err, leaf)| {
                // Whole multiples of amp/8: ties and exact-δ samples are common.
                let heights = u.iter().map(|v| ((v * 8.0).floor() * amp / 8.0) as f32).collect();
                (w, h, heights, err, leaf)
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Every chunk within its δ; shaped by its morph targets, a child is
        /// its parent's surface at every sample (and at every cell centre).
        #[test]
        fn error_stays_within_delta_and_a_morphed_child_is_its_parent((w, h, heights, err, leaf) in heights_strategy()) {
            let (tree, meshes) = meshes(w, h, &heights, err, leaf);
            for m in &meshes {
                check(m, w, &heights);
                prop_assert!(m.max_error_m <= m.delta_m);
                let Some(pk) = tree.parent(m.key) else { continue };
                let parent = meshes.iter().find(|p| p.key == pk).unwrap();
                let ((x0, x1), (z0, z1)) = m.footprint;
                for z2 in 2 * z0..=2 * z1 {
                    for x2 in 2 * x0..=2 * x1 {
                        let (x, z) = (f64::from(x2) / 2.0, f64::from(z2) / 2.0);
                        let morphed = surface_at(m, x, z, |v| v.ph).unwrap();
                        let there = surface_at(parent, x, z, |v| v.h).unwrap();
                        prop_assert!((morphed - there).abs() <= 1e-9 * (1.0 + there.abs()),
                            "{:?} at ({}, {}): {} against the parent's {}", m.key, x, z, morphed, there);
                    }
                }
            }
        }

        /// The count from the field alone bounds every chunk's vertices, and
        /// some chunk of each level has at least as many.
        #[test]
        fn counted_vertices_bound_every_chunk((w, h, heights, err, leaf) in heights_strategy()) {
            let grid = Grid::new(w, h, &heights, None);
            let tree = plan(w, h, err, None, leaf, 0);
            let rtin = Rtin::new(&grid, &tree, None, None);
            for level in 0..=tree.depth() {
                let counted = rtin.densest_squares(&[square_side(&tree, level)])[0][(tree.depth() - level) as usize];
                let l = level as usize;
                let most = (0..tree.zs[l].len() as u32)
                    .flat_map(|y| (0..tree.xs[l].len() as u32).map(move |x| ChunkKey { level, x, y }))
                    .map(|key| rtin.build_chunk(&grid, &tree, key, usize::MAX, None, None).unwrap().vertices.len())
                    .max()
                    .unwrap();
                prop_assert!(most <= counted + 4 && most >= counted, "level {}: {} vertices, counted {}", level, most, counted);
                prop_assert_eq!(rtin.densest_over(&tree, counted + 4).is_none_or(|l| l != level), true);
            }
        }

        /// A rung is how many of the δs a value exceeds, counted one by one.
        #[test]
        fn rung_counts_the_deltas_exceeded(bits in any::<u32>(), ladder in prop_oneof![Just(1.0), Just(0.001), Just(0.37), 1e-3..1e3f64]) {
            let e = f32::from_bits(bits).abs();
            prop_assume!(!e.is_nan());
            let counted = (0..64).filter(|&k| f64::from(e) > ladder * 2f64.powi(k)).count() as u32;
            prop_assert_eq!(rung(e, ladder), counted, "{} over {}", e, ladder);
            for k in 0..40 {
                let at = ladder * 2f64.powi(k);
                let f = at as f32;
                let counted = (0..64).filter(|&j| f64::from(f) > ladder * 2f64.powi(j)).count() as u32;
                prop_assert_eq!(rung(f, ladder), counted, "{} over {}", f, ladder);
            }
        }

        /// The pass that scans only where its bounds straddle a δ splits
        /// exactly where the pass that scans every triangle does, at every
        /// δ of the ladder, with and without quantized heights.
        #[test]
        fn bounded_errors_split_where_true_errors_do((w, h, heights, err, leaf) in heights_strategy(), step in prop_oneof![Just(None), Just(Some(0.01)), Just(Some(0.37))]) {
            let grid = Grid::new(w, h, &heights, None);
            let tree = plan(w, h, err, None, leaf, 0);
            let (bounded, exact) = (Rtin::with_scans(&grid, &tree, step, None, false, None).unwrap(), Rtin::with_scans(&grid, &tree, step, None, true, None).unwrap());
            for (k, (b, e)) in bounded.errors.iter().zip(&exact.errors).enumerate() {
                prop_assert!(b >= e, "sample {}: bound {} below the true {}", k, b, e);
                prop_assert_eq!(rung(*b, err), rung(*e, err), "sample {}: {} against {}", k, b, e);
            }
        }
    }
}
