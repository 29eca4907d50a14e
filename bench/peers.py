"""Mesh a grid that `terrachunk bench --export-grid` wrote with the Python
peers, pymartini (Martini's right-triangulated irregular network) and
pydelatin (hmm's greedy-insertion Delaunay TIN), at each max error; time each
(median of the timed runs after a warm-up) and write every mesh as an OBJ
file in grid units (`v column height row`, `f a b c`) with a manifest that
`terrachunk bench --peers` reads to measure their true error with
terrachunk's own checker.

Timed: pymartini `create_tile` + `get_mesh` (the `Martini(n)` set-up depends
only on the grid size and is reused across tiles, as its docs advise; its
time is printed apart); pydelatin the `Delatin(...)` call, which meshes.
Both get the float32 heights exactly as terrachunk reads them.

Each mesh's triangle shapes, in plan and in metres (`--spacing`), go to
DIR/quality.csv with the columns terrachunk's bench gives its own rows
(src/mesh/quality.rs): triangles, the share with aspect (longest edge ÷ the
height on it) over 100, how many over 10³, and the smallest angle.

usage: python bench/peers.py GRID.npy --errors 1,5 --runs 3 --out DIR [--spacing SX,SZ]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from pydelatin import Delatin
from pymartini import Martini


def timed(fn, warmup, runs):
    for _ in range(warmup):
        fn()
    secs, out = [], None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        secs.append(time.perf_counter() - t)
    return statistics.median(secs), out


def write_obj(path, xs, hs, zs, tris):
    """Vertices (column, height, row) and 0-based triangles as OBJ."""
    with open(path, "w") as f:
        f.write("# grid units: v column height_m row\n")
        np.savetxt(f, np.column_stack([xs, hs, zs]), fmt="v %.17g %.17g %.17g")
        np.savetxt(f, np.asarray(tris, dtype=np.int64) + 1, fmt="f %d %d %d")


SLIVER_ASPECT = 100.0
NEEDLE_ASPECT = 1000.0


def quality(xs, zs, tris, spacing):
    """(triangles, share with aspect > 100, count > 10³, smallest angle in
    degrees) of a mesh whose vertices are at grid (column, row), measured in
    metres. Aspect = longest edge² ÷ twice the area; no area: infinite."""
    p = np.column_stack([np.asarray(xs, np.float64) * spacing[0], np.asarray(zs, np.float64) * spacing[1]])
    t = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return 0, 0.0, 0, 60.0
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    ab, bc, ca = b - a, c - b, a - c
    twice_area = np.abs(ab[:, 0] * (-ca[:, 1]) - ab[:, 1] * (-ca[:, 0]))
    sq = np.column_stack([(e * e).sum(axis=1) for e in (ab, bc, ca)])
    with np.errstate(divide="ignore", invalid="ignore"):
        aspect = np.where(twice_area > 0, sq.max(axis=1) / twice_area, np.inf)

    def angle(u, v):
        cross = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        return np.degrees(np.arctan2(cross, (u * v).sum(axis=1)))

    smallest = np.minimum(np.minimum(angle(ab, -ca), angle(bc, -ab)), angle(ca, -bc))
    smallest = np.where(twice_area > 0, smallest, 0.0)
    return len(t), float((aspect > SLIVER_ASPECT).mean()), int((aspect > NEEDLE_ASPECT).sum()), float(smallest.min())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("grid", type=Path)
    ap.add_argument("--errors", default="0.25,0.5,1,2,5,10,20")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--spacing", default="1,1", help="cell size in metres, east-west,north-south")
    a = ap.parse_args()
    spacing = [float(s) for s in a.spacing.split(",")]
    errors = [float(e) for e in a.errors.split(",")]
    grid = np.ascontiguousarray(np.load(a.grid), dtype=np.float32)
    rows, cols = grid.shape
    if np.isnan(grid).any():
        sys.exit(
            f"{a.grid}: {int(np.isnan(grid).sum())} nodata samples; pymartini and pydelatin "
            "cannot mesh voids: use a DEM (or --square) without them"
        )
    a.out.mkdir(parents=True, exist_ok=True)
    manifest = ["tool,max_error_m,seconds,runs,mesh"]
    shapes = ["tool,max_error_m,triangles,sliver_share,over_1000,min_angle_deg"]

    def shape_row(tool, e, xs, zs, tris):
        n, share, needles, smallest = quality(xs, zs, tris, spacing)
        shapes.append(f"{tool},{e:g},{n},{share:.6g},{needles},{smallest:.6g}")
        print(f"           aspect > 100: {100 * share:.4f} %, > 10³: {needles}, smallest angle {smallest:.4g}°")

    square = rows == cols and ((rows - 1) & (rows - 2)) == 0 and rows >= 3
    if square:
        t = time.perf_counter()
        martini = Martini(rows)
        print(f"pymartini: Martini({rows}) set-up {time.perf_counter() - t:.3f} s (not counted)")
    else:
        print(f"pymartini skipped: the grid is {cols}x{rows}, not (2^k+1)²  (use --square)")

    for e in errors:
        if square:

            def run_martini():
                tile = martini.create_tile(grid)
                return tile.get_mesh(e)

            secs, (v, t) = timed(run_martini, a.warmup, a.runs)
            v = v.reshape(-1, 2).astype(np.int64)
            t = t.reshape(-1, 3)
            name = f"pymartini_{e:g}.obj"
            write_obj(a.out / name, v[:, 0], grid[v[:, 1], v[:, 0]].astype(np.float64), v[:, 1], t)
            manifest.append(f"pymartini,{e:g},{secs:.6f},{a.runs},{name}")
            print(f"pymartini  {e:>6g} m: {len(t):>8} triangles, {secs:.4f} s")
            shape_row("pymartini", e, v[:, 0], v[:, 1], t)

        secs, d = timed(lambda: Delatin(grid, max_error=e), a.warmup, a.runs)
        p = d.vertices
        t = d.triangles
        # hmm returns (x, y, height) with y pointing north (row = rows - 1 - y);
        # check that against the grid rather than trust it.
        xi, yi = p[:, 0].astype(np.int64), p[:, 1].astype(np.int64)
        h = p[:, 2].astype(np.float32)
        if np.array_equal(h, grid[rows - 1 - yi, xi]):
            row = rows - 1 - p[:, 1]
        elif np.array_equal(h, grid[yi, xi]):
            row = p[:, 1]
        else:
            sys.exit("pydelatin: vertex heights match neither grid[row, column] nor its flip")
        name = f"pydelatin_{e:g}.obj"
        write_obj(a.out / name, p[:, 0], p[:, 2].astype(np.float64), row, t)
        manifest.append(f"pydelatin,{e:g},{secs:.6f},{a.runs},{name}")
        print(f"pydelatin  {e:>6g} m: {len(t):>8} triangles, {secs:.4f} s (its own max error {d.error:.4f})")
        shape_row("pydelatin", e, p[:, 0], row, t)

    (a.out / "manifest.csv").write_text("\n".join(manifest) + "\n")
    (a.out / "quality.csv").write_text("\n".join(shapes) + "\n")


if __name__ == "__main__":
    main()
