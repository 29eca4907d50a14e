use proptest::prelude::*;

use super::field::*;
use super::plan::*;
use super::tri::{P, split_at};

use crate::mesh::grid::Grid;
use crate::mesh::{ChunkMesh, MeshVertex};
use crate::quadtree::{ChunkKey, ChunkTree};

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
                assert_eq!(rtin.error_at(x, z).is_infinite(), forced.contains(&(x, z)), "{w}×{h}: sample ({x}, {z})");
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

/// A bintree triangle's sag from its level's shape is the sag worked out
/// from its own corners (smallest enclosing circle, planar slope).
#[test]
fn sag_from_the_level_shape_is_the_sag_of_the_triangle() {
    let sag = Sag { curvature: [1.6e-7, 3.1e-8], spacing: [74.2, 92.6] };
    let direct = |c: &[MeshVertex; 3]| {
        let p = c.map(|v| [v.x * 74.2, v.z * 92.6, v.h]);
        let d = |a: usize, b: usize| [0, 1, 2].map(|k| p[b][k] - p[a][k]);
        let (u, v, w) = (d(0, 1), d(0, 2), d(1, 2));
        let l2 = |e: [f64; 3]| e[0] * e[0] + e[1] * e[1];
        let (a2, b2, c2) = (l2(u), l2(v), l2(w));
        let longest = a2.max(b2).max(c2);
        // Circumradius from the sides: R = abc / (4 · area).
        let area = (u[0] * v[1] - u[1] * v[0]).abs() / 2.0;
        let r2 = if 2.0 * longest >= a2 + b2 + c2 { longest / 4.0 } else { a2 * b2 * c2 / (16.0 * area * area) };
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let slope = (n[0] * n[0] + n[1] * n[1]).sqrt() / n[2].abs();
        crate::geodesy::Globe::margin_m(sag.curvature, r2, slope)
    };
    let mut checked = 0;
    for c in [2u32, 4, 16, 64] {
        let h = c / 2;
        for square in [false, true] {
            let first = |m: P| sag.shape(&split_at(c, square, m).into_iter().flatten().next().unwrap());
            let shapes = if square { [first((h, h)); 2] } else { [first((h, 0)), first((0, h))] };
            let places = if square {
                [(h, h), (3 * h, h), (5 * h, 5 * h), (3 * h, 7 * h)]
            } else {
                [(h, 2 * c), (3 * h, c), (2 * c, 3 * h), (4 * c, 5 * h)]
            };
            for m in places {
                let shape = shapes[shape_of(c, square, m)];
                for t in split_at(c, square, m).into_iter().flatten() {
                    let corners = [t.a, t.b, t.r].map(|p| {
                        let h = f64::from(p.0 * 7 % 13) * 11.5 - f64::from(p.1 % 5) * 40.0;
                        MeshVertex { x: f64::from(p.0), z: f64::from(p.1), h, ph: h }
                    });
                    let (got, want) = (sag.of_triangle(&shape, &corners), direct(&corners));
                    assert!((got - want).abs() <= 1e-12 * want, "c {c}, {m:?}, square {square}: {got} against {want}");
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 40);
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

    /// The densest closed square of every side at once, from cell counts,
    /// is the densest found by counting every square's samples one by one.
    #[test]
    fn densest_squares_count_every_closed_square((w, h, heights, err, leaf) in heights_strategy()) {
        let grid = Grid::new(w, h, &heights, None);
        let tree = plan(w, h, err, None, leaf, 0);
        let rtin = Rtin::new(&grid, &tree, None, None);
        let (wc, hc) = ((w - 1) as u32, (h - 1) as u32);
        let sides: Vec<u32> = (0..5).map(|k| 1u32 << k).filter(|&s| s <= 2 * wc.max(hc).max(1)).collect();
        let counted = rtin.densest_squares(&sides);
        for (s, counted) in sides.iter().zip(&counted) {
            let mut most = vec![0usize; RUNGS];
            for j in 0..hc.div_ceil(*s).max(1) {
                for i in 0..wc.div_ceil(*s).max(1) {
                    let mut above = vec![0usize; RUNGS];
                    for z in j * s..=((j + 1) * s).min(hc) {
                        for x in i * s..=((i + 1) * s).min(wc) {
                            let k = (rung(rtin.error_at(x, z), err) as usize).min(RUNGS - 1);
                            for (kk, a) in above.iter_mut().enumerate() {
                                *a += usize::from(k > kk);
                            }
                        }
                    }
                    for (m, a) in most.iter_mut().zip(&above) {
                        *m = (*m).max(*a);
                    }
                }
            }
            prop_assert_eq!(&most, counted, "side {}", s);
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
