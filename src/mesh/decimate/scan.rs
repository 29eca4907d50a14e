//! Step 4's queue of triangles by their worst sample, the scans that fill
//! it, and the finished mesh's own measure (`finish`).

use super::*;

#[derive(Clone, Copy)]
pub(super) struct Candidate {
    pub(super) err: f64,
    pub(super) t: u32,
    pub(super) i: u32,
    pub(super) j: u32,
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    fn cmp(&self, o: &Self) -> Ordering {
        // Largest error first; ties broken by position so the order is total.
        self.err.total_cmp(&o.err).then((o.i, o.j).cmp(&(self.i, self.j)))
    }
}

/// What the last scan of a triangle found.
#[derive(Clone, Copy)]
pub(super) struct Scan {
    /// The triangle's version when scanned.
    pub(super) version: u32,
    /// What it found.
    pub(super) found: TriangleScan,
}

/// What scanning one triangle found, kept with a finished mesh
/// ([`ChunkMesh::scans`]) so that a child starting from that triangle need
/// not scan it again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleScan {
    /// Largest error over its valid samples that are not vertices.
    pub(super) max_err: f64,
    /// What it covers (None: zero area).
    pub(super) coverage: Option<Coverage>,
    /// Its worst sample step 4 may insert, whatever the target: (error, row,
    /// column).
    pub(super) worst: Option<(f64, u32, u32)>,
}

/// Step 4's queue: each triangle's worst sample beyond the target.
pub(super) struct Queue<'g> {
    pub(super) grid: &'g Window<'g>,
    pub(super) clip: (Span, Span),
    pub(super) target: Targets,
    pub(super) heap: TriHeap,
    pub(super) scans: Vec<Scan>,
}

/// A max-heap of candidates holding at most one per triangle, which a rescan
/// replaces in place: no stale entries to pop, and a heap only as large as
/// the number of triangles still beyond the target.
#[derive(Default)]
pub(super) struct TriHeap {
    pub(super) heap: Vec<Candidate>,
    /// Per triangle: its entry's index in `heap`, or `u32::MAX`.
    pub(super) pos: Vec<u32>,
}

impl TriHeap {
    /// Makes `c` triangle `t`'s entry (`None`: no entry).
    pub(super) fn set(&mut self, t: u32, c: Option<Candidate>) {
        if self.pos.len() <= t as usize {
            self.pos.resize(t as usize + 1, u32::MAX);
        }
        match (self.pos[t as usize], c) {
            (u32::MAX, None) => {}
            (u32::MAX, Some(c)) => {
                self.heap.push(c);
                self.pos[t as usize] = (self.heap.len() - 1) as u32;
                self.up(self.heap.len() - 1);
            }
            (k, Some(c)) => {
                self.heap[k as usize] = c;
                let k = self.up(k as usize);
                self.down(k);
            }
            (k, None) => self.remove(k as usize),
        }
    }

    /// Takes the largest candidate.
    pub(super) fn pop(&mut self) -> Option<Candidate> {
        let top = *self.heap.first()?;
        self.remove(0);
        Some(top)
    }

    pub(super) fn remove(&mut self, k: usize) {
        let t = self.heap[k].t;
        let last = self.heap.pop().expect("entry exists");
        self.pos[t as usize] = u32::MAX;
        if k < self.heap.len() {
            self.heap[k] = last;
            self.pos[last.t as usize] = k as u32;
            let k = self.up(k);
            self.down(k);
        }
    }

    // Both sifts move a hole rather than swapping: each entry passed over
    // is written once, and the moving one only where it comes to rest (the
    // same arrangement as swapping, with half the writes).
    pub(super) fn up(&mut self, mut k: usize) -> usize {
        let c = self.heap[k];
        while k > 0 {
            let p = (k - 1) / 2;
            if c <= self.heap[p] {
                break;
            }
            self.place(k, self.heap[p]);
            k = p;
        }
        self.place(k, c);
        k
    }

    pub(super) fn down(&mut self, mut k: usize) {
        let c = self.heap[k];
        let n = self.heap.len();
        loop {
            let (l, r) = (2 * k + 1, 2 * k + 2);
            if l >= n {
                break;
            }
            let m = if r < n && self.heap[r] > self.heap[l] { r } else { l };
            if self.heap[m] <= c {
                break;
            }
            self.place(k, self.heap[m]);
            k = m;
        }
        self.place(k, c);
    }

    #[inline]
    pub(super) fn place(&mut self, k: usize, c: Candidate) {
        self.pos[c.t as usize] = k as u32;
        self.heap[k] = c;
    }
}

impl Queue<'_> {
    /// Scans triangle `t`, records what it found, and queues its worst
    /// sample that step 4 may insert, if that is beyond the target.
    pub(super) fn push(&mut self, tin: &Tin, lines: &Lines, t: u32) {
        let tri = tin.corners(t);
        let found = scan_for_queue(self.grid, self.clip, lines, &tri);
        let target = self.target.over(&tri);
        self.record(t, tin.version(t), found, target);
    }

    /// Records what triangle `t` (as it is now) holds, and queues its worst
    /// sample if that is beyond the target.
    pub(super) fn record(&mut self, t: u32, version: u32, found: TriangleScan, target: f64) {
        if self.scans.len() <= t as usize {
            let none = TriangleScan { max_err: 0.0, coverage: None, worst: None };
            self.scans.resize(t as usize + 1, Scan { version: u32::MAX, found: none });
        }
        self.scans[t as usize] = Scan { version, found };
        let c = found.worst.filter(|w| w.0 > target).map(|(err, i, j)| Candidate { err, t, i, j });
        self.heap.set(t, c);
    }
}

/// Scans triangle `tri` for step 4's queue: its largest error over samples
/// that are not vertices, and its worst sample step 4 may insert.
pub(super) fn scan_for_queue(grid: &Window, clip: (Span, Span), lines: &Lines, tri: &[V; 3]) -> TriangleScan {
    scan_within(grid, clip, lines, tri, f64::INFINITY).expect("nothing is beyond an infinite limit")
}

/// [`scan_for_queue`], or `None` as soon as a sample that is not a vertex
/// lies more than `limit` off. Every such sample is visited: while the
/// worst is within `limit`, the floor (the worst's error) is too.
pub(super) fn scan_within(
    grid: &Window,
    clip: (Span, Span),
    lines: &Lines,
    tri: &[V; 3],
    limit: f64,
) -> Option<TriangleScan> {
    let mut worst: Option<(f64, u32, u32)> = None;
    let mut max_err = 0.0;
    let mut beyond = false;
    let coverage = scan_triangle(grid, clip, tri, |i, j, err| {
        if err > max_err && !lines.is_vertex(i, j) {
            if err > limit {
                beyond = true;
                return f64::INFINITY;
            }
            max_err = err;
        }
        if worst.is_none_or(|w| err > w.0) && !lines.row_is_line(i) && !lines.col_is_line(j) && !lines.is_vertex(i, j) {
            worst = Some((err, i, j));
        }
        // A sample no further off than the worst so far (and so than
        // `max_err`, never below it) changes neither.
        worst.map_or(f64::NEG_INFINITY, |w| w.0)
    });
    (!beyond).then_some(TriangleScan { max_err, coverage, worst })
}

/// Calls `visit(i, j, |h − plane|)` for every valid sample in the closed
/// triangle `tri` (clipped to `clip`) that can matter; returns whether any
/// valid sample was what it covers, or `None` for a zero-area triangle
/// (which is not scanned).
///
/// `visit` returns a floor: a sample no further off than it cannot change
/// what `visit` finds, and is not visited (`NEG_INFINITY`: every valid
/// sample counts; `INFINITY`: stop, the answer is known). Once the worst is
/// known, most samples cost one comparison, and a nodata sample (NaN) fails
/// it too.
pub(super) fn scan_triangle(
    grid: &Window,
    clip: (Span, Span),
    tri: &[V; 3],
    mut visit: impl FnMut(u32, u32, f64) -> f64,
) -> Option<Coverage> {
    let [a, b, c] = tri.map(|v| (v.x, v.z, v.h));
    let det = (b.0 - a.0) * (c.1 - a.1) - (c.0 - a.0) * (b.1 - a.1);
    if det.abs() < 1e-12 {
        return None;
    }
    // h(x, z) = a.h + gx·(x − a.x) + gz·(z − a.z)
    let gx = ((b.2 - a.2) * (c.1 - a.1) - (c.2 - a.2) * (b.1 - a.1)) / det;
    let gz = ((b.0 - a.0) * (c.2 - a.2) - (c.0 - a.0) * (b.2 - a.2)) / det;
    const EPS: f64 = 1e-7;
    let zmin = a.1.min(b.1).min(c.1).max(f64::from(clip.1.0));
    let zmax = a.1.max(b.1).max(c.1).min(f64::from(clip.1.1));
    let first = ceil(zmin - EPS);
    let last = floor_i64(zmax + EPS);
    let mut any = false;
    let mut seen = false;
    let mut floor = f64::NEG_INFINITY;
    // Corners by row: p on top, r at the bottom; the long edge p–r spans
    // every row, the short edges p–q and q–r one part each.
    let mut v = [a, b, c];
    v.sort_unstable_by(|u, w| u.1.total_cmp(&w.1));
    let [p, q, r] = v;
    let long = (r.0 - p.0) / (r.1 - p.1);
    let upper = if q.1 > p.1 { (q.0 - p.0) / (q.1 - p.1) } else { 0.0 };
    let lower = if r.1 > q.1 { (r.0 - q.0) / (r.1 - q.1) } else { 0.0 };
    for i in first..=last {
        let z = i as f64;
        let zc = z.max(p.1).min(r.1);
        let x_long = p.0 + (zc - p.1) * long;
        let x_short = if zc < q.1 { p.0 + (zc - p.1) * upper } else { q.0 + (zc - q.1) * lower };
        let (xl, xr) = if x_long <= x_short { (x_long, x_short) } else { (x_short, x_long) };
        let j0 = ceil(xl - EPS).max(i64::from(clip.0.0));
        let j1 = floor_i64(xr + EPS).min(i64::from(clip.0.1));
        let row = grid.row(i as usize);
        // Relative to corner a: far from the grid's origin on steep ground,
        // gx·j and gx·a.x would each be large and their difference rounded.
        let base = a.2 + gz * (z - a.1);
        if j0 > j1 {
            continue;
        }
        seen = true;
        let samples = &row[j0 as usize - grid.x0..=j1 as usize - grid.x0];
        let mut k = 0;
        // A valid sample is visited at least until the floor is finite, so
        // `any` is set by then.
        while let Some((d, err)) = first_over(&samples[k..], (j0 + k as i64) as f64, a.0, base, gx, floor) {
            k += d;
            any = true;
            floor = visit(i as u32, (j0 + k as i64) as u32, err);
            if floor == f64::INFINITY {
                return Some(Coverage::Valid);
            }
            k += 1;
        }
    }
    Some(match (seen, any) {
        (_, true) => Coverage::Valid,
        (true, false) => Coverage::NodataOnly,
        (false, _) => Coverage::NoSample,
    })
}

/// The first of a row's `samples` more than `floor` off the plane
/// `base + gx·(x − ax)`, the first at column `x`, and its error: the scan's
/// inner loop, kept apart from what `visit` keeps so that its few values
/// stay in registers. The column counts up by one as an f64, exactly (a
/// whole number far below 2⁵³): each error is the one `j as f64` gives.
#[inline]
pub(super) fn first_over(samples: &[f32], x: f64, ax: f64, base: f64, gx: f64, floor: f64) -> Option<(usize, f64)> {
    let mut x = x;
    for (k, &h) in samples.iter().enumerate() {
        let err = (f64::from(h) - (base + gx * (x - ax))).abs();
        if err > floor {
            return Some((k, err));
        }
        x += 1.0;
    }
    None
}

/// `x.ceil() as i64` without the libm call (x86-64 before SSE4.1 has no
/// rounding instruction); grid coordinates are far inside i64.
#[inline]
pub(super) fn ceil(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t + 1 } else { t }
}

/// `x.floor() as i64`, as [`ceil`].
#[inline]
pub(super) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

/// What samples a triangle covers.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Coverage {
    /// At least one valid sample.
    Valid,
    /// Samples, all nodata.
    NodataOnly,
    /// No sample at all (a small triangle between samples).
    NoSample,
}

/// Whether any corner of the grid cell under the triangle's centroid holds data.
pub(super) fn cell_has_data(grid: &Window, tri: &[V; 3]) -> bool {
    let cx = (tri[0].x + tri[1].x + tri[2].x) / 3.0;
    let cz = (tri[0].z + tri[1].z + tri[2].z) / 3.0;
    let (x1, z1) = grid.last();
    let j = (cx.floor().max(grid.x0 as f64) as usize).min(x1 - 1);
    let i = (cz.floor().max(grid.z0 as f64) as usize).min(z1 - 1);
    [(i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)].iter().any(|&(i, j)| !grid.sample(i, j).is_nan())
}

pub(super) fn finish(
    grid: &Window,
    spec: &ChunkSpec,
    tin: &Tin,
    lines: &Lines,
    scans: &[Scan],
    (relief_m, magnitude_m): (f64, f64),
) -> ChunkMesh {
    // Vertices step 5 collapsed away are left out, the rest keep their order.
    let mut id = Vec::with_capacity(tin.pts.len());
    let mut vertices = Vec::with_capacity(tin.pts.len());
    for (k, v) in tin.pts.iter().enumerate() {
        id.push(vertices.len() as u32);
        if tin.is_live(k as u32) {
            vertices.push(MeshVertex { x: v.x, z: v.z, h: v.h, ph: v.ph });
        }
    }
    let n = tin.num_triangles();
    let mut triangles = Vec::with_capacity(n);
    let mut kept = Vec::with_capacity(n);
    let mut max_err: f64 = 0.0;
    let mut max_err_cut: f64 = 0.0;
    let mut parent_locator = None;
    let lattice = spec.lattice();
    let mut seeds = Vec::with_capacity(n);
    for t in (0..n as u32).filter(|&t| !tin.is_dead(t)) {
        let tri = tin.corners(t);
        // A triangle's last scan still holds unless a corner is a cut point:
        // then a sample within rounding outside it may since have become a
        // vertex (of the neighbour), which is exact and must not count. Only
        // a scan that holds is handed to the children.
        let cut = is_cut(&tri);
        let rounds = tri.iter().any(|v| off_lattice(v.x, lattice) || off_lattice(v.z, lattice));
        // Where a corner's height rounds, a sample's error as written is
        // bounded by its own share of the corners' rounding (the barycentric
        // mean: a sample on a line weighs only that line's ends, which its
        // 1-D target left room for), so such a triangle is scanned again.
        // Errors as the file will draw them, within which every target left
        // room: the corners as they move, interpolated like heights.
        let r = tri.map(|v| rounds_by(v.h, spec.height_step.unwrap_or(0.0)));
        let rounded = r.iter().any(|&r| r > 0.0);
        let [ra, rb, rc] = [0, 1, 2].map(|k| MeshVertex { x: tri[k].x, z: tri[k].z, h: r[k], ph: 0.0 });
        let moved = |i: u32, j: u32| {
            barycentric(&ra, &rb, &rc, f64::from(j), f64::from(i)).1.clamp(0.0, r[0].max(r[1]).max(r[2]))
        };
        let valid = scans.get(t as usize).filter(|s| s.version == tin.version(t) && !cut);
        seeds.push(valid.map(|s| s.found));
        let any = match valid {
            Some(s) if !rounded => {
                max_err = max_err.max(s.found.max_err);
                s.found.coverage
            }
            _ => {
                // A sample on a border or dividing line was decided in 1-D
                // against its interval's own target: δ where both ends are
                // samples, so it may be exactly δ off even in a triangle
                // with a cut corner (it lies on the exact edge, where that
                // corner weighs nothing). It counts in the lattice class,
                // whose δ reading is snapped. Where an end of its interval
                // is a cut point the file rounds, it counts with the cut
                // points: France–Italy at 0.5 m, 16-cell leaves, f32: a
                // chunk at δ 1 m ended the tree with a line sample 0.5 m off
                // beside a cut point, 0.5000005 m as written.
                let (row, col) = (|i: u32, v: &V| v.z == f64::from(i), |j: u32, v: &V| v.x == f64::from(j));
                let rounds_at = |v: &V| off_lattice(v.x, lattice) || off_lattice(v.z, lattice);
                scan_triangle(grid, spec.footprint, &tri, |i, j, e| {
                    if !lines.is_vertex(i, j) {
                        let (on_row, on_col) = (lines.row_is_line(i), lines.col_is_line(j));
                        let cut_end = tri.iter().any(|v| rounds_at(v) && (on_row && row(i, v) || on_col && col(j, v)));
                        let near_cut = rounds && (!(on_row || on_col) || cut_end);
                        let class = if near_cut { &mut max_err_cut } else { &mut max_err };
                        *class = class.max(if rounded { e + moved(i, j) } else { e });
                    }
                    f64::NEG_INFINITY // every sample counts
                })
            }
        };
        // Counter-clockwise with z taken as up is clockwise in x-east,
        // z-south grid space: store them reversed.
        let [a, b, c] = tin.triangle(t).map(|v| id[v as usize]);
        triangles.push([a, c, b]);
        // A zero-area sliver, or a small triangle with no sample inside,
        // covers nothing by itself: keep it unless its cell is all nodata.
        kept.push(match any {
            Some(Coverage::Valid) => true,
            Some(Coverage::NodataOnly) => false,
            // Over voids, a child must not draw where its parent does not
            // (it would pop in and out with the level): such a triangle lies
            // inside one parent triangle, and is written if that one is.
            _ => match (spec.parent, grid.grid.filled.is_some()) {
                (Some(p), true) => {
                    let loc = parent_locator.get_or_insert_with(|| p.locator());
                    let (cx, cz) = ((tri[0].x + tri[1].x + tri[2].x) / 3.0, (tri[0].z + tri[1].z + tri[2].z) / 3.0);
                    loc.locate(cx, cz, 1e-6).is_some_and(|(pt, _)| p.kept[pt as usize])
                }
                _ => cell_has_data(grid, &tri),
            },
        });
    }
    ChunkMesh {
        key: spec.key,
        footprint: spec.footprint,
        delta_m: spec.delta_m,
        vertices,
        triangles,
        kept,
        // A sample exactly δ off may read a hair over δ from the triangle on
        // the other side of its edge: it is δ.
        max_error_m: if max_err > spec.delta_m && max_err <= spec.delta_m + f64_slack(relief_m, magnitude_m) {
            spec.delta_m
        } else {
            max_err
        }
        .max(max_err_cut),
        max_error_near_cuts_m: max_err_cut,
        relief_m,
        scans: seeds,
        locator_index: Default::default(),
        parent_points: Vec::new(),
    }
}
