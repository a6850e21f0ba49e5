#!/usr/bin/env python3
"""The reduction sweep (issues 24 and 66): quality at every reduction, from the ~10 % point the
main benchmark uses down to ~0.1 % of the full-resolution triangles, on the generated shapes,
on fields not made with the paper's formulas and on the shared scans.

Run it through tests/bench/run.sh (which builds the programs first):
    bash tests/bench/run.sh --sweep            # full: tests/bench/SWEEP.md + sweep.json + PNGs
    bash tests/bench/run.sh --sweep --quick    # pillowbox-64 + pillowbox-sdf-64, scratch directory
Another engine on the same inputs and E0 values (the bench tools from --bin):
    bash tests/bench/run.sh --sweep --tandem OTHER/build/bin/tandem --inputs fields \
        --e0-from tests/bench/sweep.json --report /tmp/sweep-other/SWEEP.md

Inputs (--inputs / --only: a comma-separated list of name parts, or the groups "generated",
"fields", "shared"):
  generated  the Pillow Box and the Link by `tandem generate` at 256³ and 512³ (SCRATCH/volumes,
             shared with bench.py);
  fields     fields not made with the paper's formulas, at --field-size (default 128), written by
             tests/bench's field_volume (fields_lib.h): the rounded cube as the approximate
             distance (|x|⁸ + |y|⁸ + |z|⁸)^(1/8) − R (roundcube-field), the signed distance maps
             (-sdf), the Gaussian-smoothed masks (-mask) and CT-like intensities (-ct: a blurred
             mask with seeded noise) of the Pillow Box, the Link and a sphere;
  shared     the shared CT/MRI volumes (../shared/data beside the repository, at their first
             suggested iso-value; skipped when absent).

E0 values, per input. Generated: geometric from E0(10 %) (tests/bench/e0.json, the E0 at which
tandem-lag keeps ~10 % of the triangles) up to the E0 that keeps ~0.1 %, estimated from one probe
run (tandem-lag, --parts 1, at 30 × E0(10 %)) by fitting kept ∝ E0^-p through the two points;
--points N values (default 7), inputs over 300 k triangles --points-mid (5), those over 1 M
--points-large (2) from ~1 % to ~0.1 % only. Fields and shared scans: the E0 at which tandem-lag
keeps 1 %, 0.3 % and 0.1 % of the triangles (--fractions; within 15 %, found by a secant search
on log E0 from the probe's fit), the fields also at E0(10 %) and at the default E0 (0.2 × the
smallest spacing). A missing E0(10 %) is searched for and, in a full run, added to e0.json.
--e0-from RESULTS takes every input's E0 values from an earlier sweep.json instead (the same
points for another engine). Every input stops early once tandem-lag's count falls by less than
3 % from one value to the next (the floor of a volume with many small components).
--quick: pillowbox-64 at 3 values and pillowbox-sdf-64 at 2 (the default E0 and ~1 %, no search).

Per E0, each in its own process (bench.py's launcher: wall time, CPU time, peak RSS):
  classical, tandem, tandem-lag    the CLI (--tandem, default BIN/tandem) with --schedule S,
                                   default slabs (--parts 0: 4 on grids at least 256 wide, 2 on
                                   81) and --parts 1 ("/p1");
  mc+cgal                          our marching cubes + CGAL edge_collapse (Garland-Heckbert),
  fe3d+vtkqd                       FlyingEdges3D + vtkQuadricDecimation, both asked for
                                   tandem-lag's triangle count (default slabs).
Per output, against our full-resolution marching-cubes surface (`tandem measure full.ply out.ply
--json`): RMS (L2, the larger of the two directions), the Hausdorff distance (undirected) and
the one-sided Hausdorff distance from the full surface to the output (measure's "forward",
A → B: the largest distance of a point of the full surface, a thin feature's loss, from the
output); mesh_check (manifold, Euler characteristic and components compared with the full
surface's, zero-area triangles); for ours Error(K) <= E0 from the metrics (error_max) and the
refusal counts.

The report's "Bounds" section holds tandem-lag (default slabs) to issue 66's bounds at every
point (count ≤ 1.15× classical's at the same E0, RMS and one-sided Hausdorff ≤ 1.1× CGAL GH's
at the same count, Error(K) ≤ E0, topology kept): per bound and group of inputs the points
within, the geometric mean and the worst point.

The report (SWEEP.md) keeps the hand-written text between the markers
<!-- notes --> and <!-- /notes --> of the existing file.

Exit status: 0 when every run produced its output, 1 otherwise (the sweep goes on after a
failure and reports it). A check that fails (non-manifold, Euler characteristic, Error(K))
is reported, not failed: these are the targets the issue measures.
"""

import argparse
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench  # noqa: E402  (the launcher, run_tool, machine info, formats)
from bench import fmt, log, ratio  # noqa: E402

HERE = bench.HERE
OURS = ["classical", "tandem", "tandem-lag"]
PEERS = {"mc+cgal": "peer_mc_cgal", "fe3d+vtkqd": "peer_vtk"}
REFERENCE = "tandem-lag"  # the peers are asked for its triangle count (default slabs)
MID, LARGE = 300_000, 1_000_000  # full-resolution triangles: --points-mid, --points-large
PROBE_FACTOR = 30.0
ONE_SLAB_BELOW = 81  # grids narrower than this get one slab by default: "/p1" is the same run
LEAN = ("classical", "tandem-lag", "mc+cgal")  # --lean: what the bounds need, default slabs


def variants():
    """(label, schedule, parts) of our runs: default slabs, then one slab."""
    out = []
    for s in OURS:
        out.append((s, s, None))
        out.append((s + "/p1", s, 1))
    return out


def generated(args, tandem_bin, name):
    """A generated volume (SHAPE-N), made in SCRATCH/volumes unless it is there already."""
    shape, n = name.rsplit("-", 1)
    n = int(n)
    path = os.path.join(args.scratch, "volumes", f"{name}.json")
    if not os.path.exists(path) or bench.load_sidecar(path).get("dims") != [n, n, n]:
        log(f"generating {name} -> {path}")
        bench.run_tool([tandem_bin, "generate", shape, "--size", str(n), "--out", path])
    meta = bench.load_sidecar(path)
    return bench.Input(name, path, 0.0, meta.get("spacing", [1, 1, 1]), meta["dims"],
                       meta["dtype"], "synthetic")


# Fields not made with the paper's formulas (field_volume, fields_lib.h).
FIELDS = ["roundcube-field", "pillowbox-sdf", "link-sdf", "sphere-sdf", "pillowbox-mask",
          "link-mask", "sphere-mask", "pillowbox-ct", "link-ct", "sphere-ct"]
QUICK_FIELDS = {"pillowbox-sdf-64": [0.2, 0.64]}  # the default E0 and ~1 %: no search
GROUPS = {"generated": "synthetic", "fields": "field", "shared": "shared"}


def selected(args, name, kind):
    """Whether --inputs / --only (name parts or group names) selects this input."""
    if not args.only:
        return True
    return any(o == name or (o in GROUPS and GROUPS[o] == kind) or
               (o not in GROUPS and o in name) for o in args.only)


def field(args, field_bin, name):
    """A field_volume volume (SHAPE-KIND-N), made in SCRATCH/volumes unless it is there."""
    shape, kind, n = name.rsplit("-", 2)
    path = os.path.join(args.scratch, "volumes", f"{name}.json")
    meta = bench.load_sidecar(path) if os.path.exists(path) else {}
    if meta.get("source") != "tests/bench/field_volume" or meta.get("dims") != [int(n)] * 3:
        log(f"generating {name} -> {path}")
        bench.run_tool([field_bin, shape, kind, "--size", n, "--out", path])
        meta = bench.load_sidecar(path)
    return bench.Input(name, path, float(meta["suggested_isovalues"][0]),
                       meta.get("spacing", [1, 1, 1]), meta["dims"], meta["dtype"], "field")


def make_inputs(args, bins):
    inputs = []
    synth = ["pillowbox-64"] if args.quick else ["pillowbox-256", "link-256"]
    os.makedirs(os.path.join(args.scratch, "volumes"), exist_ok=True)
    for name in synth:
        if selected(args, name, "synthetic"):
            inputs.append(generated(args, bins["tandem"], name))
    for name in QUICK_FIELDS if args.quick else [f"{f}-{args.field_size}" for f in FIELDS]:
        if not selected(args, name, "field"):
            continue
        if "field_volume" not in bins:
            log(f"SKIP {name}: field_volume not built")
            continue
        inputs.append(field(args, bins["field_volume"], name))
    if args.quick:
        return inputs
    shared_inputs(args, inputs)
    # The 512³ inputs last: the most expensive, and a partial run keeps what came before.
    for name in ("pillowbox-512", "link-512"):
        if selected(args, name, "synthetic"):
            inputs.append(generated(args, bins["tandem"], name))
    return inputs


def shared_inputs(args, inputs):
    if not os.path.isdir(args.data):
        log(f"SKIP shared volumes: {args.data} is absent")
        return
    for fn in sorted(os.listdir(args.data)):
        if not fn.endswith(".json"):
            continue
        name = fn[:-5]
        if not selected(args, name, "shared"):
            continue
        meta = bench.load_sidecar(os.path.join(args.data, fn))
        raw = os.path.join(args.data, meta.get("raw_file", name + ".raw"))
        if not os.path.exists(raw):
            log(f"SKIP {fn}: its raw file {raw} is absent")
            continue
        inputs.append(bench.Input(name, os.path.join(args.data, fn),
                                  float(meta["suggested_isovalues"][0]),
                                  meta.get("spacing", [1, 1, 1]), meta["dims"], meta["dtype"],
                                  "shared"))


def ours_cmd(bins, inp, schedule, parts, e0, out):
    cmd = [bins["tandem"], "extract", "--input", inp.path, "--iso", repr(inp.iso),
           "--out", out, "--metrics", out + ".metrics.json", "--quiet"]
    if schedule == "none":
        return cmd + ["--no-simplify"]
    cmd += ["--error", repr(e0), "--schedule", schedule]
    if parts is not None:
        cmd += ["--parts", str(parts)]
    return cmd


def peer_cmd(bins, inp, name, target, out):
    if name == "fe3d+vtkqd":
        return [bins["peer_vtk"], "--input", inp.path, "--iso", repr(inp.iso), "--simplify",
                "vtkqd", "--target-triangles", str(target), "--out", out]
    return [bins["peer_mc_cgal"], "--input", inp.path, "--iso", repr(inp.iso),
            "--target-triangles", str(target), "--out", out]


def parse_ours(out):
    m = bench.load_sidecar(out + ".metrics.json")
    keep = {"triangles": m["triangles_final"], "triangles_extracted": m["triangles_extracted"],
            "error_max": m["error_max"], "peak_triangles": m.get("peak_triangles")}
    for k in ("refusals", "contractions", "max_reach_over_front", "max_layer_over_front"):
        if k in m:
            keep[k] = m[k]
    return keep


def parse_peer(stdout_path):
    with open(stdout_path) as f:
        lines = [l for l in f.read().splitlines() if l.startswith("{")]
    if not lines:
        raise RuntimeError("no result line on stdout")
    r = json.loads(lines[-1])
    return {"triangles": r["triangles_final"], "triangles_extracted": r["triangles_extracted"]}


def measure(bins, full, out):
    """Distance to the full-resolution surface and topology of one output."""
    d = json.loads(bench.run_tool([bins["tandem"], "measure", full, out, "--json"]))["distance"]
    t = json.loads(bench.run_tool([bins["mesh_check"], out]))
    # forward = A -> B = from the full-resolution surface to the output (what a thin feature loses).
    return {"rms": d["L2"]["max"], "hausdorff": d["Linf"]["max"],
            "hausdorff_1s": d["Linf"]["forward"],
            "topology": {k: t[k] for k in ("manifold", "euler", "components", "boundary_edges",
                                           "nonmanifold_edges", "degenerate_triangles",
                                           "zero_area_triangles")}}


def run_one(label, cmd, out, work, bins, parse, failures):
    """One measured run; returns its result dict or None (failure recorded)."""
    for stale in (out, out + ".metrics.json"):
        if os.path.exists(stale):
            os.remove(stale)
    stem = os.path.join(work, label.replace("/", "_").replace("+", "_"))
    so, se = stem + ".stdout", stem + ".stderr"
    r, problem = bench.run_checked(label, cmd, out, so, se, bins["bench_run"],
                                   lambda: parse(so), failures)
    if problem is not None:
        return None
    return {k: r[k] for k in r if k not in ("rc",)}


def e0_points(args, bins, inp, e0_10, kept_10, n_full, work, failures):
    """The sweep's E0 values: geometric from E0(10 %) to the estimated ~0.1 % point."""
    n = args.points
    first = 0.0  # the first point, as a fraction of the span's logarithm
    if args.quick:
        n = 3
    elif n_full > LARGE:
        # Only the coarse half (~1 % to ~0.1 %): the 10 % point is the main benchmark's
        # (REPORT.md), and a point of these inputs costs minutes of CGAL and VTK.
        n, first = args.points_large, 0.5
    elif n_full > MID:
        n = args.points_mid
    probe_e0 = float(f"{e0_10 * PROBE_FACTOR:.2g}")
    out = os.path.join(work, "probe.ply")
    r = run_one(f"{inp.name} / probe", ours_cmd(bins, inp, "tandem-lag", 1, probe_e0, out), out,
                work, bins, lambda so: parse_ours(out), failures)
    span = 100.0  # kept ∝ 1/E0 when the probe says nothing
    probe = None
    if r is not None:
        f_probe = r["triangles"] / max(1, n_full)
        probe = {"e0": probe_e0, "kept": f_probe}
        if 0 < f_probe < kept_10:
            p = math.log(kept_10 / f_probe) / math.log(probe_e0 / e0_10)
            span = (kept_10 / 0.001) ** (1.0 / p)
        span = min(max(span, 5.0), 1000.0)
        os.remove(out)
    es = [float(f"{e0_10 * span ** (first + (1 - first) * i / max(1, n - 1)):.3g}")
          for i in range(n)]
    return es, probe


def fraction_points(args, bins, inp, e0_entry, n_full, work, failures):
    """[(E0, goal)]: for each goal fraction (fields: also 10 %), the E0 at which tandem-lag
    (default slabs) keeps it within 15 %, by a secant search on log E0 against log kept; the
    fields also at the default E0. Stops at a floor (the count no longer falls)."""
    unit = min(inp.spacing)
    cache = {}  # E0 -> kept fraction (None: the run failed)

    def kept(e0):
        e0 = float(f"{e0:.3g}")
        if e0 not in cache:
            out = os.path.join(work, "search.ply")
            r = run_one(f"{inp.name} / search E0 {e0:g}",
                        ours_cmd(bins, inp, REFERENCE, None, e0, out), out, work, bins,
                        lambda so: parse_ours(out), failures)
            cache[e0] = None if r is None else r["triangles"] / max(1, n_full)
        return e0, cache[e0]

    def guess(goal):
        known = sorted(((e, f) for e, f in cache.items() if f), key=lambda k: abs(math.log(k[1] / goal)))
        if e0_entry and not known:
            known = [(e0_entry["e0"], e0_entry["kept"])]
        if not known:
            return 0.2 * unit
        e_a, f_a = known[0]
        p = 1.0  # kept ∝ 1/E0 on a smooth surface (triangles ∝ 1/h², error ∝ h²)
        for e_b, f_b in known[1:]:
            if e_b != e_a and f_b != f_a:
                p = max(0.2, -math.log(f_b / f_a) / math.log(e_b / e_a))
                break
        return e_a * min(30.0, max(1 / 30.0, (f_a / goal) ** (1 / p)))

    goals = ([0.10] if inp.kind == "field" else []) + list(args.fractions)
    points = []
    for goal in goals:
        e0 = guess(goal)
        for _ in range(5):
            e0, f = kept(e0)
            if f is None or abs(math.log(f / goal)) <= math.log(1.15):
                break
            nxt = float(f"{guess(goal):.3g}")
            if nxt in cache:
                break
            e0 = nxt
        tried = [(e, f) for e, f in cache.items() if f]
        if not tried:
            break
        e0, f = min(tried, key=lambda k: abs(math.log(k[1] / goal)))
        if all(e != e0 for e, _ in points):
            points.append((e0, f"{100 * goal:g} %"))
        if f > 1.5 * goal:
            log(f"  {inp.name}: tandem-lag keeps {100 * f:.2f} % at best, not {100 * goal:g} % "
                "(a floor): no coarser goal")
            break
    default = float(f"{0.2 * unit:.3g}")
    if inp.kind == "field" and all(abs(math.log(e / default)) > 0.05 for e, _ in points):
        points.append((default, "default E0"))
    return sorted(points), {"searched": sorted([e, f] for e, f in cache.items() if f)}


def sweep_input(inp, e0_entry, args, bins, failures):
    work = os.path.join(args.scratch, "sweep", inp.name)
    os.makedirs(work, exist_ok=True)
    res = {"name": inp.name, "kind": inp.kind, "grid": inp.grid, "dtype": inp.dtype,
           "iso": inp.iso, "spacing": inp.spacing,
           "e0_10": e0_entry["e0"] if e0_entry else None, "points": []}
    full = os.path.join(work, "full.ply")
    r = run_one(f"{inp.name} / mc-only", ours_cmd(bins, inp, "none", None, 0, full), full, work,
                bins, lambda so: parse_ours(full), failures)
    if r is None:
        res["failed"] = "full-resolution extraction failed"
        return res
    t = json.loads(bench.run_tool([bins["mesh_check"], full]))
    res["full"] = {"triangles": r["triangles"], "wall_s": r["wall_s"],
                   "euler": t["euler"], "components": t["components"],
                   "manifold": t["manifold"]}
    n_full = r["triangles"]
    log(f"{inp.name}: {n_full:,} triangles at full resolution, χ = {t['euler']}, "
        f"{t['components']} components; E0(10 %) = "
        + (f"{e0_entry['e0']:g}" if e0_entry else "to be searched"))
    if inp.name in args.e0_from:
        es = [(p["e0"], p.get("goal")) for p in args.e0_from[inp.name]]
    elif args.quick and inp.kind == "field":
        es = [(e, None) for e in QUICK_FIELDS[inp.name]]
    elif args.quick or inp.kind == "synthetic":
        es, res["probe"] = e0_points(args, bins, inp, e0_entry["e0"], e0_entry["kept"], n_full,
                                     work, failures)
        es = [(e, None) for e in es]
    else:
        es, res["search"] = fraction_points(args, bins, inp, e0_entry, n_full, work, failures)
    if res["e0_10"] is None:
        res["e0_10"] = next((e for e, g in es if g == "10 %"), None)
    log(f"  E0 values: {', '.join(f'{e:g}' + (f' ({g})' if g else '') for e, g in es)}")
    for e0, goal in es:
        pt = {"e0": e0, "goal": goal, "runs": {}}
        def run(name, cmd, out, parse):
            label = f"{inp.name} / E0 {e0:g} / {name}"
            r = run_one(label, cmd, out, work, bins, parse, failures)
            if r is not None:
                r.update(measure_or_fail(bins, full, out, label, failures))
            pt["runs"][name] = r or {"failed": True}

        for label, sched, parts in variants():
            if args.lean and (sched not in LEAN or parts is not None):
                continue
            if parts == 1 and inp.grid[0] < ONE_SLAB_BELOW and sched in pt["runs"]:
                pt["runs"][label] = dict(pt["runs"][sched], same_as=sched)  # the same run
                continue
            out = os.path.join(work, label.replace("/", "_") + ".ply")
            run(label, ours_cmd(bins, inp, sched, parts, e0, out), out,
                lambda so, out=out: parse_ours(out))
        target = pt["runs"].get(REFERENCE, {}).get("triangles")
        for name, prog in PEERS.items():
            if args.lean and name not in LEAN:
                continue
            if prog not in bins:
                pt["runs"][name] = {"skipped": f"{prog} not built"}
            elif target is None:
                pt["runs"][name] = {"failed": True}
            else:
                out = os.path.join(work, name.replace("+", "_") + ".ply")
                run(name, peer_cmd(bins, inp, name, target, out), out, parse_peer)
        res["points"].append(pt)
        line = "  ".join(f"{k} {v['triangles']:,}/{fmt(v.get('rms'))}"
                         for k, v in pt["runs"].items() if "triangles" in v)
        log(f"  E0 {e0:g}: {line}")
        if not args.keep:
            for fn in os.listdir(work):
                if (fn.endswith(".ply") or fn.endswith(".metrics.json")) and fn != "full.ply":
                    os.remove(os.path.join(work, fn))
        counts = [p["runs"].get(REFERENCE, {}).get("triangles") for p in res["points"][-2:]]
        apart = len(res["points"]) >= 2 and e0 >= 1.5 * res["points"][-2]["e0"]
        if apart and None not in counts and counts[1] >= 0.97 * counts[0]:
            # The count stopped falling (the topology floor of a CT with many small
            # components): coarser E0 values only repeat this point.
            res["floor"] = counts[1]
            log(f"  tandem-lag's count stopped falling ({counts[0]:,} -> {counts[1]:,}): "
                "no coarser E0")
            break
    if not args.keep:
        os.remove(full)
    return res


def measure_or_fail(bins, full, out, label, failures):
    try:
        return measure(bins, full, out)
    except (RuntimeError, ValueError, KeyError) as e:
        msg = f"{label}: measuring the output failed: {e}"
        log("FAILED " + msg)
        failures.append(msg)
        return {"measure_failed": True}


# ----------------------------------------------------------------------------------------
# Checks, ratios, plots, report.

def checks(res, run):
    """The problems of one of our outputs (or a peer's): topology against the full surface,
    Error(K) <= E0 (ours)."""
    problems = []
    t = run.get("topology")
    full = res.get("full", {})
    if t:
        if not t["manifold"]:
            problems.append(f"non-manifold ({t['nonmanifold_edges']} edges)")
        if t["euler"] != full.get("euler"):
            problems.append(f"χ {t['euler']} (full {full.get('euler')})")
        if t["components"] != full.get("components"):
            problems.append(f"{t['components']} components (full {full.get('components')})")
    return problems


def error_ok(run, e0):
    em = run.get("error_max")
    return None if em is None else em <= e0 * (1 + 1e-9)


def point_ratios(pt):
    runs = pt["runs"]

    def get(name, key):
        return runs.get(name, {}).get(key)
    return {
        "lag_cgal_rms": ratio(get("tandem-lag", "rms"), get("mc+cgal", "rms")),
        "lag_vtkqd_rms": ratio(get("tandem-lag", "rms"), get("fe3d+vtkqd", "rms")),
        "lag_cgal_hausdorff": ratio(get("tandem-lag", "hausdorff"), get("mc+cgal", "hausdorff")),
        "lag_cgal_hausdorff_1s": ratio(get("tandem-lag", "hausdorff_1s"),
                                       get("mc+cgal", "hausdorff_1s")),
        "lag_classical_count": ratio(get("tandem-lag", "triangles"), get("classical", "triangles")),
        "lag_classical_count_p1": ratio(get("tandem-lag/p1", "triangles"),
                                        get("classical/p1", "triangles")),
    }


# Issue 66's bounds at every point, on tandem-lag with the default slabs: (key, what, limit).
BOUNDS = [("lag_classical_count", "count / classical's at the same E0", 1.15),
          ("lag_cgal_rms", "RMS / CGAL GH's at the same count", 1.1),
          ("lag_cgal_hausdorff_1s", "one-sided Hausdorff (full → output) / CGAL GH's", 1.1)]
GROUP_NAMES = [("all", None), ("fields", "field"), ("shared scans", "shared"),
               ("generated", "synthetic")]


def point_problems(res, pt):
    """What tandem-lag's output at this point fails of Error(K) <= E0 and the topology."""
    run = pt["runs"].get(REFERENCE, {})
    if "triangles" not in run:
        return None
    p = checks(res, run)
    if error_ok(run, pt["e0"]) is False:
        p.append(f"Error(K) {run['error_max']:.4g} > E0")
    return p


def bounds_section(results):
    """Each bound per group of inputs: points within, geometric mean, worst point, the points
    outside; then Error(K) <= E0 and the topology of tandem-lag's outputs."""
    L = ["## Bounds (issue 66)", "",
         "tandem-lag with the default slabs at every point, per group of inputs: points within "
         "the bound, the ratio's geometric mean and worst point, and every point outside (input, "
         "E0, ratio).", "",
         "| bound | limit | inputs | points within | geometric mean | worst point | outside |",
         "|---|---:|---|---:|---:|---|---|"]
    for key, what, limit in BOUNDS:
        for group, kind in GROUP_NAMES:
            pts = [(point_ratios(pt)[key], res["name"], pt["e0"]) for res in results
                   if kind is None or res["kind"] == kind for pt in res.get("points", [])]
            pts = [p for p in pts if p[0] is not None]
            if not pts:
                continue
            worst = max(pts)
            # Three decimals where two would round onto the limit.
            out = [f"{n} E0 {e:g}: {x:.{2 if round(x, 2) > limit else 3}f}"
                   for x, n, e in pts if x > limit]
            L.append(f"| {what} | {limit:g} | {group} | {len(pts) - len(out)} of {len(pts)} | "
                     f"{fmt(geomean([x for x, _, _ in pts]), '.2f')} | {worst[1]} E0 "
                     f"{worst[2]:g}: {worst[0]:.2f} | {'; '.join(out) or 'none'} |")
    bad, n = [], 0
    for res in results:
        for pt in res.get("points", []):
            p = point_problems(res, pt)
            if p is None:
                continue
            n += 1
            if p:
                bad.append(f"{res['name']} E0 {pt['e0']:g}: {'; '.join(p)}")
    L += ["", f"Error(K) ≤ E0, manifold, χ and components kept (tandem-lag): "
          f"{n - len(bad)} of {n} points" + (" — outside: " + "; ".join(bad) if bad else "."), ""]
    return L


def plot(res, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("SKIP plots: matplotlib is not installed for this python")
        return False
    styles = {"classical": ("tab:blue", "-", "o"), "tandem": ("tab:orange", "-", "s"),
              "tandem-lag": ("tab:red", "-", "D"), "classical/p1": ("tab:blue", "--", "o"),
              "tandem/p1": ("tab:orange", "--", "s"), "tandem-lag/p1": ("tab:red", "--", "D"),
              "mc+cgal": ("black", "-", "x"), "fe3d+vtkqd": ("tab:green", "-", "+")}
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for name, (color, ls, marker) in styles.items():
        xs, ys = [], []
        for pt in res["points"]:
            r = pt["runs"].get(name, {})
            if r.get("rms") is not None and r.get("triangles"):
                xs.append(r["triangles"])
                ys.append(r["rms"])
        if xs:
            label = name.replace("/p1", " (--parts 1)")
            if name in PEERS:
                label += " (at tandem-lag's count)"
            ax.plot(xs, ys, color=color, linestyle=ls, marker=marker, label=label, lw=1.2, ms=5,
                    fillstyle="none" if "/p1" in name else "full")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles")
    ax.set_ylabel("RMS distance to the full-resolution surface")
    full = res.get("full", {}).get("triangles")
    ax.set_title(f"{res['name']} ({full:,} triangles at full resolution)" if full else res["name"])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def geomean(xs):
    xs = [x for x in xs if x is not None and x > 0]
    return math.exp(sum(math.log(x) for x in xs) / len(xs)) if xs else None


def write_report(path, results, meta, plots):
    notes = bench.read_notes(path) or (bench.NOTES_BEGIN + "\n(no notes yet)\n" + bench.NOTES_END)
    m = meta["machine"]
    L = ["# The reduction sweep (issues 24 and 66)", "",
         "Generated by `bash tests/bench/run.sh --sweep` (tests/bench/sweep.py; results in "
         "sweep.json beside this file). The text between the notes markers is hand-written and "
         "kept when the report is regenerated.", "",
         f"Machine: {m['cpu']}, {m['cores']} cores (shared), {m['memory']}; commit {m['commit']}; "
         f"{m['date']}; load average at start {', '.join(f'{x:.1f}' for x in m['load_average_at_start'])}; "
         f"{meta['elapsed_s'] / 60:.0f} min. Mode: {meta['mode']}. One run per point (timings "
         "are indicative only: other jobs shared the machine). Engine: "
         f"`{meta.get('tandem', 'BIN/tandem')}`"
         + (f"; E0 values from {meta['e0_from']}" if meta.get("e0_from") else "") + ".", "",
         "Every E0 row: " + ("classical and tandem-lag with the default slabs (--lean), "
                             if "--lean" in meta["mode"] else
                             "our three schedules with the default slabs (4 on grids at least 256 "
                             "wide, 2 on grids at least 81 wide, else 1) and with `--parts 1` "
                             "(/p1); ")
         + "CGAL Garland–Heckbert (mc+cgal) "
         + ("" if "--lean" in meta["mode"] else "and vtkQuadricDecimation (fe3d+vtkqd) ")
         + "asked for tandem-lag's count (default slabs). RMS and "
         "Hausdorff (undirected, and one-sided from the full surface to the output): `tandem "
         "measure full.ply out.ply` against our full-resolution marching-cubes surface. Fields "
         "and shared scans: E0 values found for a kept fraction (in brackets) or the default "
         "E0.", "",
         notes, ""]
    # Summary of the key ratios.
    L += ["## Key ratios per point", "",
          "lag/CGAL RMS = tandem-lag RMS / CGAL GH RMS at the same triangle count (target ≤ 1.1); "
          "lag/vtkqd RMS likewise (target < 1); lag/classical count = tandem-lag triangles / "
          "classical triangles at the same E0 (target ≤ 1.15), default slabs and --parts 1.", "",
          "| input | E0 | kept (lag) | lag/CGAL RMS | lag/CGAL Hausdorff | "
          "lag/CGAL one-sided Hausdorff | lag/vtkqd RMS | lag/classical count | same, --parts 1 | "
          "Error(K), topology |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    allr = {k: [] for k in ("lag_cgal_rms", "lag_vtkqd_rms", "lag_classical_count",
                            "lag_classical_count_p1", "lag_cgal_hausdorff",
                            "lag_cgal_hausdorff_1s")}
    for res in results:
        nf = res.get("full", {}).get("triangles")
        for pt in res.get("points", []):
            q = point_ratios(pt)
            for k in allr:
                allr[k].append(q[k])
            lag = pt["runs"].get("tandem-lag", {}).get("triangles")
            kept = f"{100 * lag / nf:.2f} %" if lag and nf else "–"

            def b(x, lim):
                s = fmt(x, ".2f")
                return f"**{s}**" if x is not None and x > lim else s
            probs = point_problems(res, pt)
            e0 = f"{pt['e0']:g}" + (f" ({pt['goal']})" if pt.get("goal") else "")
            L.append(f"| {res['name']} | {e0} | {kept} | {b(q['lag_cgal_rms'], 1.1)} | "
                     f"{fmt(q['lag_cgal_hausdorff'], '.2f')} | "
                     f"{b(q['lag_cgal_hausdorff_1s'], 1.1)} | {b(q['lag_vtkqd_rms'], 1.0)} | "
                     f"{b(q['lag_classical_count'], 1.15)} | {b(q['lag_classical_count_p1'], 1.15)} | "
                     + ("–" if probs is None else "**" + "; ".join(probs) + "**" if probs else "ok")
                     + " |")
    L += ["", "Bold: outside the issue's target. Geometric means over all points: "
          f"lag/CGAL RMS {fmt(geomean(allr['lag_cgal_rms']), '.2f')}, "
          f"lag/vtkqd RMS {fmt(geomean(allr['lag_vtkqd_rms']), '.2f')}, "
          f"lag/classical count {fmt(geomean(allr['lag_classical_count']), '.2f')} "
          f"(--parts 1: {fmt(geomean(allr['lag_classical_count_p1']), '.2f')}); worst: "
          f"lag/CGAL RMS {fmt(max([x for x in allr['lag_cgal_rms'] if x] or [None], key=lambda x: x or 0), '.2f')}, "
          f"lag/classical count {fmt(max([x for x in allr['lag_classical_count'] if x] or [None], key=lambda x: x or 0), '.2f')}.",
          ""]
    L += bounds_section(results)
    # Checks.
    L += ["## Checks", "",
          "Each output against the full-resolution surface: manifold, the same Euler "
          "characteristic χ and number of components; ours also Error(K) = max ε0 ≤ E0 "
          "(error_max in the metrics). Zero-area triangles are counted (issue 24, item 5): "
          "mesh_check's zero_area_triangles (twice the area at most 2e-6 of the squared edges, "
          "as written in the PLY) and degenerate_triangles (a repeated index).", ""]
    bad, zero, uncounted = [], [], 0
    for res in results:
        for pt in res.get("points", []):
            for name, run in pt["runs"].items():
                if "triangles" not in run:
                    continue
                p = checks(res, run)
                ok = error_ok(run, pt["e0"])
                if ok is False:
                    p.append(f"Error(K) {run['error_max']:.4g} > E0")
                if p:
                    bad.append(f"- {res['name']} E0 {pt['e0']:g} {name}: {'; '.join(p)}")
                # mesh_check's degenerate_triangles are repeated indices; zero_area_triangles
                # have three corners and no area as written.
                topo = run.get("topology", {})
                if "zero_area_triangles" not in topo:
                    uncounted += 1
                z = topo.get("zero_area_triangles", 0) + topo.get("degenerate_triangles", 0)
                if z:
                    zero.append((res["name"], pt["e0"], name, z))
    L += (bad or ["- every output passed."]) + [""]
    if uncounted:
        L += [f"Zero-area triangles were not counted in {uncounted} outputs (measured before "
              "mesh_check counted them: its degenerate_triangles are repeated indices).", ""]
    if zero:
        ours_z = [z for z in zero if z[2] not in PEERS]
        L += [f"Zero-area triangles: {len(zero)} outputs hold some ({len(ours_z)} of them ours); "
              "ours: " + (", ".join(f"{n} E0 {e:g} {p}: {z}" for n, e, p, z in ours_z[:40])
                          or "none") + ("…" if len(ours_z) > 40 else ""), ""]
    else:
        L += ["Zero-area triangles: none in any output.", ""]
    # Per input.
    L += ["## Per input", ""]
    cols = [v[0] for v in variants()] + list(PEERS)
    for res in results:
        L += [f"### {res['name']}", ""]
        if res.get("failed"):
            L += [f"**FAILED**: {res['failed']}", ""]
            continue
        f = res["full"]
        g = res["grid"]
        pr = res.get("probe")
        L += [f"{g[0]}×{g[1]}×{g[2]} {res['dtype']}, spacing {', '.join(f'{s:g}' for s in res['spacing'])}, "
              f"iso {res['iso']:g}; full resolution {f['triangles']:,} triangles, χ = {f['euler']}, "
              f"{f['components']} components. E0(10 %) = {fmt(res['e0_10'], 'g')}"
              + (f"; probe: E0 {pr['e0']:g} keeps {100 * pr['kept']:.2f} % (tandem-lag, --parts 1)." if pr else "."),
              ""]
        if res["name"] in plots:
            L += [f"![RMS against triangle count, {res['name']}]({plots[res['name']]})", ""]
        L += ["Triangles:", "", "| E0 | " + " | ".join(cols) + " |",
              "|---:|" + "---:|" * len(cols)]
        for pt in res["points"]:
            L.append(f"| {pt['e0']:g} | " + " | ".join(
                f"{pt['runs'][c]['triangles']:,}" if "triangles" in pt["runs"].get(c, {}) else "–"
                for c in cols) + " |")
        L += ["", "RMS / Hausdorff / one-sided Hausdorff (full → output):", "",
              "| E0 | " + " | ".join(cols) + " |",
              "|---:|" + "---:|" * len(cols)]
        for pt in res["points"]:
            cells = []
            for c in cols:
                r = pt["runs"].get(c, {})
                cells.append(f"{fmt(r.get('rms'))} / {fmt(r.get('hausdorff'))} / "
                             f"{fmt(r.get('hausdorff_1s'))}" if "rms" in r else "–")
            L.append(f"| {pt['e0']:g} | " + " | ".join(cells) + " |")
        L += ["", "Wall time s (one run, shared machine):", "", "| E0 | " + " | ".join(cols) + " |",
              "|---:|" + "---:|" * len(cols)]
        for pt in res["points"]:
            L.append(f"| {pt['e0']:g} | " + " | ".join(
                fmt(pt["runs"].get(c, {}).get("wall_s")) for c in cols) + " |")
        L += ["", "Refusals of tandem-lag/p1 and classical/p1 (link / flip / degenerate / box / "
              "error / distance) and contractions:", "",
              "| E0 | tandem-lag/p1 | classical/p1 |", "|---:|---|---|"]
        for pt in res["points"]:
            cells = []
            for c in ("tandem-lag/p1", "classical/p1"):
                r = pt["runs"].get(c, {})
                rf = r.get("refusals")
                if isinstance(rf, dict):
                    cells.append(" / ".join(str(rf.get(k, "–")) for k in
                                            ("link", "flip", "degenerate", "box", "error", "distance"))
                                 + f"; {r.get('contractions', '–')}")
                else:
                    cells.append("–")
            L.append(f"| {pt['e0']:g} | " + " | ".join(cells) + " |")
        L.append("")
    if meta["failures"]:
        L += ["## Failed runs", ""] + [f"- {x.splitlines()[0]}" for x in meta["failures"]] + [""]
    with open(path, "w") as fobj:
        fobj.write("\n".join(L))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    bench.add_common_args(ap, "SWEEP.md", "sweep.json")
    ap.add_argument("--quick", action="store_true",
                    help="pillowbox-64 at 3 E0 values, " + ", ".join(QUICK_FIELDS) + " at 2")
    ap.add_argument("--inputs", action="append", default=[],
                    help="comma-separated name parts or groups (generated, fields, shared); "
                    "the same as --only")
    ap.add_argument("--lean", action="store_true",
                    help="only " + ", ".join(LEAN) + " (default slabs): the bounds' runs")
    ap.add_argument("--tandem", help="the tandem binary under test (default: BIN/tandem)")
    ap.add_argument("--e0-from", metavar="RESULTS",
                    help="take each input's E0 values from this earlier sweep.json")
    ap.add_argument("--field-size", type=int, default=128,
                    help="the grid of the fields not made with the paper's formulas (default 128)")
    ap.add_argument("--fractions", default="0.01,0.003,0.001",
                    help="kept fractions the fields and shared scans are swept at "
                    "(default 0.01,0.003,0.001)")
    ap.add_argument("--points", type=int, default=7, help="E0 values per input (default 7)")
    ap.add_argument("--points-mid", type=int, default=5,
                    help=f"E0 values for inputs over {MID:,} triangles (default 5)")
    ap.add_argument("--points-large", type=int, default=2,
                    help=f"E0 values for inputs over {LARGE:,} triangles, from ~1 %% to ~0.1 %% "
                    "(default 2)")
    args = ap.parse_args()
    args.only = [o for x in (args.only or []) + args.inputs for o in x.split(",") if o] or None
    args.fractions = [float(x) for x in args.fractions.split(",") if x]
    e0_from, args.e0_from = args.e0_from, {}
    if e0_from:
        args.e0_from = {r["name"]: r["points"] for r in bench.load_sidecar(e0_from)["inputs"]
                        if r.get("points")}
    paths = bench.report_paths(args, ap, "SWEEP.md", "sweep.json", lambda report, saved: write_report(
        report, saved["inputs"], saved["meta"], make_plots(saved["inputs"], os.path.dirname(report))))
    if paths is None:
        return
    report, results_json = paths
    os.makedirs(args.scratch, exist_ok=True)
    bins = bench.find_programs(args.bin, ("tandem", "bench_run", "mesh_check", "peer_vtk",
                                          "peer_mc_cgal", "field_volume"), "sweep")
    if args.tandem:
        if not os.access(args.tandem, os.X_OK):
            sys.exit(f"sweep: --tandem {args.tandem} is not an executable")
        bins["tandem"] = os.path.abspath(args.tandem)
    for name, prog in PEERS.items():
        if prog not in bins:
            log(f"SKIP {name}: {prog} not built (bash tests/bench/install-peers.sh)")
    t0 = time.perf_counter()
    e0_table = bench.load_e0_table()
    failures, results = [], []
    meta = {"machine": bench.machine_info(), "packages": bench.package_versions(),
            "mode": ("quick" if args.quick else "full")
            + (" --lean (" + ", ".join(LEAN) + "; default slabs only)" if args.lean else ""),
            "failures": failures,
            "tandem": bins["tandem"], "e0_from": e0_from}
    for inp in make_inputs(args, bins):
        entry = e0_table.get(inp.name)
        if entry is None and inp.kind == "synthetic":
            log(f"searching E0 for {inp.name} (tandem-lag keeping ~10%)")
            entry = bench.calibrate_e0(bins["tandem"], inp, args.scratch)
        results.append(sweep_input(inp, entry, args, bins, failures))
        meta["elapsed_s"] = time.perf_counter() - t0
        with open(results_json, "w") as f:  # after every input: a partial run keeps its data
            json.dump({"meta": meta, "inputs": results}, f, indent=1)
    meta["elapsed_s"] = time.perf_counter() - t0
    plots = make_plots(results, os.path.dirname(report))
    bench.finish("sweep", report, results_json, results, meta,
                 lambda: write_report(report, results, meta, plots), lambda: None)


def make_plots(results, folder):
    plots = {}
    for res in results:
        if not res.get("points"):
            continue
        fn = f"sweep-plots/{res['name']}.png"
        os.makedirs(os.path.join(folder, "sweep-plots"), exist_ok=True)
        if plot(res, os.path.join(folder, fn)):
            plots[res["name"]] = fn
    return plots


if __name__ == "__main__":
    main()
