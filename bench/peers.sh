#!/usr/bin/env bash
# Peers side by side: terrachunk (whole pipeline and one greedy
# TIN), pymartini and pydelatin on the SAME height grid, at the same max
# errors; every mesh's true error measured by terrachunk's own checker; one
# CSV and one plot with all of them.
#
#   bench/peers.sh DEM [OUT]            (OUT defaults to bench-out/peers)
#
# Settings from the environment:
#   ERRORS      max errors, metres     (default 0.25,0.5,1,2,5,10,20)
#   RUNS        timed runs per mesh    (default 3, after one warm-up)
#   SQUARE      grid side, 2^k+1, for pymartini (default 513): the top-left
#               SQUARE x SQUARE samples of the DEM; a smaller DEM is padded by
#               repeating its last row / column (512² -> 513², as Martini's
#               own demo does). terrachunk runs on the same grid.
#   THREADS     terrachunk threads     (default 0 = one per core)
#   TERRACHUNK  terrachunk binary      (default: cargo build --release)
#   VENV        virtualenv for the peers (default bench/.venv)
#
# Writes OUT/bench.csv, OUT/bench.png, OUT/bench.svg; OUT/peers/ keeps the
# exported grid (grid.npy), the peers' meshes (OBJ) and their manifest.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dem="${1:?usage: bench/peers.sh DEM [OUT]}"
out="${2:-bench-out/peers}"
errors="${ERRORS:-0.25,0.5,1,2,5,10,20}"
runs="${RUNS:-3}"
square="${SQUARE:-513}"
threads="${THREADS:-0}"
venv="${VENV:-$root/bench/.venv}"

if [ -z "${TERRACHUNK:-}" ]; then
  (cd "$root" && cargo build --release --quiet)
  TERRACHUNK="${CARGO_TARGET_DIR:-$root/target}/release/terrachunk"
fi

if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
"$venv/bin/pip" install --quiet --disable-pip-version-check -r "$root/bench/requirements.txt"

mkdir -p "$out/peers"
"$TERRACHUNK" bench "$dem" --square "$square" --export-grid "$out/peers/grid.npy"
"$TERRACHUNK" bench "$dem" --square "$square" --errors "$errors" --runs "$runs" \
  --threads "$threads" --single-tin --out "$out"
"$venv/bin/python" "$root/bench/peers.py" "$out/peers/grid.npy" --errors "$errors" \
  --runs "$runs" --out "$out/peers"
"$TERRACHUNK" bench "$dem" --square "$square" --peers "$out/peers/manifest.csv" --out "$out"

# The comparison at a glance.
"$venv/bin/python" - "$out/bench.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print(f"{'tool':<22} {'max err':>7} {'leaf tris':>10} {'meas. max':>10} {'meas. RMS':>10} {'seconds':>9} {'µs/sample':>10}")
for r in sorted(rows, key=lambda r: (float(r["max_error_m"]), r["tool"])):
    s = float(r["s_total"])
    print(f"{r['tool']:<22} {float(r['max_error_m']):>7g} {r['leaf_triangles']:>10} "
          f"{float(r['measured_max_error_m']):>10.4f} {float(r['measured_rms_error_m']):>10.4f} "
          f"{s:>9.4f} {s / int(r['samples']) * 1e6:>10.3f}")
PY
echo "$out/bench.csv $out/bench.png"
