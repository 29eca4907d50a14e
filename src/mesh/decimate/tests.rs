use super::*;
use crate::mesh::tin::Broken;

/// Rough ground: two ridges and a hashed roughness of a few metres.
fn rough(w: usize, h: usize) -> Vec<f32> {
    (0..w * h)
        .map(|k| {
            let (x, z) = ((k % w) as f64, (k / w) as f64);
            let hash = ((k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as f64 / f64::from(1u32 << 24);
            (40.0 * (x / 9.0).sin() * (z / 13.0).cos() + 0.3 * x + 3.0 * hash) as f32
        })
        .collect()
}

/// [`build_chunk`], with the finished TIN held to [`Tin::sanity_check`]
/// and its border to the footprint, whatever the build's profile: every
/// mesh these tests make is checked.
fn meshed(grid: &Grid, spec: &ChunkSpec) -> Result<ChunkMesh, MeshError> {
    build_checked(grid, spec, Thinning::ByParts, true)
}

/// Panics with the first broken invariant of the TIN over `soup`.
#[track_caller]
fn assert_soup_sound(soup: &Soup) {
    let tin = Tin::from_soup(soup.pts.clone(), &soup.tris, &soup.fixed);
    if let Err(broken) = tin.sanity_check() {
        panic!("{broken}");
    }
}

/// Each triangle as its corners' coordinates, sorted: a mesh's
/// triangles whatever their numbering.
fn triangle_set(m: &ChunkMesh) -> Vec<[[u64; 3]; 3]> {
    let mut set: Vec<[[u64; 3]; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let mut c = t.map(|v| {
                let p = m.vertices[v as usize];
                [p.x.to_bits(), p.z.to_bits(), p.h.to_bits()]
            });
            c.sort_unstable();
            c
        })
        .collect();
    set.sort_unstable();
    set
}

#[test]
fn parts_filled_in_parallel_make_the_same_mesh_as_one_tin() {
    let (w, h) = (129, 97);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let spec = |key, footprint, delta_m, parent, split| ChunkSpec {
        key,
        footprint,
        delta_m,
        parent,
        keep_parent_edges: true,
        max_vertices: crate::config::MAX_CHUNK_VERTICES as usize,
        dividing_lines: DividingLines::Children,
        split_insertion: split,
        cancel: None,
        cut_share: CUT_SHARE,
        cut_lattice: None,
        height_step: None,
        thin: false,
    };
    let root = ChunkKey { level: 0, x: 0, y: 0 };
    let whole = ((0, 128), (0, 96));
    let [one, parts] = [false, true].map(|split| meshed(&grid, &spec(root, whole, 2.0, None, split)).unwrap());
    assert!(one.triangles.len() > 1000, "{} triangles", one.triangles.len());
    assert_eq!(triangle_set(&one), triangle_set(&parts));
    assert_eq!(one.vertices.len(), parts.vertices.len());
    assert_eq!(one.max_error_m, parts.max_error_m);
    // The scans each hands down stand for the same triangles: a child of
    // either is the same mesh, and so is a child filled in parts.
    let child = ChunkKey { level: 1, x: 1, y: 0 };
    let quarter = ((64, 128), (0, 48));
    let a = meshed(&grid, &spec(child, quarter, 1.0, Some(&one), false)).unwrap();
    let b = meshed(&grid, &spec(child, quarter, 1.0, Some(&parts), false)).unwrap();
    let c = meshed(&grid, &spec(child, quarter, 1.0, Some(&parts), true)).unwrap();
    assert_eq!(triangle_set(&a), triangle_set(&b));
    assert_eq!(triangle_set(&a), triangle_set(&c));
    let held = |m: &ChunkMesh| m.scans.iter().filter(|s| s.is_some()).count();
    assert_eq!(held(&one), held(&parts));
    // The vertex limit counts the parts together.
    let limit = one.vertices.len() - 1;
    for split in [false, true] {
        let tight = ChunkSpec { max_vertices: limit, ..spec(root, whole, 2.0, None, split) };
        assert!(matches!(meshed(&grid, &tight), Err(MeshError::TooDense { .. })), "split {split}");
        let exact = ChunkSpec { max_vertices: limit + 1, ..spec(root, whole, 2.0, None, split) };
        assert!(meshed(&grid, &exact).is_ok(), "split {split}");
    }
}

/// A chunk with dividing lines, nested in `parent` if given, thinned or not.
fn lined<'p>(
    key: ChunkKey,
    footprint: (Span, Span),
    delta_m: f64,
    parent: Option<&'p ChunkMesh>,
    thin: bool,
) -> ChunkSpec<'p> {
    ChunkSpec {
        key,
        parent,
        dividing_lines: DividingLines::Children,
        thin,
        ..ChunkSpec::unconstrained(footprint, delta_m)
    }
}

/// A chunk filled by parts and thinned (`--thin all`'s root) is thinned
/// part by part, on the threads: it must make the collapses that
/// thinning the joined TIN on one thread made, so the files stay the same.
#[test]
fn parts_thinned_in_parallel_make_the_collapses_of_the_joined_tin() {
    // Rough ground with a void, so that thinning also skips stars that
    // touch nodata; the root filled by parts and thinned, as `--thin
    // all` builds it, then a child of it filled and thinned by parts.
    let (w, h) = (129, 97);
    let mut heights = rough(w, h);
    for i in 60..75 {
        for j in 20..41 {
            heights[i * w + j] = f32::NAN;
        }
    }
    let hf = crate::heightfield::Heightfield::ungeoreferenced(w, h, heights.clone(), "rough".into());
    let filled = crate::heightfield::void_fill(&hf).expect("a void");
    let grid = Grid::new(w, h, &heights, Some(&filled));
    let spec = |key, footprint, delta_m, parent, thin| ChunkSpec {
        split_insertion: true,
        ..lined(key, footprint, delta_m, parent, thin)
    };
    let root = ChunkKey { level: 0, x: 0, y: 0 };
    let whole = ((0, 128), (0, 96));
    let plain = meshed(&grid, &spec(root, whole, 2.0, None, false)).unwrap();
    let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
        .map(|how| build_checked(&grid, &spec(root, whole, 2.0, None, true), how, true).unwrap());
    let (n0, n1) = (plain.vertices.len(), by_parts.vertices.len());
    assert!(n1 * 100 < n0 * 97, "{n1} vertices thinned against {n0}");
    same_mesh(&joined, &by_parts);
    let child = ChunkKey { level: 1, x: 0, y: 1 };
    let quarter = ((0, 64), (48, 96));
    let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
        .map(|how| build_checked(&grid, &spec(child, quarter, 1.0, Some(&by_parts), true), how, true).unwrap());
    same_mesh(&joined, &by_parts);
    assert!(by_parts.kept.iter().any(|&k| !k), "the child covers part of the void");
}

/// The same mesh, vertex for vertex and triangle for triangle, so the
/// same bytes: `a` thinned joined, `b` by parts.
fn same_mesh(a: &ChunkMesh, b: &ChunkMesh) {
    let (na, nb) = ((a.vertices.len(), a.triangles.len()), (b.vertices.len(), b.triangles.len()));
    assert!(a.vertices == b.vertices, "vertices differ: joined {na:?}, by parts {nb:?} (vertices, triangles)");
    assert!(a.triangles == b.triangles, "triangles differ: joined {na:?}, by parts {nb:?}");
    assert!(a.kept == b.kept && a.scans == b.scans, "what is written or handed down differs");
    assert_eq!(a.max_error_m.to_bits(), b.max_error_m.to_bits());
}

/// A lone leaf cut into parts only to fill them in parallel
/// ([`DividingLines::Parts`]) starts from the samples where its lines
/// meet the borders and each other: unlike the children's lines, which
/// cut the corners' diagonal at a point off the sample grid where a
/// span is odd, it holds no vertex but samples. Filled and thinned by
/// parts it is the mesh of filling and thinning it whole, within δ, and
/// its lines cost the free leaf few triangles.
#[test]
fn a_lone_leaf_cut_into_parts_holds_only_samples_and_meets_delta() {
    // 127 cells across: the vertical line at 63 meets the diagonal off the grid.
    let (w, h) = (128, 97);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let whole = ((0, 127), (0, 96));
    let spec = |lines, split| ChunkSpec {
        dividing_lines: lines,
        split_insertion: split,
        thin: true,
        ..ChunkSpec::unconstrained(whole, 2.0)
    };
    let on_samples = |m: &ChunkMesh| m.vertices.iter().all(|v| v.x.fract() == 0.0 && v.z.fract() == 0.0);
    let children = meshed(&grid, &spec(DividingLines::Children, false)).unwrap();
    assert!(!on_samples(&children), "the children's lines make a cut point here");
    let free = meshed(&grid, &spec(DividingLines::None, false)).unwrap();
    let [joined, by_parts] = [Thinning::Joined, Thinning::ByParts]
        .map(|how| build_checked(&grid, &spec(DividingLines::Parts, true), how, true).unwrap());
    same_mesh(&joined, &by_parts);
    assert!(on_samples(&by_parts), "a vertex off the sample grid");
    assert!(by_parts.max_error_m <= 2.0, "{} m", by_parts.max_error_m);
    for (x, z) in [(63.0, 48.0), (0.0, 48.0), (127.0, 48.0), (63.0, 0.0), (63.0, 96.0)] {
        assert!(by_parts.vertices.iter().any(|v| (v.x, v.z) == (x, z)), "({x}, {z}) is where lines meet");
    }
    let count = |m: &ChunkMesh| m.kept.iter().filter(|&&k| k).count();
    let (n, n0) = (count(&by_parts), count(&free));
    assert!(n0 > 2000 && n * 100 <= n0 * 105, "{n} triangles by parts against {n0} free");
}

/// Step 5 takes out vertices step 4 no longer needs, and only those: the
/// thinned TIN keeps every sample within δ (measured afresh over its
/// triangles, not from the mesher's scans), keeps every border and
/// dividing-line vertex, holds no vertex without a triangle, and a child
/// meshed from a thinned parent still refines it (each child triangle
/// inside one parent triangle, each morph target on the parent surface).
#[test]
fn thinning_takes_out_vertices_and_keeps_every_sample_within_delta() {
    let (w, h) = (129, 97);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let root = ChunkKey { level: 0, x: 0, y: 0 };
    let whole = ((0, 128), (0, 96));
    let spec = lined;
    let [plain, thinned] = [false, true].map(|thin| meshed(&grid, &spec(root, whole, 2.0, None, thin)).unwrap());
    let (n0, n1) = (plain.vertices.len(), thinned.vertices.len());
    assert!(n1 * 100 < n0 * 97, "{n1} vertices thinned against {n0}");
    assert!(thinned.max_error_m <= 2.0, "{}", thinned.max_error_m);
    let within = |m: &ChunkMesh, delta: f64| {
        let loc = m.locator();
        for i in 0..h {
            for j in 0..w {
                let (_, s) = loc.locate(j as f64, i as f64, 1e-9).expect("every sample covered");
                let e = (s - f64::from(heights[i * w + j])).abs();
                assert!(e <= delta + 1e-9, "sample ({i}, {j}) {e} m off, δ {delta}");
            }
        }
    };
    within(&thinned, 2.0);
    let mut used = vec![false; n1];
    thinned.triangles.iter().flatten().for_each(|&v| used[v as usize] = true);
    assert!(used.iter().all(|&u| u), "a vertex without a triangle");
    let lines = |m: &ChunkMesh| {
        let on = |v: &MeshVertex| [0.0, 64.0, 128.0].contains(&v.x) || [0.0, 48.0, 96.0].contains(&v.z);
        let mut p: Vec<(u64, u64)> =
            m.vertices.iter().filter(|v| on(v)).map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
        p.sort_unstable();
        p
    };
    assert_eq!(lines(&plain), lines(&thinned));

    // The scans a thinned mesh keeps, from which its max error is read
    // and its children start, are what scanning its triangles finds:
    // thinning records the scans it made while trying each collapse
    // instead of scanning the new triangles again.
    let corner: std::collections::HashSet<(u64, u64)> =
        thinned.vertices.iter().map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
    let mut kept_scans = 0;
    for (t, scan) in thinned.triangles.iter().zip(&thinned.scans) {
        let Some(scan) = scan else { continue };
        let [p, q, r] = t.map(|k| thinned.vertices[k as usize]);
        let mut worst: f64 = 0.0;
        for i in p.z.min(q.z).min(r.z) as usize..=p.z.max(q.z).max(r.z) as usize {
            for j in p.x.min(q.x).min(r.x) as usize..=p.x.max(q.x).max(r.x) as usize {
                let (x, z) = (j as f64, i as f64);
                let (outside, plane) = barycentric(&p, &q, &r, x, z);
                if outside <= 1e-9 && !corner.contains(&(x.to_bits(), z.to_bits())) {
                    worst = worst.max((f64::from(heights[i * w + j]) - plane).abs());
                }
            }
        }
        assert!((worst - scan.max_err).abs() < 1e-9, "kept scan {} against {worst} by brute force", scan.max_err);
        kept_scans += 1;
    }
    assert!(kept_scans * 10 > thinned.triangles.len() * 9, "{kept_scans} of {}", thinned.triangles.len());

    let child = ChunkKey { level: 1, x: 1, y: 0 };
    let quarter = ((64, 128), (0, 48));
    let c = meshed(
        &grid,
        &ChunkSpec { dividing_lines: DividingLines::None, ..spec(child, quarter, 1.0, Some(&thinned), true) },
    )
    .unwrap();
    assert!(c.max_error_m <= 1.0, "{}", c.max_error_m);
    let parent = thinned.locator();
    for v in &c.vertices {
        let (_, ph) = parent.locate(v.x, v.z, 1e-9).unwrap();
        assert!((ph - v.ph).abs() < 1e-9, "morph target {} against the parent's {ph}", v.ph);
    }
    for t in &c.triangles {
        let [a, b, d] = t.map(|k| c.vertices[k as usize]);
        let (cx, cz) = ((a.x + b.x + d.x) / 3.0, (a.z + b.z + d.z) / 3.0);
        let (pt, _) = parent.locate(cx, cz, 1e-9).unwrap();
        let [p, q, r] = thinned.triangles[pt as usize].map(|k| thinned.vertices[k as usize]);
        for v in [a, b, d] {
            let (outside, _) = barycentric(&p, &q, &r, v.x, v.z);
            assert!(outside < 1e-9, "a child triangle crosses a parent edge");
        }
    }
}

/// The leaf-width estimate measures each δ by continuing its windows'
/// TINs from twice that δ (`quadtree::estimate::Estimate`). A continued TIN is the
/// free TIN at its δ but for the order its points went in: within δ,
/// every point it started from kept, its borders exactly a fresh TIN's
/// (each interval split at its worst sample whatever the δ), and about
/// as many vertices. It fails if the start's edges stay fixed (0.73 to
/// 1.45 times the vertices here).
#[test]
fn a_continued_tin_is_within_delta_with_a_fresh_tins_borders() {
    let (w, h) = (129, 97);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let whole = ((0, 128), (0, 96));
    let on_border = |v: &MeshVertex| v.x == 0.0 || v.x == 128.0 || v.z == 0.0 || v.z == 96.0;
    let points = |m: &ChunkMesh, border: bool| {
        let mut p: Vec<(u64, u64)> =
            m.vertices.iter().filter(|v| !border || on_border(v)).map(|v| (v.x.to_bits(), v.z.to_bits())).collect();
        p.sort_unstable();
        p
    };
    let mut chain = meshed(&grid, &ChunkSpec::unconstrained(whole, 8.0)).unwrap();
    for delta in [4.0, 2.0, 1.0, 0.5] {
        let next = meshed(&grid, &ChunkSpec::continued(whole, delta, &chain)).unwrap();
        let fresh = meshed(&grid, &ChunkSpec::unconstrained(whole, delta)).unwrap();
        assert!(next.max_error_m <= delta, "{} over δ {delta}", next.max_error_m);
        let kept = points(&next, false);
        assert!(points(&chain, false).iter().all(|p| kept.binary_search(p).is_ok()), "δ {delta}");
        assert_eq!(points(&next, true), points(&fresh, true), "δ {delta}");
        let ratio = next.vertices.len() as f64 / fresh.vertices.len() as f64;
        // The order moves the count by up to 5 % here (kept edges: 0.73–1.45×).
        assert!((0.95..=1.06).contains(&ratio), "δ {delta}: {} against {}", next.vertices.len(), fresh.vertices.len());
        chain = next;
    }
    assert!(chain.vertices.len() > 2000, "{} vertices", chain.vertices.len());
}

/// A mesh's locator (the children's void checks use their parent's) is
/// indexed once and then lent: the same grid on every call, and the
/// same answers as a locator indexed afresh.
#[test]
fn a_meshs_locator_is_indexed_once_and_answers_as_a_fresh_one() {
    let (w, h) = (65, 49);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let mesh = meshed(&grid, &ChunkSpec::unconstrained(((0, 64), (0, 48)), 2.0)).unwrap();
    assert!(mesh.locator_index.get().is_none(), "indexed before it was asked for");
    let (first, second) = (mesh.locator(), mesh.locator());
    assert!(mesh.locator_index.get().is_some(), "not indexed when first asked for");
    let fresh = crate::mesh::locate::SurfaceLocator::from_parts(&mesh.vertices, &mesh.triangles);
    let mut found = 0;
    for k in 0..2000 {
        let (x, z) = (f64::from(k % 97) * 0.661, f64::from(k / 97) * 2.31 + 0.1);
        let want = fresh.locate(x, z, 1e-6);
        assert_eq!(first.locate(x, z, 1e-6), want, "({x}, {z})");
        assert_eq!(second.locate(x, z, 1e-6), want, "({x}, {z})");
        found += usize::from(want.is_some());
    }
    assert!(found > 1900, "{found} points located");
}

/// A fan of parent edges around a vertex a thousandth of a cell from the
/// dividing line crosses it at points closer together than the quantize
/// grid, which the file cannot hold apart. Each crossing moves onto the
/// grid, those on one point stay separate vertices (each its own morph
/// target) with flat pieces between them, and no piece turns over.
#[test]
fn crowded_crossings_move_onto_the_lattice_without_folding_a_piece() {
    let (w, h) = (21, 11);
    let heights: Vec<f32> = (0..w * h).map(|k| ((k % w) * 7 + (k / w) * 3) as f32).collect();
    let grid = Grid::new(w, h, &heights, None);
    let window = Window::new(&grid, ((0, 20), (0, 10)));
    let centre = V { x: 10.001, z: 5.0, h: 50.0, ph: 50.0 };
    let mut pts = vec![centre];
    let n = 16;
    for k in 0..n {
        let a = std::f64::consts::TAU * f64::from(k) / f64::from(n) + 0.1;
        pts.push(V { x: 10.001 + 4.0 * a.cos(), z: 5.0 + 4.0 * a.sin(), h: 40.0, ph: 40.0 });
    }
    let tris: Vec<[u32; 3]> = (0..n).map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
    let mut soup = Soup { fixed: vec![[true; 3]; tris.len()], origin: vec![u32::MAX; tris.len()], pts, tris };
    let lattice = 256.0;
    let before = soup.pts.len();
    let nested = (Targeting { nested: true, parent: None }, soup.pts.len());
    assert_soup_sound(&soup);
    cut_along_line(&mut soup, &window, Line { vertical: true, coord: 10 }, nested, lattice);
    // The two rim crossings move along the line onto the grid, off the
    // rim, so the fan's border bends in by a hair there (a chunk's border
    // is its rectangle, which crossings never leave); every check before
    // the border's shape holds.
    match Tin::from_soup(soup.pts.clone(), &soup.tris, &soup.fixed).sanity_check() {
        Ok(()) => {}
        Err(Broken::BorderNotConvex { v }) if v as usize >= before => {}
        Err(broken) => panic!("{broken}"),
    }
    let pos = |v: u32| Coord { x: soup.pts[v as usize].x, y: soup.pts[v as usize].z };
    let area = |t: &[u32; 3]| robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2])) / 2.0;
    for t in &soup.tris {
        assert!(area(t) >= 0.0, "piece {t:?} turned over");
    }
    // All counter-clockwise and the fan's area (less what the two rim
    // crossings' moves take, under 1e-3 here): the pieces tile it
    // without overlap.
    let rim: f64 = (0..n).map(|k| area(&[0, 1 + k, 1 + (k + 1) % n])).sum();
    let total: f64 = soup.tris.iter().map(area).sum();
    assert!((total - rim).abs() < 1e-3 * rim, "pieces cover {total}, the fan {rim}");
    let crossings = &soup.pts[before..];
    // Eight spokes reach across the line, seven of them within two grid
    // steps, and two rim edges cross it far away.
    assert_eq!(crossings.len(), 10);
    assert!(crossings.iter().all(|v| v.x == 10.0 && !off_lattice(v.z, lattice)), "on the line and the grid");
    let mut at: Vec<f64> = crossings.iter().map(|v| v.z).collect();
    at.sort_by(f64::total_cmp);
    at.dedup();
    assert!(at.len() <= 6, "seven crowded crossings share three grid points: {at:?}");
    let flat = soup.tris.iter().filter(|t| area(t) == 0.0).count();
    assert!(flat > 0, "the crossings on one point leave flat pieces between them");
}

/// Provence at 5 m with 16-cell leaves, `quantize`, failed `verify`: a
/// sample was placed on an edge from a crossing that the file's grid had
/// moved a thousandth of a cell off a steep parent sliver, and its morph
/// target, interpolated from that crossing's, missed the parent by 1.9 m
/// (and the next sample, inside an ordinary parent triangle, by 0.75 m).
/// In a quantized build every sample's target is now the parent
/// surface's height at it, to f64 rounding, however the crossings moved.
#[test]
fn samples_placed_against_moved_crossings_target_the_parent_surface() {
    let (w, h) = (129, 97);
    let heights = rough(w, h);
    let grid = Grid::new(w, h, &heights, None);
    let root = ChunkKey { level: 0, x: 0, y: 0 };
    fn on_grid(spec: ChunkSpec<'_>, k: u32) -> ChunkSpec<'_> {
        ChunkSpec { cut_lattice: Some(k), ..spec }
    }
    let parent = meshed(&grid, &on_grid(lined(root, ((0, 128), (0, 96)), 4.0, None, false), 2)).unwrap();
    let surface = parent.locator();
    let (mut samples, mut crossings) = (0, 0);
    for (x, y, footprint) in [(0, 0, ((0, 64), (0, 48))), (1, 0, ((64, 128), (0, 48))), (1, 1, ((64, 128), (48, 96)))] {
        let key = ChunkKey { level: 1, x, y };
        let child = meshed(&grid, &on_grid(lined(key, footprint, 2.0, Some(&parent), false), 3)).unwrap();
        for v in &child.vertices {
            if whole(v.x) && whole(v.z) {
                let (_, ph) = surface.locate(v.x, v.z, 1e-9).expect("on the parent");
                assert!((ph - v.ph).abs() < 1e-9, "sample ({}, {}): target {} against {ph}", v.x, v.z, v.ph);
                samples += 1;
            } else {
                crossings += usize::from(!off_lattice(v.x, 8.0) && !off_lattice(v.z, 8.0));
            }
        }
    }
    assert!(samples > 300 && crossings > 20, "{samples} samples, {crossings} cut points on the grid");
}

/// California at 1 m panicked ("a line is a chain of edges"): crossings
/// within half a step of the point where the dividing line meets the
/// border rounded onto that sample, where the border's vertex already
/// was, and the border line went through seven vertices at one point.
/// A crossing never lands on a sample's point.
#[test]
fn a_crossing_next_to_a_sample_does_not_land_on_it() {
    let heights = vec![0.0f32; 21 * 11];
    let grid = Grid::new(21, 11, &heights, None);
    let window = Window::new(&grid, ((0, 20), (0, 10)));
    let v = |x: f64, z: f64| V { x, z, h: 0.0, ph: 0.0 };
    // The line x = 10 passes through corner P and crosses A–B at z = 4.999,
    // whose nearest point on a 1/256 grid is the sample (10, 5) = P.
    let pts = vec![v(9.0, 4.998), v(11.0, 5.0), v(10.0, 5.0)];
    let mut soup = Soup { pts, tris: vec![[0, 1, 2]], fixed: vec![[true; 3]], origin: vec![0] };
    let nested = (Targeting { nested: true, parent: None }, soup.pts.len());
    cut_along_line(&mut soup, &window, Line { vertical: true, coord: 10 }, nested, 256.0);
    assert_soup_sound(&soup);
    let x = soup.pts[3];
    assert_eq!((x.x, x.z * 256.0), (10.0, 1279.0), "the other neighbour, off the sample");
    let pos = |v: u32| Coord { x: soup.pts[v as usize].x, y: soup.pts[v as usize].z };
    assert!(soup.tris.iter().all(|t| robust::orient2d(pos(t[0]), pos(t[1]), pos(t[2])) > 0.0));
}

/// A vertex 7·10⁻⁵ cells from a free edge of its triangle (quantized
/// output, one lattice step 1/256) takes the edge's place only where
/// the flipped triangles stay within target.
#[test]
fn a_vertex_a_hair_from_a_free_edge_takes_its_place_where_the_surface_allows() {
    // 9 × 9 samples at 100 m. The free edge a–b along z = x + 0.5 has
    // c 7·10⁻⁵ cells off it on one side (a sliver) and d across.
    let (w, h) = (9, 9);
    let heights = vec![100.0f32; w * h];
    let grid = Grid::new(w, h, &heights, None);
    let window = Window::new(&grid, ((0, 8), (0, 8)));
    let lattice = 256.0;
    let target = Targets::new(1.0, 0.0).on_lattice(lattice, None);
    let run = |c_height: f64| {
        let v = |x: f64, z: f64, h: f64| V { x, z, h, ph: h };
        let (a, b, c, d) = (0, 1, 2, 3);
        let pts = vec![v(0.0, 0.5, 100.0), v(8.0, 8.5, 100.0), v(4.0, 4.5001, c_height), v(6.0, 2.0, 100.0)];
        let mut tin = Tin::from_soup(pts, &[[a, b, c], [b, a, d]], &[[false; 3], [false; 3]]);
        let lines = Lines::new(&tin, ((0, 8), (0, 8)), [Some(0), None, Some(8)], [Some(0), None, Some(8)]);
        assert_eq!(tin.sanity_check(), Ok(()));
        unsliver(&mut tin, &window, ((0, 8), (0, 8)), &lines, target, 1.0 / lattice);
        assert_eq!(tin.sanity_check(), Ok(()));
        let turned = (0..2).filter(|&t| !counter_clockwise(&tin.corners(t))).count();
        (tin.find_edge(a, b).is_some(), tin.find_edge(c, d).is_some(), turned)
    };
    // On the surface the edge carries: the edge gives way to c–d.
    assert_eq!(run(100.0), (false, true, 0));
    // A vertex 50 m off that surface would tilt the new triangles past
    // δ over the samples beside it: the edge stays.
    assert_eq!(run(150.0), (true, false, 0));
}

/// A sample beside a fixed edge is split onto it only where the
/// triangle across covers data: over a void, that triangle's parent is
/// not written, and the sample at its corner would keep the child's.
#[test]
fn a_sample_is_split_onto_an_edge_only_where_data_lies_across() {
    // 9 × 9 samples; the columns x < 4 are nodata.
    let (w, h) = (9, 9);
    let heights: Vec<f32> = (0..w * h).map(|k| if k % w < 4 { f32::NAN } else { 100.0 }).collect();
    let filled: Vec<f32> = vec![100.0; w * h];
    let v = |x: f64, z: f64| V { x, z, h: 100.0, ph: 100.0 };
    // The fixed edge A–B along x = 3.5: data east of it, a void west.
    let (a, b, east, west) = (0, 1, 2, 3);
    let pts = vec![v(3.5, 0.0), v(3.5, 8.0), v(8.0, 4.0), v(0.5, 4.0)];
    let tin = Tin::from_soup(pts, &[[b, a, east], [a, b, west]], &[[true, false, false], [true, false, false]]);
    assert_eq!(tin.sanity_check(), Ok(()));
    assert_eq!((tin.ends(0), tin.ends(3)), ((b, a), (a, b)));
    let grid = Grid::new(w, h, &heights, Some(&filled));
    let window = Window::new(&grid, ((0, 8), (0, 8)));
    assert!(!data_across(&tin, &window, 0), "from the east, the void across");
    assert!(data_across(&tin, &window, 3), "from the west, the data across");
    // Without voids every edge has data across.
    let whole = Grid::new(w, h, &filled, None);
    assert!(data_across(&tin, &Window::new(&whole, ((0, 8), (0, 8))), 0));
}
