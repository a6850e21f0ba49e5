#!/usr/bin/env python3
"""--target-triangles N against the E0 run that gives N (issue 24, item 4).

Run it through tests/bench/run.sh (which builds the programs first):
    bash tests/bench/run.sh --target            # tests/bench/TARGET.md + target.json
    bash tests/bench/run.sh --target --quick    # pillowbox-64, one repeat, scratch directory

Inputs: the Pillow Box and the Link generated at 256³ and the shared CT/MRI volumes (the
sweep's, tests/bench/sweep.py; --quick: pillowbox-64). Per input, three E0 values: E0(10 %)
from tests/bench/e0.json (tandem-lag keeping ~10 % of the triangles), 4x and 16x it.

Per E0, each in its own process (bench.py's launcher: wall time, CPU time, peak RSS),
--repeats times (medians; peak RSS: the median too):
  e0 run       tandem extract --error E0 (tandem-lag, default slabs): N = its triangle count;
  target run   tandem extract --target-triangles N --error E0;
  wrong E0     the same with --error 100 x E0 (once): the count must not depend on it;
  mc+cgal      our marching cubes + CGAL Garland-Heckbert asked for N (once), when built.
Per output: RMS (L2) and Hausdorff distance to our full-resolution surface (`tandem measure`),
and for the target run mesh_check (manifold, Euler characteristic, components against the
full surface).

The issue's targets: the count within 1 % of N whatever E0 is; time and peak RSS at most 1.5x
the E0 run's; RMS at N at most 1.1x CGAL's. The report states each ratio with its geometric
mean and worst case; no timing is asserted. Exit status 1 when a run failed.
"""

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench  # noqa: E402
import sweep  # noqa: E402  (inputs, commands, measures)
from bench import fmt, log, ratio  # noqa: E402

HERE = bench.HERE
FACTORS = (1, 4, 16)  # E0 = factor x E0(10 %)
WRONG = 100           # the "wrong E0" run's factor


def tandem_cmd(bins, inp, e0, out, target=None):
    cmd = [bins["tandem"], "extract", "--input", inp.path, "--iso", repr(inp.iso), "--out", out,
           "--metrics", out + ".metrics.json", "--quiet", "--error", repr(e0)]
    return cmd + (["--target-triangles", str(target)] if target else [])


def repeated(label, cmd, out, work, bins, parse, failures, repeats):
    runs = []
    for i in range(repeats):
        r = sweep.run_one(f"{label} #{i + 1}", cmd, out, work, bins, parse, failures)
        if r is None:
            return None
        runs.append(r)
    best = dict(runs[0])
    for k in ("wall_s", "cpu_s", "peak_rss_bytes"):
        best[k] = statistics.median(r[k] for r in runs)
    return best


def parse_metrics(out):
    m = bench.load_sidecar(out + ".metrics.json")
    return {"triangles": m["triangles_final"], "error_max": m["error_max"],
            "error_reached": m.get("error_reached"), "peak_triangles": m.get("peak_triangles")}


def target_input(inp, e0_10, args, bins, failures):
    work = os.path.join(args.scratch, "target", inp.name)
    os.makedirs(work, exist_ok=True)
    res = {"name": inp.name, "grid": inp.grid, "e0_10": e0_10, "points": []}
    full = os.path.join(work, "full.ply")
    if sweep.run_one(f"{inp.name} / mc-only", sweep.ours_cmd(bins, inp, "none", None, 0, full),
                     full, work, bins, lambda so: parse_metrics(full), failures) is None:
        res["failed"] = "full-resolution extraction failed"
        return res
    t = json.loads(bench.run_tool([bins["mesh_check"], full]))
    res["full"] = {k: t[k] for k in ("euler", "components", "manifold")}
    for factor in ([1] if args.quick else FACTORS):
        e0 = float(f"{e0_10 * factor:.3g}")
        pt = {"e0": e0}
        out = os.path.join(work, "e0.ply")
        r = repeated(f"{inp.name} / E0 {e0:g} / e0 run", tandem_cmd(bins, inp, e0, out), out,
                     work, bins, lambda so: parse_metrics(out), failures, args.repeats)
        if r is None:
            res["points"].append(pt)
            continue
        r.update(sweep.measure_or_fail(bins, full, out, "e0 run", failures))
        pt["e0_run"] = r
        n = r["triangles"]
        out = os.path.join(work, "target.ply")
        r = repeated(f"{inp.name} / E0 {e0:g} / target {n}", tandem_cmd(bins, inp, e0, out, n),
                     out, work, bins, lambda so: parse_metrics(out), failures, args.repeats)
        if r is not None:
            r.update(sweep.measure_or_fail(bins, full, out, "target run", failures))
            pt["target_run"] = r
        out = os.path.join(work, "wrong.ply")
        r = sweep.run_one(f"{inp.name} / E0 {e0:g} / target, E0 x{WRONG}",
                          tandem_cmd(bins, inp, e0 * WRONG, out, n), out, work, bins,
                          lambda so: parse_metrics(out), failures)
        if r is not None:
            pt["wrong_e0_run"] = r
        if "peer_mc_cgal" in bins:
            out = os.path.join(work, "cgal.ply")
            r = sweep.run_one(f"{inp.name} / E0 {e0:g} / mc+cgal {n}",
                              sweep.peer_cmd(bins, inp, "mc+cgal", n, out), out, work, bins,
                              sweep.parse_peer, failures)
            if r is not None:
                r.update(sweep.measure_or_fail(bins, full, out, "mc+cgal", failures))
                pt["cgal"] = r
        q = point_ratios(pt)
        log(f"  E0 {e0:g}, N {n:,}: count/N {fmt(q['reach'], '.4f')}, time {fmt(q['time'], '.2f')}x, "
            f"RSS {fmt(q['rss'], '.2f')}x, RMS/e0 run {fmt(q['rms_e0'], '.3f')}, "
            f"RMS/CGAL {fmt(q['rms_cgal'], '.3f')}")
        res["points"].append(pt)
    if not args.keep:
        for fn in os.listdir(work):
            if fn.endswith(".ply") or fn.endswith(".metrics.json"):
                os.remove(os.path.join(work, fn))
    return res


def point_ratios(pt):
    e, t, w, c = (pt.get(k, {}) for k in ("e0_run", "target_run", "wrong_e0_run", "cgal"))
    n = e.get("triangles")
    return {
        "reach": ratio(t.get("triangles"), n), "reach_wrong": ratio(w.get("triangles"), n),
        "time": ratio(t.get("wall_s"), e.get("wall_s")),
        "rss": ratio(t.get("peak_rss_bytes"), e.get("peak_rss_bytes")),
        "peak": ratio(t.get("peak_triangles"), e.get("peak_triangles")),
        "rms_e0": ratio(t.get("rms"), e.get("rms")), "rms_cgal": ratio(t.get("rms"), c.get("rms")),
        "e0_run_rms_cgal": ratio(e.get("rms"), c.get("rms")),
        "hausdorff_e0": ratio(t.get("hausdorff"), e.get("hausdorff")),
    }


def geomean(xs):
    xs = [x for x in xs if x]
    return statistics.geometric_mean(xs) if xs else None


def write_report(path, results, meta):
    m = meta["machine"]
    L = ["# --target-triangles against the E0 run (issue 24, item 4)", "",
         "Generated by `bash tests/bench/run.sh --target` (tests/bench/target.py; results in "
         "target.json beside this file).", "",
         f"Machine: {m['cpu']}, {m['cores']} cores (shared), {m['memory']}; commit {m['commit']}; "
         f"{m['date']}; load average at start "
         f"{', '.join(f'{x:.1f}' for x in m['load_average_at_start'])}; "
         f"{meta['elapsed_s'] / 60:.0f} min; {meta['repeats']} repeat(s), medians.", "",
         "N = the triangles of `tandem extract --error E0` (tandem-lag, default slabs); the "
         "target run is `--target-triangles N --error E0`, the wrong-E0 run the same with "
         f"--error {WRONG} x E0. Ratios are target run / E0 run (time: wall; RSS: peak; peak "
         "triangles held), and RMS / Hausdorff distance to our full-resolution surface against "
         "the E0 run's and CGAL Garland–Heckbert's at N. Targets (issue 24): count within 1 % "
         "of N whatever E0, time and memory ≤ 1.5x, RMS ≤ 1.1x CGAL.", "",
         "| input | E0 | N | count/N | wrong E0: count/N | E0 reached | time | peak RSS | "
         "peak triangles | RMS / E0 run | RMS / CGAL | E0 run RMS / CGAL | Hausdorff / E0 run | "
         "topology |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    keys = ("reach", "reach_wrong", "time", "rss", "peak", "rms_e0", "rms_cgal",
            "e0_run_rms_cgal", "hausdorff_e0")
    allr = {k: [] for k in keys}
    bad = []
    for res in results:
        full = res.get("full", {})
        for pt in res.get("points", []):
            q = point_ratios(pt)
            for k in keys:
                allr[k].append(q[k])
            t = pt.get("target_run", {})
            topo = t.get("topology")
            ok = "–"
            if topo:
                problems = [p for p, bad_ in (
                    ("non-manifold", not topo["manifold"]),
                    (f"χ {topo['euler']}", topo["euler"] != full.get("euler")),
                    (f"{topo['components']} components",
                     topo["components"] != full.get("components"))) if bad_]
                ok = "; ".join(problems) or "ok"
                if problems:
                    bad.append(f"{res['name']} E0 {pt['e0']:g}: {ok}")
            n = pt.get("e0_run", {}).get("triangles")
            L.append(f"| {res['name']} | {pt['e0']:g} | {n if n is not None else '–'} | "
                     f"{fmt(q['reach'], '.4f')} | {fmt(q['reach_wrong'], '.4f')} | "
                     f"{fmt(t.get('error_reached'), '.3g')} | {fmt(q['time'], '.2f')} | "
                     f"{fmt(q['rss'], '.2f')} | {fmt(q['peak'], '.2f')} | {fmt(q['rms_e0'], '.3f')} | "
                     f"{fmt(q['rms_cgal'], '.3f')} | {fmt(q['e0_run_rms_cgal'], '.3f')} | "
                     f"{fmt(q['hausdorff_e0'], '.3f')} | {ok} |")

    def worst(k, lo=False):
        xs = [x for x in allr[k] if x]
        return (min(xs) if lo else max(xs)) if xs else None
    L += ["", "Geometric means (worst): " + "; ".join(
        f"{name} {fmt(geomean(allr[k]), '.3f')} ({fmt(worst(k, lo), '.3f')})"
        for name, k, lo in (("count/N", "reach", True), ("wrong E0 count/N", "reach_wrong", True),
                            ("time", "time", False), ("peak RSS", "rss", False),
                            ("peak triangles", "peak", False), ("RMS / E0 run", "rms_e0", False),
                            ("RMS / CGAL", "rms_cgal", False),
                            ("Hausdorff / E0 run", "hausdorff_e0", False))) + ".", ""]
    L += ["Topology of the target runs: " + ("; ".join(bad) if bad else "every output manifold, "
                                              "with the full surface's χ and components") + ".", ""]
    if meta["failures"]:
        L += ["## Failures", ""] + [f"- {f.splitlines()[0]}" for f in meta["failures"]] + [""]
    notes = bench.read_notes(path)  # the hand-written findings stay
    if notes:
        L += [notes, ""]
    with open(path, "w") as f:
        f.write("\n".join(L))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    bench.add_common_args(ap, "TARGET.md", "target.json")
    ap.add_argument("--quick", action="store_true", help="pillowbox-64, one E0, one repeat")
    ap.add_argument("--repeats", type=int, default=3, help="runs per measured point (default 3)")
    args = ap.parse_args()
    if args.quick:
        args.repeats = 1
    paths = bench.report_paths(args, ap, "TARGET.md", "target.json",
                               lambda report, saved: write_report(report, saved["inputs"],
                                                                  saved["meta"]))
    if paths is None:
        return
    report, results_json = paths
    os.makedirs(args.scratch, exist_ok=True)
    bins = bench.find_programs(args.bin, ("tandem", "bench_run", "mesh_check", "peer_mc_cgal"),
                               "target")
    if "peer_mc_cgal" not in bins:
        log("SKIP mc+cgal: peer_mc_cgal not built (bash tests/bench/install-peers.sh)")
    t0 = time.perf_counter()
    e0_table = bench.load_e0_table()
    failures, results = [], []
    meta = {"machine": bench.machine_info(), "repeats": args.repeats, "failures": failures}
    os.makedirs(os.path.join(args.scratch, "volumes"), exist_ok=True)
    inputs = [sweep.generated(args, bins["tandem"], name)
              for name in (["pillowbox-64"] if args.quick else ["pillowbox-256", "link-256"])
              if not args.only or any(o in name for o in args.only)]
    if not args.quick:
        sweep.shared_inputs(args, inputs)
    for inp in inputs:
        entry = e0_table.get(inp.name)
        if entry is None:
            log(f"searching E0 for {inp.name} (tandem-lag keeping ~10%)")
            entry = bench.calibrate_e0(bins["tandem"], inp, args.scratch)
        log(f"{inp.name}: E0(10 %) = {entry['e0']:g}")
        results.append(target_input(inp, entry["e0"], args, bins, failures))
        meta["elapsed_s"] = time.perf_counter() - t0
    meta["elapsed_s"] = time.perf_counter() - t0
    bench.finish("target", report, results_json, results, meta,
                 lambda: write_report(report, results, meta), lambda: None)


if __name__ == "__main__":
    main()
