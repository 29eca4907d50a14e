#!/usr/bin/env bash
# Open terrachunk chunks in the tools people will open them in (DESIGN.md
# promises 4 and 5): Blender's glTF importer (bpy), MeshLab (pymeshlab) and
# CesiumJS in headless Chromium. Installs its pinned tools itself (Debian
# chromium, a fresh venv from requirements.txt, npm ci from package-lock.json),
# builds a georeferenced, textured, skirted fixture with the terrachunk binary,
# runs the three checkers and exits non-zero if any of them finds a mismatch.
#
#   tests/importers/run.sh [--compress none|quantize|meshopt|meshopt-v1] [--dem DEM]... [--bin TERRACHUNK]
#                          [--screenshots DIR] [--has-nodata]
#
# By default three fixtures: Mount St Helens (UTM 10N on NAD27, 4 levels),
# Dallas–Fort Worth (SRTM 3″ in degrees, 3 levels), both textured with the
# generated colour map and skirted, so both placement paths (projected and
# geographic) reach CesiumJS, and Mount St Helens again at 0.25 m in two
# levels with --max-chunk-vertices 1048575, whose root passes 65 535
# vertices and takes u32 indices. Dallas–Fort Worth is built with
# --index-tiles 8, so its index is tileset.json over external tilesets
# and every checker reads them (CesiumJS fetches them itself). --compress is passed to `terrachunk build`
# (default none: not passed at all, so this runs on a binary that predates
# the option); --bin defaults to the debug binary `cargo test` builds;
# --screenshots writes the first fixture's blender_chunk.png and cesium.png
# there (docs/ for the README), else into the scratch directory.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
cd "$repo"

compress=none
dems=()
bin=""
shots=""
nodata=()
while [ $# -gt 0 ]; do
  case "$1" in
    --compress) compress="$2"; shift 2 ;;
    --dem) dems+=("$2"); shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --screenshots) shots="$2"; shift 2 ;;
    --has-nodata) nodata=(--has-nodata); shift ;;
    *) echo "run.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
# Extra build settings per fixture (one string each, split on spaces).
extra=()
if [ ${#dems[@]} -eq 0 ]; then
  # The third: Mount St Helens at 0.25 m with 256-cell leaves and chunks
  # allowed up to 2^20 - 1 vertices, two levels,
  # whose root holds over 65 535 vertices and so is written with u32
  # indices (max_chunk_vertices); the run checks that it is.
  dems=(fixtures/mount_st_helens_30m.tif fixtures/dfw_texas_srtm3.tif fixtures/mount_st_helens_30m.tif)
  extra=("" "--index-tiles 8" "--max-error 0.25 --leaf-cells 256 --max-chunk-vertices 1048575")
fi

t0=$SECONDS
stamp() { echo "importers: $1 ($((SECONDS - t0)) s)"; }
work="$(mktemp -d "${TMPDIR:-/tmp}/terrachunk-importers.XXXXXX")"
trap 'rm -rf "$work"' EXIT
shots="${shots:-$work}"
mkdir -p "$shots"

# ---- Tools (nothing is kept from an earlier run but the package managers' caches)
if ! command -v "${CHROMIUM:-/usr/bin/chromium}" >/dev/null 2>&1; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
python="${PYTHON:-python3.11}"
"$python" -m venv "$work/venv"
"$work/venv/bin/pip" install --quiet --disable-pip-version-check -r "$here/requirements.txt"
(cd "$here" && npm ci --no-audit --no-fund --loglevel=error)
stamp "tools installed: $("${CHROMIUM:-/usr/bin/chromium}" --version 2>/dev/null | head -1), $("$work/venv/bin/python" --version)"

# ---- The tilesets, and the checkers on each: every checker runs even when
# one before it failed
if [ -z "$bin" ]; then
  bin="${CARGO_TARGET_DIR:-$repo/target}/debug/terrachunk"
  [ -x "$bin" ] || cargo build --quiet
fi
status=0
run() {
  local name="$1"; shift
  if "$@"; then stamp "$name passed"; else stamp "$name FAILED"; status=1; fi
}
n=0
for dem in "${dems[@]}"; do
  out="$work/out$n"
  build_args=(build "$dem" -o "$out")
  [ "$compress" != none ] && build_args+=(--compress "$compress")
  # shellcheck disable=SC2206 # split on purpose: a fixture's extra settings
  [ -n "${extra[$n]:-}" ] && build_args+=(${extra[$n]})
  if ! "$bin" "${build_args[@]}" >"$work/build$n.log" 2>&1; then
    cat "$work/build$n.log"
    stamp "build of $dem FAILED"
    status=1
    continue
  fi
  stamp "built $dem (compress $compress${extra[$n]:+, ${extra[$n]}}) with $bin"
  if [[ "${extra[$n]:-}" == *--index-tiles* ]] && ! compgen -G "$out/tileset-*.json" >/dev/null; then
    stamp "index of $dem not split into external tilesets FAILED"
    status=1
  fi
  if [[ "${extra[$n]:-}" == *--max-chunk-vertices* ]]; then
    run "u32 indices ($dem)" "$work/venv/bin/python" "$here/glbref.py" --expect-u32-root "$out"
  fi
  dir="$shots"
  [ $n -eq 0 ] || dir="$work/shots$n"
  mkdir -p "$dir"
  run "blender ($dem)" "$work/venv/bin/python" "$here/blender_check.py" "$out" --render "$dir/blender_chunk.png"
  run "meshlab ($dem)" "$work/venv/bin/python" "$here/meshlab_check.py" "$out" "${nodata[@]}"
  run "cesium ($dem)" node "$here/cesium_check.mjs" "$out" --dem "$dem" --screenshot "$dir/cesium.png" --close-shot "$work/cesium_close$n.png"
  n=$((n + 1))
done
if [ $status -ne 0 ]; then
  stamp "importer checks FAILED (compress $compress)"
else
  stamp "importer checks passed on ${#dems[@]} fixtures (compress $compress)"
fi
exit $status
