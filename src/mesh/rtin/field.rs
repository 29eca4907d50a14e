//! The bottom-up pass: every vertex's largest true error, scanned from
//! the samples each bintree triangle covers, and the curved frame's sag.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::plan::square_side;
use super::tri::{P, Place, Tri, place, split_at};
use crate::geodesy::Globe;
use crate::mesh::MeshVertex;
use crate::mesh::grid::{Grid, RELIEF_STEPS};
use crate::quadtree::ChunkTree;
use crate::store::{self, Big, Memory};

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

    /// The shape of the bintree triangles congruent to `t`: every triangle
    /// of one level and orientation has the same enclosing circle and plan
    /// area in metres, so they are worked out once per level.
    pub(super) fn shape(&self, t: &Tri) -> SagShape {
        let s = self.spacing;
        let p = [t.a, t.b, t.r].map(|q| [f64::from(q.0) * s[0], f64::from(q.1) * s[1]]);
        let d = |a: usize, b: usize| [p[b][0] - p[a][0], p[b][1] - p[a][1]];
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
        SagShape { r2, inv_plan2: 1.0 / (u[0] * v[1] - u[1] * v[0]).abs() }
    }

    /// The sag bound of the triangle with these corners (grid units, with
    /// their heights) and this `shape`: [`Globe::margin_m`] for its
    /// smallest enclosing circle and its planar slope.
    pub(super) fn of_triangle(&self, shape: &SagShape, c: &[MeshVertex; 3]) -> f64 {
        let s = self.spacing;
        let p = c.map(|v| [v.x * s[0], v.z * s[1], v.h]);
        let d = |a: usize, b: usize| [p[b][0] - p[a][0], p[b][1] - p[a][1], p[b][2] - p[a][2]];
        let (u, v) = (d(0, 1), d(0, 2));
        // The normal's horizontal part over its vertical one (twice the plan area).
        let (n0, n1) = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2]);
        let slope = (n0 * n0 + n1 * n1).sqrt() * shape.inv_plan2;
        let slope = if slope.is_finite() { slope } else { 0.0 };
        Globe::margin_m(self.curvature, shape.r2, slope)
    }
}

/// What [`Sag::of_triangle`] needs of a bintree triangle's shape.
#[derive(Clone, Copy, Debug)]
pub(super) struct SagShape {
    /// The squared radius of its smallest enclosing circle, m².
    r2: f64,
    /// 1 / (twice its plan area), 1/m².
    inv_plan2: f64,
}

/// The error field: what every chunk of one build is cut from, for any
/// tree it [`serves`](Rtin::serves).
pub struct Rtin {
    width: usize,
    height: usize,
    /// Per sample (row-major): the largest true error of the triangles split
    /// there and of everything below them, in metres, rounded up to f32 (or
    /// a bound on the same rung).
    pub(super) errors: Big<f32>,
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
    pub(super) fn with_scans(
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
}

impl Rtin {
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

    /// Per side in `sides` (powers of two) and per rung k, the most samples
    /// any closed square of that side (aligned to it) holds above rung k.
    /// One pass over the field, bands of rows in parallel, counts per cell
    /// of the smallest side: samples in the half-open cell, on its west
    /// line, on its north line and at its north-west corner. A closed
    /// square of any side is then a block of cells plus the west lines of
    /// the column past it, the north lines of the row below it and one
    /// corner: each sample is counted once, not once per side.
    pub(super) fn densest_squares(&self, sides: &[u32]) -> Vec<Vec<usize>> {
        const CELL: usize = 0;
        const WEST: usize = 1;
        const NORTH: usize = 2;
        const CORNER: usize = 3;
        let (wc, hc) = ((self.width - 1) as u32, (self.height - 1) as u32);
        let Some(&s0) = sides.iter().min() else { return Vec::new() };
        debug_assert!(sides.iter().all(|s| s.is_power_of_two()));
        let shift0 = s0.trailing_zeros();
        let (nx0, nz0) = ((wc >> shift0) as usize + 1, (hc >> shift0) as usize + 1);
        let band_len = 4 * nx0 * RUNGS;
        let mut counts = vec![0u32; nz0 * band_len];
        counts.par_chunks_mut(band_len).enumerate().for_each(|(jb, band)| {
            let first = (jb as u32) << shift0;
            for z in first..=(first + (s0 - 1)).min(hc) {
                let row = &self.errors[z as usize * self.width..][..self.width];
                for (x, &e) in row.iter().enumerate() {
                    if f64::from(e) <= self.ladder {
                        continue;
                    }
                    let k = (rung(e, self.ladder) as usize).min(RUNGS - 1);
                    let x = x as u32;
                    let at = |kind: usize| (kind * nx0 + (x >> shift0) as usize) * RUNGS + k;
                    let west = x & (s0 - 1) == 0;
                    band[at(CELL)] += 1;
                    if west {
                        band[at(WEST)] += 1;
                    }
                    if z == first {
                        band[at(NORTH)] += 1;
                        if west {
                            band[at(CORNER)] += 1;
                        }
                    }
                }
            }
        });
        let add = |sq: &mut [u32; RUNGS], kind: usize, ib: usize, jb: usize| {
            if ib < nx0 && jb < nz0 {
                let from = jb * band_len + (kind * nx0 + ib) * RUNGS;
                for (a, &c) in sq.iter_mut().zip(&counts[from..from + RUNGS]) {
                    *a += c;
                }
            }
        };
        sides
            .iter()
            .map(|&s| {
                let m = (s >> shift0) as usize;
                let (nx, nz) = (wc.div_ceil(s).max(1) as usize, hc.div_ceil(s).max(1) as usize);
                let mut most = vec![0usize; RUNGS];
                for j in 0..nz {
                    for i in 0..nx {
                        let mut sq = [0u32; RUNGS];
                        let (cols, rows) = (i * m..(i + 1) * m, j * m..(j + 1) * m);
                        for jb in rows.clone() {
                            for ib in cols.clone() {
                                add(&mut sq, CELL, ib, jb);
                            }
                            add(&mut sq, WEST, (i + 1) * m, jb);
                        }
                        for ib in cols {
                            add(&mut sq, NORTH, ib, (j + 1) * m);
                        }
                        add(&mut sq, CORNER, (i + 1) * m, (j + 1) * m);
                        let mut above = 0usize;
                        for k in (0..RUNGS).rev() {
                            most[k] = most[k].max(above);
                            above += sq[k] as usize;
                        }
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

    /// Whether the mesh at `delta` splits triangle `t` (whose box lies
    /// inside or straddles the grid).
    #[inline]
    pub(super) fn splits(&self, t: &Tri, place: Place, delta: f64) -> Option<P> {
        let m = t.midpoint()?;
        (place == Place::Straddles || f64::from(self.error_at(m.0, m.1)) > delta).then_some(m)
    }

    pub(super) fn place(&self, t: &Tri) -> Place {
        place(t, (self.width - 1) as u32, (self.height - 1) as u32)
    }
}

/// The height a vertex at a sample takes: the sample, or the void fill
/// (NaN past the grid, where no written triangle has a corner).
#[inline]
pub(super) fn vertex_height(grid: &Grid, (x, z): P) -> f64 {
    if x as usize >= grid.width || z as usize >= grid.height {
        return f64::NAN;
    }
    grid.vertex_height(z as usize, x as usize)
}

/// What a triangle's samples say against its plane.
pub(super) struct Scan {
    /// Largest |plane − sample| over its valid samples, metres.
    pub(super) error: f64,
    /// It covers at least one valid sample.
    pub(super) valid: bool,
}

/// Scans every sample inside or on a triangle whose corners lie on samples;
/// rows in parallel for a large one.
pub(super) fn scan_triangle(grid: &Grid, corners: &[MeshVertex; 3]) -> Scan {
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

/// The bottom-up pass's state: the grid and the errors found so far.
pub(super) struct Field<'g> {
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
        // The shapes of this level's triangles: the halves of a square, or
        // those on a horizontal and on a vertical side ([`shape_of`]).
        let shapes = self.sag.map(|s| {
            let first = |m: P| split_at(c, square, m).into_iter().flatten().next().expect("a triangle splits there");
            if square { [s.shape(&first((h, h))); 2] } else { [s.shape(&first((h, 0))), s.shape(&first((0, h)))] }
        });
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
                let e = self.vertex(c, square, (x, z), shapes.as_ref());
                self.errors[z as usize * self.grid.width + x as usize].store(e.to_bits(), Ordering::Relaxed);
                x += c;
            }
        });
    }

    /// The error of vertex `m`: the largest over the (one or two) triangles
    /// split there that reach into the grid.
    fn vertex(&self, c: u32, square: bool, m: P, shapes: Option<&[SagShape; 2]>) -> f32 {
        let mut e = 0.0f32;
        let shape = shapes.map(|s| s[shape_of(c, square, m)]);
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
                        + self.sag.zip(shape).map_or(0.0, |(s, shape)| s.of_triangle(&shape, &corners));
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

/// Which of a level's two triangle shapes those split at `m` have: 0 for
/// the halves of a square and those on a horizontal side, 1 on a vertical
/// one.
pub(super) fn shape_of(c: u32, square: bool, m: P) -> usize {
    usize::from(!square && !m.1.is_multiple_of(c))
}

/// Rungs [`Rtin::densest_over`] tells apart; higher ones count as the last
/// (a tree of more levels is not planned).
pub(super) const RUNGS: usize = 48;

/// How many of the δs `ladder`·2^k (k = 0..64) `e` exceeds: two errors on
/// one rung split the same triangles at every level.
#[inline]
pub(super) fn rung(e: f32, ladder: f64) -> u32 {
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
