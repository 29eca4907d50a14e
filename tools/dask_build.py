#!/usr/bin/env python3
"""Run a sharded terrachunk build on a Dask distributed cluster.

`terrachunk plan` writes the manifest; this driver submits its jobs to the
cluster's scheduler (job 0 first, then the shard jobs, then one merge task
that depends on all of them) and waits. Each job is one
`terrachunk build --manifest M --job K` process on whichever worker the
scheduler picks; the jobs need no files from each other, so they all run at
once. Retries are the engine's: a task that fails is retried `--retries`
times, and a task whose worker dies is rerun elsewhere by the scheduler
(`distributed.scheduler.allowed-failures`). A job is atomic and idempotent,
so a rerun writes the same bytes and a job already done returns at once.

    python tools/dask_build.py --scheduler tcp://127.0.0.1:8786 OUT.shards/manifest.json

Every worker must see the manifest's folder, the DEM and the `terrachunk`
binary at the same paths (a shared file system; docs/distributed.md).
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import time


def _die_with_parent():
    """Linux: the job process is killed when its worker dies, so a killed
    worker never leaves a job running that the scheduler has given to
    another worker."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def run(argv):
    """Runs one terrachunk command on a worker; raises on failure so that the
    engine retries it. Returns the command's last line of output."""
    t0 = time.monotonic()
    p = subprocess.run(argv, capture_output=True, text=True, preexec_fn=_die_with_parent)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {p.returncode}: {p.stderr.strip()}")
    lines = p.stdout.strip().splitlines()
    return {"argv": argv, "seconds": time.monotonic() - t0, "out": lines[-1] if lines else ""}


def run_job(terrachunk, manifest, job, threads):
    return run([terrachunk, "build", "--manifest", manifest, "--job", str(job), "--threads", str(threads)])


def run_merge(terrachunk, manifest, *jobs):
    # `jobs` are the job tasks' results: the scheduler runs this after all.
    return run([terrachunk, "merge", manifest])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest", help="the manifest `terrachunk plan` wrote")
    ap.add_argument("--scheduler", required=True, help="scheduler address, e.g. tcp://127.0.0.1:8786")
    ap.add_argument("--terrachunk", default="terrachunk", help="the terrachunk binary on the workers")
    ap.add_argument("--threads", type=int, default=1, help="threads per job (one job per worker thread)")
    ap.add_argument("--retries", type=int, default=2, help="retries of a failing task")
    a = ap.parse_args()

    from dask.distributed import Client, wait

    manifest = os.path.abspath(a.manifest)
    with open(manifest) as f:
        m = json.load(f)
    jobs, tag = len(m["jobs"]), m["hash"][:12]
    t0 = time.monotonic()
    with Client(a.scheduler) as client:
        opts = dict(retries=a.retries, pure=False)
        # Job 0 first (highest priority), then the shards in order.
        futures = [
            client.submit(run_job, a.terrachunk, manifest, k, a.threads, key=f"terrachunk-{tag}-job-{k}",
                          priority=jobs - k, **opts)
            for k in range(jobs)
        ]
        merged = client.submit(run_merge, a.terrachunk, manifest, *futures, key=f"terrachunk-{tag}-merge", **opts)
        wait(futures + [merged])
        failed = [f for f in futures + [merged] if f.status != "finished"]
        for f in failed:
            print(f"{f.key}: {f.exception()}", file=sys.stderr)
        if failed:
            return 1
        for f in futures:
            r = f.result()
            print(f"{f.key}: {r['seconds']:.2f} s: {r['out']}")
        r = merged.result()
        print(f"merge: {r['seconds']:.2f} s: {r['out']}")
    print(f"{jobs} jobs and the merge in {time.monotonic() - t0:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
