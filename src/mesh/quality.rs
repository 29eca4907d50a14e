//! Triangle shape in plan (DESIGN.md, promise 8): slivers stay a rare
//! exception, so that shading, rasterisation, compression and f32 rounding
//! are all safe.
//!
//! A triangle's *aspect* is its longest edge divided by the height on that
//! edge, measured in plan (x east, z south, metres): 2/√3 ≈ 1.15 for an
//! equilateral triangle, 2 for the right-isosceles halves of a grid cell,
//! infinite for one with no area. A *sliver* has aspect over
//! [`SLIVER_ASPECT`]; a level meets the promise where at most
//! [`SLIVER_SHARE`] of its triangles are slivers. One function measures
//! every mesh, whoever made it: `verify` (from the files), `bench` (the
//! leaves, and the peers' meshes) and the mesher's tests.

use serde::Serialize;

/// Aspect past which a triangle is a sliver.
pub const SLIVER_ASPECT: f64 = 100.0;

/// Aspect past which a sliver is a needle: none should exist unless the
/// DEM's own samples force it.
pub const NEEDLE_ASPECT: f64 = 1000.0;

/// Largest share of a level's triangles that may be slivers (0.1 %).
pub const SLIVER_SHARE: f64 = 0.001;

/// The shape of one triangle in plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    /// Longest edge ÷ the height on it (≥ 2/√3; infinite without area).
    pub aspect: f64,
    /// Smallest interior angle, degrees (0 without area).
    pub min_angle_deg: f64,
}

/// The shape of the triangle with these plan corners (x, z in metres; any
/// unit shared by both axes gives the same result).
pub fn shape(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> Shape {
    let coord = |p: [f64; 2]| robust::Coord { x: p[0], y: p[1] };
    // Twice the area; exact sign and zero from the robust predicate, so a
    // triangle with no area is never given a finite aspect by rounding.
    let twice_area = robust::orient2d(coord(a), coord(b), coord(c)).abs();
    let sq = |p: [f64; 2], q: [f64; 2]| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
    let longest = sq(a, b).max(sq(b, c)).max(sq(c, a));
    if twice_area == 0.0 || longest == 0.0 {
        return Shape { aspect: f64::INFINITY, min_angle_deg: 0.0 };
    }
    // height = 2A / L, so L / height = L² / 2A.
    let aspect = longest / twice_area;
    let angle = |o: [f64; 2], p: [f64; 2], q: [f64; 2]| {
        let (u, v) = ([p[0] - o[0], p[1] - o[1]], [q[0] - o[0], q[1] - o[1]]);
        let cross = (u[0] * v[1] - u[1] * v[0]).abs();
        let dot = u[0] * v[0] + u[1] * v[1];
        cross.atan2(dot).to_degrees()
    };
    let min_angle_deg = angle(a, b, c).min(angle(b, c, a)).min(angle(c, a, b));
    Shape { aspect, min_angle_deg }
}

/// Shapes of a set of triangles (a chunk, a level, a whole mesh).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ShapeSummary {
    /// Triangles measured.
    pub triangles: usize,
    /// Those with aspect over [`SLIVER_ASPECT`].
    pub slivers: usize,
    /// Those with aspect over [`NEEDLE_ASPECT`].
    pub needles: usize,
    /// Smallest angle of any triangle, degrees (60 when there are none).
    pub min_angle_deg: f64,
    /// Largest aspect of any triangle (0 when there are none; infinite,
    /// written as `null` in JSON, once one has no area).
    pub max_aspect: f64,
}

impl Default for ShapeSummary {
    fn default() -> Self {
        ShapeSummary { triangles: 0, slivers: 0, needles: 0, min_angle_deg: 60.0, max_aspect: 0.0 }
    }
}

impl ShapeSummary {
    /// Counts one more triangle.
    pub fn add(&mut self, s: Shape) {
        self.triangles += 1;
        self.slivers += usize::from(s.aspect > SLIVER_ASPECT);
        self.needles += usize::from(s.aspect > NEEDLE_ASPECT);
        self.min_angle_deg = self.min_angle_deg.min(s.min_angle_deg);
        self.max_aspect = self.max_aspect.max(s.aspect);
    }

    /// Both sets together.
    pub fn merge(self, o: ShapeSummary) -> ShapeSummary {
        ShapeSummary {
            triangles: self.triangles + o.triangles,
            slivers: self.slivers + o.slivers,
            needles: self.needles + o.needles,
            min_angle_deg: self.min_angle_deg.min(o.min_angle_deg),
            max_aspect: self.max_aspect.max(o.max_aspect),
        }
    }

    /// Slivers as a share of the triangles (0 for none).
    pub fn sliver_share(&self) -> f64 {
        if self.triangles == 0 { 0.0 } else { self.slivers as f64 / self.triangles as f64 }
    }

    /// Whether these triangles keep promise 8: at most [`SLIVER_SHARE`] of
    /// them slivers (so a level of under 1 000 triangles holds none).
    pub fn meets_promise(&self) -> bool {
        self.slivers as f64 <= SLIVER_SHARE * self.triangles as f64
    }
}

/// The shapes of `triangles` over `plan`, each vertex's (x, z) in metres.
pub fn summarize(plan: &[[f64; 2]], triangles: &[[u32; 3]]) -> ShapeSummary {
    let mut s = ShapeSummary::default();
    for t in triangles {
        let [a, b, c] = t.map(|v| plan[v as usize]);
        s.add(shape(a, b, c));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_equilateral_triangle_and_a_grid_cell_half() {
        let h = 3f64.sqrt() / 2.0;
        let s = shape([0.0, 0.0], [1.0, 0.0], [0.5, h]);
        assert!((s.aspect - 2.0 / 3f64.sqrt()).abs() < 1e-12);
        assert!((s.min_angle_deg - 60.0).abs() < 1e-9);
        let s = shape([0.0, 0.0], [1.0, 0.0], [1.0, 1.0]);
        assert!((s.aspect - 2.0).abs() < 1e-12);
        assert!((s.min_angle_deg - 45.0).abs() < 1e-9);
    }

    #[test]
    fn aspect_is_the_longest_edge_over_its_height_whatever_the_winding() {
        // A 200 m edge with its apex 1 m off it.
        let (a, b, c) = ([0.0, 0.0], [200.0, 0.0], [50.0, 1.0]);
        assert!((shape(a, b, c).aspect - 200.0).abs() < 1e-9);
        assert_eq!(shape(a, b, c), shape(a, c, b));
        // Unequal spacing: measured in metres, not in cells.
        let (x, z) = (0.5, 2.0);
        let s = shape([0.0, 0.0], [100.0 * x, 0.0], [0.0, z]);
        assert!((s.aspect - (2500.0 + 4.0) / 100.0).abs() < 1e-9);
    }

    #[test]
    fn a_triangle_without_area_is_the_worst_shape() {
        let s = shape([0.0, 0.0], [1.0, 1.0], [3.0, 3.0]);
        assert_eq!(s, Shape { aspect: f64::INFINITY, min_angle_deg: 0.0 });
        let s = shape([2.0, 2.0], [2.0, 2.0], [5.0, 1.0]);
        assert!(s.aspect.is_infinite());
        let mut sum = ShapeSummary::default();
        sum.add(shape([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]));
        sum.add(s);
        sum.add(shape([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]));
        assert_eq!((sum.slivers, sum.needles, sum.max_aspect, sum.min_angle_deg), (1, 1, f64::INFINITY, 0.0));
    }

    #[test]
    fn the_promise_allows_one_sliver_per_thousand_triangles() {
        let good = shape([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]);
        let sliver = shape([0.0, 0.0], [500.0, 0.0], [250.0, 1.0]);
        assert!(sliver.aspect > SLIVER_ASPECT && sliver.aspect < NEEDLE_ASPECT);
        let mut level = ShapeSummary::default();
        (0..999).for_each(|_| level.add(good));
        level.add(sliver);
        assert!(level.meets_promise());
        assert_eq!((level.slivers, level.needles), (1, 0));
        assert!((level.max_aspect - 500.0).abs() < 1e-9);
        let mut small = ShapeSummary::default();
        (0..10).for_each(|_| small.add(good));
        small.add(sliver);
        assert!(!small.meets_promise());
        let merged = level.merge(small);
        assert_eq!((merged.triangles, merged.slivers), (1011, 2));
        assert!(!merged.meets_promise());
        assert!((merged.sliver_share() - 2.0 / 1011.0).abs() < 1e-15);
    }

    #[test]
    fn summarize_reads_the_plan_positions_of_each_triangle() {
        let plan = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [5.0, 0.01]];
        let s = summarize(&plan, &[[0, 1, 2], [0, 2, 3], [0, 4, 1]]);
        assert_eq!((s.triangles, s.slivers, s.needles), (3, 1, 0));
        assert!((s.max_aspect - 1000.0).abs() < 1e-6);
        assert_eq!(ShapeSummary::default().merge(ShapeSummary::default()), ShapeSummary::default());
    }
}
