#!/usr/bin/env bash
# Builds every DEM given (files or .hgt folders) at each max error in each
# --compress mode and holds each tileset to `terrachunk verify`; one CSV row
# per build: the verdict, the leaves' triangles, the largest sliver share
# (aspect over 100) of any level and the smallest angle.
#
#   bench/verify_sweep.sh DEM... > sweep.csv
#
# Settings from the environment:
#   ERRORS      max errors, metres   (default 0.5,1,5)
#   MODES       compress modes       (default none,quantize,meshopt,meshopt-v1)
#   MESHER      rtin or tin          (default rtin)
#   TERRACHUNK  terrachunk binary    (default target/release/terrachunk)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${TERRACHUNK:-$root/target/release/terrachunk}"
errors="${ERRORS:-0.5,1,5}"
modes="${MODES:-none,quantize,meshopt,meshopt-v1}"
mesher="${MESHER:-rtin}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
echo "dem,max_error_m,compress,mesher,verify,build_s,leaf_triangles,worst_sliver_pct,min_angle_deg"
for dem in "$@"; do
  for e in ${errors//,/ }; do
    for m in ${modes//,/ }; do
      out="$work/out"
      start=$(date +%s%N)
      if ! "$bin" build "$dem" -o "$out" --force --texture none --max-error "$e" --compress "$m" \
          --mesher "$mesher" >"$work/build.txt" 2>&1; then
        echo "$(basename "$dem"),$e,$m,$mesher,BUILD FAILED,,,,"
        tail -3 "$work/build.txt" >&2
        continue
      fi
      ms=$(( ($(date +%s%N) - start) / 1000000 ))
      if "$bin" verify "$out" --dem "$dem" >"$work/verify.txt" 2>&1; then verdict=OK; else verdict=FAIL; fi
      # Level rows: level chunks δ err gap triangles slivers% angle°
      stats=$(awk '$1 ~ /^[0-9]+$/ && NF == 8 { t = $6; if ($7 > w) w = $7; a = $8; sub(/°/, "", a);
                   if (min == "" || a + 0 < min) min = a + 0 } END { printf "%s,%.3f,%.2f", t, w, min }' "$work/verify.txt")
      [ "$verdict" = OK ] || grep FAIL "$work/verify.txt" | head -3 >&2
      echo "$(basename "$dem"),$e,$m,$mesher,$verdict,$((ms / 1000)).$(( (ms % 1000) / 100 )),$stats"
    done
  done
done
