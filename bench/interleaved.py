"""Whole-pipeline time against pydelatin, run by run.

`bench/peers.sh` times each tool's ladder in turn, so a machine whose speed
drifts between the two halves moves the ratio. This script alternates them:
for each max error, one build by each terrachunk binary given, then one
pydelatin mesh, repeated; it prints the medians and the ratios as CSV.

    bench/.venv/bin/python bench/interleaved.py GRID.npy GRID.asc \\
        --bin target/release/terrachunk [--bin OTHER] --errors 0.25,1,5,20 --runs 9

Each build's output is kept until the end (a few hundred MB for Fuji's
ladder), so that no build pays for deleting the one before it. With
`--sync` the files are flushed to disk after each build, outside its time:
without it, a virtual machine's slow writeback makes later builds wait on
the dirty pages of earlier ones.

GRID.npy is the grid `terrachunk bench DEM --square 513 --export-grid`
writes; GRID.asc the same grid as an ESRI ASCII file for `terrachunk build`
(`--write-asc` makes it). terrachunk's time is its report's total less its
DEM load (the ASCII parse, which pydelatin does not pay); pydelatin's is the
`Delatin(...)` call alone, as in `bench/peers.py`.
"""

import argparse
import itertools
import json
import os
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from pydelatin import Delatin


def write_asc(grid, path):
    with open(path, "w") as f:
        f.write(f"ncols {grid.shape[1]}\nnrows {grid.shape[0]}\n")
        f.write("xllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n")
        for row in grid:
            f.write(" ".join("-9999" if np.isnan(v) else repr(float(v)) for v in row) + "\n")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("npy")
    p.add_argument("asc")
    p.add_argument("--bin", action="append", required=True, help="terrachunk binary (repeatable)")
    p.add_argument("--errors", default="0.25,0.5,1,2,5,10,20,30")
    p.add_argument("--runs", type=int, default=9)
    p.add_argument("--write-asc", action="store_true", help="write ASC from NPY first")
    p.add_argument("--sync", action="store_true",
                   help="flush written files to disk after each build, untimed, so no build waits on an earlier one's")
    a = p.parse_args()
    grid = np.load(a.npy)
    if a.write_asc:
        write_asc(grid, a.asc)
    scratch = Path(tempfile.mkdtemp(prefix="interleaved-"))

    # Every build writes into a folder of its own, all removed at the end:
    # ext4 searches past inodes freed in the last minutes when it creates
    # files, so deleting one build's output before the next made the next
    # pay for it (Fuji at 0.25 m, about 600 files: 1.17 s a build that way,
    # 0.77-0.88 s without).
    count = itertools.count()

    def build(binary, e):
        k = next(count)
        out, rep = scratch / f"out{k}", scratch / f"report{k}.json"
        subprocess.run([binary, "build", a.asc, "--out", str(out), "--max-error", str(e), "--report", str(rep)],
                       check=True, capture_output=True)
        s = json.loads(rep.read_text())["seconds"]
        if a.sync:
            os.sync()
        return s["total"] - s["load"]

    def delatin(e):
        t = time.perf_counter()
        Delatin(grid, max_error=e)
        return time.perf_counter() - t

    names = [f"bin{k}" for k in range(len(a.bin))]
    print("max_error," + ",".join(f"{n}_s" for n in names) + ",pydelatin_s," + ",".join(f"{n}_ratio" for n in names))
    for e in (float(x) for x in a.errors.split(",")):
        for b in a.bin:
            build(b, e)  # warm-up
        delatin(e)
        times = {b: [] for b in a.bin}
        peer = []
        for _ in range(a.runs):
            for b in a.bin:
                times[b].append(build(b, e))
            peer.append(delatin(e))
        mp = statistics.median(peer)
        ms = [statistics.median(times[b]) for b in a.bin]
        print(f"{e:g}," + ",".join(f"{m:.4f}" for m in ms) + f",{mp:.4f}," + ",".join(f"{m / mp:.2f}" for m in ms),
              flush=True)
    shutil.rmtree(scratch, ignore_errors=True)
    for k, b in enumerate(a.bin):
        print(f"# bin{k} = {b}")


if __name__ == "__main__":
    main()
