#!/usr/bin/env python3
"""RMS distance at the same triangle count, for a speed step that changes the meshes.

    python3 tests/bench/same_count_rms.py OLD/bin/tandem NEW/bin/tandem [--quick] [--keep DIR]

Issue 25's quality bound: a change may move the meshes, but the RMS distance to the
full-resolution surface at the same triangle count may not grow by more than 3 %. Two builds
at the same E0 rarely stop at the same count, so each runs at E0 x {0.8, 1, 1.25} with
`--reference` (distances to our own full-resolution marching-cubes surface). B's RMS is then
interpolated at A's count, log-log through B's three points, and the ratio B / A is printed
per input, with the geometric mean and the worst. Error(K) <= E0 is checked on every run.
Exit 1 when some run's Error(K) exceeds its E0 or the geometric mean exceeds 1.03.

Inputs (generated, so that a clone without ../shared runs it):
- the Pillow Box, the Link and the gyroid ball at 256³ (`tandem generate`), at e0.json's E0;
- with --dense-volume (tests/bench's dense_volume, built by `run.sh --dense`): the closed
  period-32 gyroid and the noise field at 512² x 32, E0 = 0.2;
- the shared CT/MRI volumes of ../shared/data when present, at e0.json's E0.
--quick keeps the 128³ shapes only (a minute; a smoke test of the script, not a verdict).
Nothing here is timed.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SHARED = os.path.normpath(os.path.join(HERE, "..", "..", "..", "shared", "data"))
FACTORS = [0.8, 1.0, 1.25]
SHARED_INPUTS = ["ct_engine_256x256x128_uint8", "ct_head_headsq_64x64x93_int16",
                 "mri_avg152T1_91x109x91_uint8", "mr_head_48x62x42_uint8"]


def run(tandem, path, e0, work):
    out = os.path.join(work, "out.metrics.json")
    subprocess.run([tandem, "extract", "--input", path, "--error", repr(e0), "--out",
                    os.path.join(work, "out.ply"), "--reference", "--metrics", out, "--quiet"],
                   check=True, capture_output=True)
    with open(out) as f:
        m = json.load(f)
    return m["triangles_final"], m["distance"]["L2"]["max"], m["error_max"] <= e0 * (1 + 1e-9)


def at_count(points, n):
    """RMS at triangle count n, piecewise linear in log-log through (count, rms) points."""
    pts = sorted((math.log(c), math.log(r)) for c, r in points)
    x = math.log(n)
    k = 0
    while k < len(pts) - 2 and x > pts[k + 1][0]:
        k += 1
    (xa, ya), (xc, yc) = pts[k], pts[k + 1]
    return math.exp(ya + (yc - ya) * (x - xa) / (xc - xa)) if xc != xa else math.exp(ya)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="the reference build's tandem")
    ap.add_argument("b", help="the changed build's tandem")
    ap.add_argument("--quick", action="store_true", help="the 128³ shapes only")
    ap.add_argument("--dense-volume", help="tests/bench's dense_volume binary: adds 512² x 32 inputs")
    ap.add_argument("--keep", help="generate the inputs here (and keep them) instead of a temp dir")
    args = ap.parse_args()
    with open(os.path.join(HERE, "e0.json")) as f:
        e0s = json.load(f)
    work = args.keep or tempfile.mkdtemp(prefix="same_count_rms.")
    os.makedirs(work, exist_ok=True)
    inputs = []
    size = 128 if args.quick else 256
    for shape in ("pillowbox", "link", "gyroid"):
        name = f"{shape}-{size}"
        path = os.path.join(work, name + ".json")
        if not os.path.exists(path):
            subprocess.run([args.a, "generate", shape, "--size", str(size), "--out", path],
                           check=True, capture_output=True)
        inputs.append((name, path, e0s[name]["e0"]))
    if args.dense_volume and not args.quick:
        for name, spec in (("gyroid-p32-512x32", ["gyroid", "--period", "32"]),
                           ("noise-512x32", ["noise", "--scale", "32", "--seed", "1"])):
            path = os.path.join(work, name + ".json")
            if not os.path.exists(path):
                subprocess.run([args.dense_volume] + spec + ["--size", "512", "--slices", "32",
                                                             "--out", path],
                               check=True, capture_output=True)
            inputs.append((name, path, 0.2))
    if not args.quick:
        for name in SHARED_INPUTS:
            path = os.path.join(SHARED, name + ".json")
            if os.path.exists(path):
                inputs.append((name, path, e0s[name]["e0"]))
    ratios, all_ok = [], True
    for name, path, e0 in inputs:
        runs = [[run(t, path, e0 * f, work) for f in FACTORS] for t in (args.a, args.b)]
        n_a, rms_a, _ = runs[0][1]
        rms_b = at_count([(n, r) for n, r, _ in runs[1]], n_a)
        ok = all(r[2] for side in runs for r in side)
        all_ok &= ok
        ratios.append(rms_b / rms_a)
        print(f"{name:32s} A: {n_a} triangles, RMS {rms_a:.5f} | B at E0: {runs[1][1][0]} "
              f"triangles, RMS {runs[1][1][1]:.5f} | B's RMS at A's count {rms_b:.5f}: "
              f"ratio {rms_b / rms_a:.4f} | Error(K) <= E0: {ok}", flush=True)
    gm = math.exp(sum(map(math.log, ratios)) / len(ratios))
    print(f"B / A RMS at the same count over {len(ratios)} inputs: geometric mean {gm:.4f}, "
          f"worst {max(ratios):.4f} (issue 25's bound: 1.03); Error(K) <= E0 on every run: "
          f"{all_ok}")
    return 0 if all_ok and gm <= 1.03 else 1


if __name__ == "__main__":
    sys.exit(main())
