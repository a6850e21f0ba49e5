#!/usr/bin/env python3
"""A label map with many ids (issue 64, bad input): N = n^3 labels of c^3 voxels each, uint64
ids scattered over the whole range (2^53, 2^53 + 1 and 2^64 - 1 among them), meshed by
tandem extract --labels into one file per label, into one GLB, and into a Neuroglancer
export; wall, CPU and peak RSS of each through bench_run, as a Markdown table on stdout.

    python3 tests/bench/many_ids.py --bin BENCH_BUILD/bin [--tandem build/bin/tandem]
        [--n 100] [--cell 1] [--error 4] [--only folder,glb,neuroglancer] [--keep]

BENCH_BUILD: the benchmark's build (bash tests/bench/run.sh --labels --quick makes one).
The volume and outputs go to the scratch folder ($TANDEM_BENCH_SCRATCH, default
${TMPDIR:-/tmp}/tandem-bench) and are removed afterwards unless --keep.
"""

import argparse
import array
import json
import os
import random
import shutil
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench  # noqa: E402
from bench import fmt, mib  # noqa: E402


def write_volume(path, n, cell, seed=1):
    """n^3 cells of cell^3 voxels, each its own uint64 id; raw + JSON sidecar."""
    rng = random.Random(seed)
    ids = [1 << 53, (1 << 53) + 1, (1 << 64) - 1]
    seen = set(ids)
    while len(ids) < n ** 3:
        x = rng.getrandbits(64)
        if x and x not in seen:
            seen.add(x)
            ids.append(x)
    rng.shuffle(ids)
    side = n * cell
    with open(path[:-5] + ".raw", "wb") as f:
        for k in range(side):
            plane = array.array("Q")
            for j in range(side):
                base = ((k // cell) * n + j // cell) * n
                plane.extend(ids[base + i // cell] for i in range(side))
            f.write(plane.tobytes())
    with open(path, "w") as f:
        json.dump({"dims": [side] * 3, "dtype": "uint64", "spacing": [1, 1, 1],
                   "byte_order": "little", "raw_file": os.path.basename(path[:-5]) + ".raw",
                   "description": f"{n ** 3} one-id cells of {cell}^3 voxels, scattered uint64 ids"},
                  f)
    return len(ids)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True, help="the benchmark build's bin folder")
    ap.add_argument("--tandem", help="the tandem to run (default: BIN/tandem; the Neuroglancer "
                    "export needs one built with Draco, as the main build is)")
    ap.add_argument("--n", type=int, default=100, help="cells per axis (n^3 labels)")
    ap.add_argument("--cell", type=int, default=1, help="voxels per cell and axis")
    ap.add_argument("--error", type=float, default=4.0, help="tandem's --error")
    ap.add_argument("--only", help="comma-separated: folder, glb, neuroglancer")
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--scratch", default=os.environ.get(
        "TANDEM_BENCH_SCRATCH", os.path.join(os.environ.get("TMPDIR", "/tmp"), "tandem-bench")))
    args = ap.parse_args()
    work = os.path.join(args.scratch, f"many-ids-{args.n}-{args.cell}")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    volume = os.path.join(work, "ids.json")
    labels = write_volume(volume, args.n, args.cell)
    tandem = args.tandem or os.path.join(args.bin, "tandem")
    base = [tandem, "extract", "--input", volume, "--labels", "--error", str(args.error),
            "--quiet"]
    runs = {
        "folder": base + ["--out", os.path.join(work, "out") + "/"],
        "glb": base + ["--out", os.path.join(work, "labels.glb")],
        "neuroglancer": base + ["--out", os.path.join(work, "ng.glb"), "--neuroglancer",
                                os.path.join(work, "ng")],
    }
    only = args.only.split(",") if args.only else list(runs)
    rows = []
    for name in only:
        r = bench.run_measured(runs[name], os.path.join(work, f"{name}.out"),
                               os.path.join(work, f"{name}.err"),
                               os.path.join(args.bin, "bench_run"), timeout=7200)
        problem = bench.run_problem(r, None)
        if problem:
            sys.exit(f"many_ids: {name}: {problem}: {bench.tail(os.path.join(work, name + '.err'), 3)}")
        files = len(os.listdir(os.path.join(work, "out"))) if name == "folder" else None
        rows.append((name, r, files))
        print(f"{name}: wall {r['wall_s']:.1f} s, cpu {r['cpu_s']:.1f} s, "
              f"rss {mib(r['peak_rss_bytes']):.0f} MiB", file=sys.stderr, flush=True)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{labels:,} labels ({args.n}^3 cells of {args.cell}^3 voxels, uint64), "
          f"--error {args.error:g}; load average after: {load}\n")
    print("| output | wall s | CPU s | peak RSS MiB | files |\n|---|---|---|---|---|")
    for name, r, files in rows:
        print(f"| {name} | {fmt(r['wall_s'])} | {fmt(r['cpu_s'])} | "
              f"{fmt(mib(r['peak_rss_bytes']), '.0f')} | {'' if files is None else f'{files:,}'} |")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
