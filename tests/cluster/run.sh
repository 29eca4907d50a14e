#!/usr/bin/env bash
# A sharded build on a real local Dask cluster (DESIGN.md, promise 10): a
# scheduler and two workers, separate processes talking over 127.0.0.1,
# run the jobs of `terrachunk plan` through tools/dask_build.py.
#
#   1. The merged tileset is byte-identical to the single-process build and
#      passes `terrachunk verify`.
#   2. Again with the greedy TIN, and one worker killed (SIGKILL) while it
#      runs a job: the job is frozen (SIGSTOP) as soon as it is seen and let
#      run in steps of a few milliseconds until it has begun writing chunks,
#      so the check does not depend on how long a job lasts. The scheduler
#      reruns the job elsewhere, the result is still identical, and neither
#      OUT nor the killed job's folder appears before they are whole.
#
#   tests/cluster/run.sh [--bin TERRACHUNK] [--dem DEM] [--shards N] [-- BUILD OPTIONS…]
#
# Installs Dask into tests/cluster/.venv (requirements.txt) on first use;
# --bin defaults to the debug binary `cargo test` builds. Every process it
# starts is stopped on exit, by its own pid.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
cd "$repo"

bin="$repo/target/debug/terrachunk"
dem="$repo/fixtures/mount_st_helens_30m.tif"
shards=6
build_opts=(--max-error 1 --leaf-cells 32)
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$(cd "$(dirname "$2")" && pwd)/$(basename "$2")"; shift 2 ;;
    --dem) dem="$(cd "$(dirname "$2")" && pwd)/$(basename "$2")"; shift 2 ;;
    --shards) shards="$2"; shift 2 ;;
    --) shift; build_opts=("$@"); break ;;
    *) echo "run.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
[ -x "$bin" ] || cargo build --quiet
t0=$SECONDS
stamp() { echo "cluster: $1 ($((SECONDS - t0)) s)"; }

venv="$here/.venv"
if ! "$venv/bin/python" -c "import distributed" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet -r "$here/requirements.txt"
fi
py="$venv/bin/python"

work="$(mktemp -d "${TMPDIR:-/tmp}/terrachunk-cluster.XXXXXX")"
pids=()
workers=" "
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  sleep 1
  # A worker whose scheduler went first may wait to reconnect instead of exiting.
  for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

# A free port on the loopback interface for the scheduler.
port="$("$py" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
addr="tcp://127.0.0.1:$port"
"$venv/bin/dask" scheduler --host 127.0.0.1 --port "$port" --no-dashboard >"$work/scheduler.log" 2>&1 &
pids+=($!)
start_worker() {
  # No nanny: a killed worker stays dead, so the rerun is the other worker's.
  "$venv/bin/dask" worker "$addr" --host 127.0.0.1 --nthreads 1 --no-nanny --no-dashboard \
    --name "$1" >"$work/worker-$1.log" 2>&1 &
  pids+=($!)
  workers+=" $! "
}
start_worker w1
start_worker w2
"$py" - "$addr" <<'EOF'
import sys
from dask.distributed import Client
with Client(sys.argv[1], timeout=60) as c:
    c.wait_for_workers(2, timeout=60)
EOF
stamp "scheduler and 2 workers up at $addr"

"$bin" build "$dem" -o "$work/whole" --threads 2 "${build_opts[@]}" >/dev/null
"$bin" build "$dem" -o "$work/whole-tin" --threads 2 "${build_opts[@]}" --mesher tin >/dev/null
stamp "single-process builds"

# same OUT WHOLE: byte-identical to the single-process build, and verified.
same() {
  if ! diff -r "$2" "$1" >/dev/null; then
    echo "cluster: FAIL: $1 differs from the single-process build" >&2
    diff -rq "$2" "$1" | head >&2
    exit 1
  fi
  "$bin" verify "$1" --dem "$dem" >"$work/verify.log" || { cat "$work/verify.log" >&2; exit 1; }
}

# 1. Straight through.
"$bin" plan --shards "$shards" "$dem" -o "$work/a" "${build_opts[@]}" >/dev/null
"$py" tools/dask_build.py --scheduler "$addr" --terrachunk "$bin" "$work/a.shards/manifest.json" >"$work/a.log"
same "$work/a" "$work/whole"
stamp "sharded build on 2 workers: byte-identical, verify OK"

# 2. A worker killed in the middle of a job.
"$bin" plan --shards "$shards" "$dem" -o "$work/b" "${build_opts[@]}" --mesher tin >/dev/null
"$py" tools/dask_build.py --scheduler "$addr" --terrachunk "$bin" "$work/b.shards/manifest.json" >"$work/b.log" 2>&1 &
driver=$!
pids+=($driver)
victim=""
for _ in $(seq 3000); do
  for p in $(pgrep -f -- "--manifest $work/b.shards/manifest.json" || true); do
    # (The job may end between the look-ups: each may find nothing.)
    job="$( (tr '\0' ' ' <"/proc/$p/cmdline") 2>/dev/null | sed -n 's/.*--job \([0-9]*\).*/\1/p' || true)"
    [ -n "$job" ] || continue
    parent="$(ps -o ppid= -p "$p" | tr -d ' ' || true)"
    # Only ever a job of one of the workers this script started.
    case "$workers" in *" $parent "*) ;; *) continue ;; esac
    # Frozen at once, then let run a few milliseconds at a time until it is
    # seen writing chunks: however fast the job, it is caught unfinished.
    kill -STOP "$p" 2>/dev/null || continue
    for _ in $(seq 2000); do
      [ -e "$work/b.shards/job-$job" ] && break
      if compgen -G "$work/b.shards/.job-$job.tmp-*/tiles" >/dev/null; then
        victim="$parent"
        break 3
      fi
      kill -CONT "$p" 2>/dev/null || break
      sleep 0.005
      kill -STOP "$p" 2>/dev/null || break
    done
    kill -CONT "$p" 2>/dev/null || true
  done
  sleep 0.02
done
[ -n "$victim" ] || { echo "cluster: FAIL: no job seen running" >&2; exit 1; }
# The worker's death takes its job with it (PR_SET_PDEATHSIG in the driver).
kill -KILL "$victim" "$p"
stamp "killed worker $victim while it ran job $job"
if [ -e "$work/b" ] || [ -e "$work/b.shards/job-$job" ]; then
  echo "cluster: FAIL: a partial result is visible after the kill" >&2
  exit 1
fi
wait "$driver" || { cat "$work/b.log" >&2; exit 1; }
same "$work/b" "$work/whole-tin"
grep -q "job-$job: " "$work/b.log"
stamp "job $job rerun by the surviving worker: byte-identical, verify OK"
echo "cluster: 2 passed, 0 failed"
