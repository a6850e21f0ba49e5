#!/usr/bin/env python3
"""The tandem benchmark (issue 6, part 1): ours against existing extraction + simplification
pipelines, each run in a separate process that reads the volume from the same raw + JSON files.

Run it through tests/bench/run.sh (which builds the programs first):
    bash tests/bench/run.sh            # full: 128^3, 256^3, 512^3 synthetic + shared volumes,
                                       # 3 repeats, writes tests/bench/REPORT.md + results.json
    bash tests/bench/run.sh --quick    # 64^3/128^3 synthetic + the smallest shared volume,
                                       # 1 repeat, report in the scratch directory

Per run: wall time of the process (fork to exit), its CPU time (user + sys) and peak RSS
(wait4 rusage), the phase times the program itself reports, and the triangle count. Per
output (first repeat): L2 (RMS) and Hausdorff distance to our full-resolution marching-cubes
surface (`tandem measure full.ply out.ply --json`, undirected = max of both directions) and
topology (mesh_check: manifold, Euler characteristic). Medians over the repeats.

Exit status: 0 when every run that was attempted produced its output, 1 otherwise (a crash
or missing output is reported loudly and the remaining runs still go ahead). Peers whose
program was not built (library not installed) are skipped with a message, not failed.
"""

import argparse
import datetime
import json
import math
import os
import platform
import signal
import statistics
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))
E0_FILE = os.path.join(HERE, "e0.json")
RUN_TIMEOUT_S = 3600

# Pipelines in table order: name -> (program, description). "ours" = the tandem CLI.
PIPELINES = {
    "tandem-lag": ("tandem", "ours: tandem with time-lag (CLI)"),
    "tandem": ("tandem", "ours: tandem without time-lag (CLI)"),
    "classical": ("tandem", "ours: extract all, then simplify (CLI)"),
    "fe3d+meshopt": ("peer_vtk", "vtkFlyingEdges3D + meshopt_simplify (fastest existing)"),
    "fe3d+vtkqd": ("peer_vtk", "vtkFlyingEdges3D + vtkCleanPolyData + vtkQuadricDecimation"),
    "mc+meshopt": ("peer_mc_meshopt", "our marching cubes + meshopt_simplify"),
    "mc+cgal": ("peer_mc_cgal", "our marching cubes + CGAL edge_collapse, Garland-Heckbert"),
}
# Extraction alone (no simplification), for the cost breakdown; not compared for distance.
EXTRACT_ONLY = {
    "mc-only": ("tandem", "our marching cubes, full resolution (the distance reference)"),
    "fe3d-only": ("peer_vtk", "vtkFlyingEdges3D alone"),
}
OURS = "tandem-lag"
PEERS = ["fe3d+meshopt", "fe3d+vtkqd", "mc+meshopt", "mc+cgal", "classical", "tandem"]
SHAPES = ["pillowbox", "link", "gyroid"]


def log(msg):
    print(msg, flush=True)


# The hand-written part of a generated report: from NOTES_BEGIN to NOTES_END of the existing
# file, kept when the report is written again (None: the file has none).
NOTES_BEGIN, NOTES_END = "<!-- notes -->", "<!-- /notes -->"


def read_notes(path):
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        return None
    a, b = text.find(NOTES_BEGIN), text.find(NOTES_END)
    if a < 0 or b < a:
        return None
    return text[a:b + len(NOTES_END)]


# ----------------------------------------------------------------------------------------
# Running one process and measuring it.

def run_measured(cmd, stdout_path, stderr_path, launcher, timeout=RUN_TIMEOUT_S):
    """Runs cmd (a list) through bench_run (the launcher: see bench_run.cc for why), with
    stdout/stderr to files. Returns a dict with rc (negative: killed by that signal), wall_s,
    cpu_s and peak_rss_bytes of the child, from wait4's rusage."""
    result_path = stdout_path + ".rusage.json"
    if os.path.exists(result_path):
        os.remove(result_path)
    actions = [
        (os.POSIX_SPAWN_OPEN, 1, stdout_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644),
        (os.POSIX_SPAWN_OPEN, 2, stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644),
    ]
    pid = os.posix_spawn(launcher, [launcher, result_path] + cmd, os.environ,
                         file_actions=actions, setpgroup=0)
    done = threading.Event()
    timer = threading.Timer(timeout, lambda: done.is_set() or os.killpg(pid, signal.SIGKILL))
    timer.start()
    _, status = os.waitpid(pid, 0)
    done.set()
    timer.cancel()
    try:
        with open(result_path) as f:
            result = json.load(f)
        os.remove(result_path)
    except (OSError, ValueError):
        result = {"rc": os.waitstatus_to_exitcode(status) or -1, "wall_s": None, "cpu_s": None,
                  "peak_rss_bytes": None}
        if os.waitstatus_to_exitcode(status) == -signal.SIGKILL:
            result["timed_out"] = True
    return result


def run_problem(r, out):
    """What went wrong with a run_measured result (None: nothing); out = the output file the
    run must have written, or None when it writes none worth checking."""
    if r.get("timed_out"):
        return f"timed out after {RUN_TIMEOUT_S} s"
    if r["rc"] != 0:
        return f"exit status {r['rc']}" + (" (crashed)" if r["rc"] < 0 else "")
    if out is not None and (not os.path.exists(out) or os.path.getsize(out) == 0):
        return f"output {out} is missing"
    return None


def report_failure(label, problem, cmd, stderr_path, failures):
    msg = f"{label}: {problem}\n  command: {' '.join(cmd)}\n  stderr tail:\n{tail(stderr_path)}"
    log("FAILED " + msg)
    failures.append(msg)


def run_checked(label, cmd, out, stdout_path, stderr_path, launcher, parse, failures):
    """run_measured, then the checks of run_problem and parse() (a dict merged into the
    result). Returns (result, None), or (None, problem) after reporting the failure."""
    r = run_measured(cmd, stdout_path, stderr_path, launcher)
    problem = run_problem(r, out)
    if problem is None:
        try:
            r.update(parse())
        except (OSError, ValueError, KeyError, RuntimeError) as e:
            problem = f"unreadable result: {e}"
    if problem is not None:
        report_failure(label, problem, cmd, stderr_path, failures)
        return None, problem
    return r, None


def tail(path, n=20):
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-n:])
    except OSError:
        return ""


def run_tool(cmd):
    """A helper run (measure, check, generate): output captured, failure raises."""
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {p.returncode}):\n{p.stderr[-2000:]}")
    return p.stdout


# ----------------------------------------------------------------------------------------
# Inputs.

class Input:
    def __init__(self, name, path, iso, spacing, grid, dtype, kind):
        self.name, self.path, self.iso = name, path, iso
        self.spacing, self.grid, self.dtype, self.kind = spacing, grid, dtype, kind


def load_sidecar(path):
    with open(path) as f:
        return json.load(f)


def make_inputs(args, tandem_bin):
    inputs = []
    sizes = [64, 128] if args.quick else [128, 256, 512]
    if args.sizes:
        sizes = [int(s) for s in args.sizes.split(",")]
    os.makedirs(os.path.join(args.scratch, "volumes"), exist_ok=True)
    for shape in SHAPES:
        for n in sizes:
            name = f"{shape}-{n}"
            if args.only and not any(o in name for o in args.only):
                continue
            path = os.path.join(args.scratch, "volumes", f"{name}.json")
            if not os.path.exists(path) or load_sidecar(path).get("dims") != [n, n, n]:
                log(f"generating {name} -> {path}")
                run_tool([tandem_bin, "generate", shape, "--size", str(n), "--out", path])
            meta = load_sidecar(path)
            inputs.append(Input(name, path, 0.0, meta.get("spacing", [1, 1, 1]), meta["dims"],
                                meta["dtype"], "synthetic"))
    data = args.data
    if not os.path.isdir(data):
        log(f"SKIP shared volumes: {data} is absent")
        return inputs
    shared = []
    for fn in sorted(os.listdir(data)):
        if not fn.endswith(".json"):
            continue
        meta = load_sidecar(os.path.join(data, fn))
        raw = os.path.join(data, meta.get("raw_file", fn[:-5] + ".raw"))
        if not os.path.exists(raw):
            log(f"SKIP {fn}: its raw file {raw} is absent")
            continue
        shared.append((os.path.getsize(raw), fn, meta))
    if not shared:
        log(f"SKIP shared volumes: no readable volume in {data}")
    if args.quick:
        shared = sorted(shared)[:1]  # the smallest
    for _, fn, meta in shared:
        name = fn[:-5]
        if args.only and not any(o in name for o in args.only):
            continue
        iso = float(meta["suggested_isovalues"][0])
        inputs.append(Input(name, os.path.join(data, fn), iso, meta.get("spacing", [1, 1, 1]),
                            meta["dims"], meta["dtype"], "shared"))
    return inputs


# ----------------------------------------------------------------------------------------
# E0: per input, the threshold at which tandem-lag keeps about 10% of the triangles.

def kept_fraction(tandem_bin, inp, e0, work):
    out = os.path.join(work, "calib.ply")
    metrics = os.path.join(work, "calib.json")
    run_tool([tandem_bin, "extract", "--input", inp.path, "--iso", repr(inp.iso), "--error",
              repr(e0), "--out", out, "--metrics", metrics, "--quiet"])
    m = load_sidecar(metrics)
    os.remove(out)
    return m["triangles_final"] / max(1, m["triangles_extracted"])


def calibrate_e0(tandem_bin, inp, work, goal=0.10, tol=0.01):
    """Geometric bisection on E0 (the kept fraction falls as E0 grows); E0 is rounded to two
    significant digits, so the result is a readable number within about 10% of the goal."""
    unit = min(inp.spacing)
    lo, hi = None, None  # lo keeps more than the goal, hi keeps less
    e0 = 0.01 * unit
    history = []
    for _ in range(14):
        e0 = float(f"{e0:.2g}")
        f = kept_fraction(tandem_bin, inp, e0, work)
        history.append((e0, f))
        log(f"  calibrate {inp.name}: E0 = {e0:g} keeps {100 * f:.2f}%")
        if abs(f - goal) <= tol:
            break
        if f > goal:
            lo = e0
            e0 = e0 * 4 if hi is None else math.sqrt(e0 * hi)
        else:
            hi = e0
            e0 = e0 / 4 if lo is None else math.sqrt(lo * e0)
        if float(f"{e0:.2g}") in [h[0] for h in history]:
            break
    best = min(history, key=lambda h: abs(h[1] - goal))
    return {"e0": best[0], "kept": round(best[1], 4)}


def load_e0_table():
    if os.path.exists(E0_FILE):
        with open(E0_FILE) as f:
            return json.load(f)
    return {}


# ----------------------------------------------------------------------------------------
# The pipelines.

def pipeline_cmd(name, bins, inp, e0, target, out):
    iso = repr(inp.iso)
    if name in ("tandem-lag", "tandem", "classical"):
        return [bins["tandem"], "extract", "--input", inp.path, "--iso", iso, "--error", repr(e0),
                "--schedule", name, "--out", out, "--metrics", out + ".metrics.json", "--quiet"]
    if name == "mc-only":
        return [bins["tandem"], "extract", "--input", inp.path, "--iso", iso, "--no-simplify",
                "--out", out, "--metrics", out + ".metrics.json", "--quiet"]
    if name == "fe3d-only":
        return [bins["peer_vtk"], "--input", inp.path, "--iso", iso, "--simplify", "none",
                "--out", out]
    if name.startswith("fe3d+"):
        return [bins["peer_vtk"], "--input", inp.path, "--iso", iso, "--simplify",
                name.split("+")[1], "--target-triangles", str(target), "--out", out]
    return [bins[PIPELINES[name][0]], "--input", inp.path, "--iso", iso,
            "--target-triangles", str(target), "--out", out]


def parse_program_result(name, out, stdout_path):
    """Triangles and phase times as the program reports them."""
    if name in ("tandem-lag", "tandem", "classical", "mc-only"):
        m = load_sidecar(out + ".metrics.json")
        return {"triangles_extracted": m["triangles_extracted"],
                "triangles": m["triangles_final"], "vertices": m["vertices_final"],
                "extract_s": m["time_s"]["extract"], "simplify_s": m["time_s"]["simplify"],
                "error_max": m["error_max"], "peak_triangles": m["peak_triangles"]}
    with open(stdout_path) as f:
        lines = [l for l in f.read().splitlines() if l.startswith("{")]
    if not lines:
        raise RuntimeError("no result line on stdout")
    r = json.loads(lines[-1])
    t = r["time_s"]
    return {"triangles_extracted": r["triangles_extracted"], "triangles": r["triangles_final"],
            "vertices": r["vertices_final"], "extract_s": t["read"] + t["extract"],
            "simplify_s": t["simplify"], "note": r.get("note", "")}


def available(name, bins, vtk_modes):
    """None when runnable, else the reason it is skipped."""
    prog = (PIPELINES.get(name) or EXTRACT_ONLY[name])[0]
    if prog not in bins:
        lib = {"peer_vtk": "VTK 9 (libvtk9-dev)", "peer_mc_meshopt": "meshoptimizer",
               "peer_mc_cgal": "CGAL 5.5 (libcgal-dev)"}.get(prog, prog)
        return f"{prog} not built: {lib} is not installed (bash tests/bench/install-peers.sh)"
    if name == "fe3d+meshopt" and "meshopt" not in vtk_modes:
        return "peer_vtk was built without meshoptimizer (libmeshoptimizer-dev)"
    return None


def median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def bench_input(inp, e0, args, bins, vtk_modes, failures):
    work = os.path.join(args.scratch, "runs", inp.name)
    os.makedirs(work, exist_ok=True)
    res = {"name": inp.name, "kind": inp.kind, "grid": inp.grid, "dtype": inp.dtype,
           "iso": inp.iso, "spacing": inp.spacing, "e0": e0, "pipelines": {}}
    names = list(PIPELINES) + list(EXTRACT_ONLY)
    for name in names:
        reason = available(name, bins, vtk_modes)
        res["pipelines"][name] = {"runs": []} if reason is None else {"skipped": reason}
        if reason is not None and (name, reason) not in args.skips_told:
            log(f"SKIP {name}: {reason}")
            args.skips_told.add((name, reason))
    target = None
    for rep in range(args.repeats):
        order = [OURS] + [n for n in names if n != OURS]
        for name in order:
            p = res["pipelines"][name]
            if "skipped" in p or p.get("failed"):
                continue
            if name in PIPELINES and name != OURS and name not in ("tandem", "classical") \
                    and target is None:
                p["failed"] = "no target triangle count (tandem-lag failed)"
                continue
            out = os.path.join(work, f"{name}.ply" if rep == 0 else f"{name}.rep.ply")
            for stale in (out, out + ".metrics.json"):
                if os.path.exists(stale):
                    os.remove(stale)
            cmd = pipeline_cmd(name, bins, inp, e0, target, out)
            so, se = os.path.join(work, f"{name}.stdout"), os.path.join(work, f"{name}.stderr")
            r, problem = run_checked(f"{inp.name} / {name}", cmd, out, so, se, bins["bench_run"],
                                     lambda: parse_program_result(name, out, so), failures)
            if problem is not None:
                p["failed"] = problem
                continue
            p["runs"].append(r)
            if name == OURS and target is None:
                target = r["triangles"]
                res["target_triangles"] = target
            if rep > 0:
                os.remove(out)
            log(f"  {inp.name:34s} {name:13s} rep {rep + 1}: {r['triangles']:>9d} triangles, "
                f"{r['wall_s']:7.2f} s wall, {r['cpu_s']:7.2f} s cpu, "
                f"{r['peak_rss_bytes'] / 2**20:8.1f} MiB")
    # Medians, then distance and topology of the first repeat's output.
    full = os.path.join(work, "mc-only.ply")
    for name in names:
        p = res["pipelines"][name]
        if "skipped" in p or p.get("failed") or not p["runs"]:
            continue
        runs = p["runs"]
        tris = {r["triangles"] for r in runs}
        if len(tris) > 1:
            log(f"NOTE {inp.name} / {name}: triangle count differs between repeats: {sorted(tris)}")
        p["median"] = {k: median([r.get(k) for r in runs])
                       for k in ("wall_s", "cpu_s", "peak_rss_bytes", "extract_s", "simplify_s")}
        p["triangles"] = runs[0]["triangles"]
        p["triangles_extracted"] = runs[0]["triangles_extracted"]
        for k in ("error_max", "peak_triangles", "note"):
            if k in runs[0]:
                p[k] = runs[0][k]
        out = os.path.join(work, f"{name}.ply")
        try:
            p["topology"] = json.loads(run_tool([bins["mesh_check"], out]))
            if name in PIPELINES and os.path.exists(full):
                d = json.loads(run_tool([bins["tandem"], "measure", full, out, "--json"]))["distance"]
                p["distance"] = {"L1": d["L1"]["max"], "L2": d["L2"]["max"],
                                 "Linf": d["Linf"]["max"], "L2_forward": d["L2"]["forward"],
                                 "L2_backward": d["L2"]["backward"],
                                 "Linf_forward": d["Linf"]["forward"],
                                 "Linf_backward": d["Linf"]["backward"]}
        except (RuntimeError, ValueError, KeyError) as e:
            msg = f"{inp.name} / {name}: measuring the output failed: {e}"
            log("FAILED " + msg)
            failures.append(msg)
            p["failed"] = "measure failed"
    if not args.keep:
        for fn in os.listdir(work):
            if fn.endswith(".ply") or fn.endswith(".metrics.json"):
                os.remove(os.path.join(work, fn))
    return res


# ----------------------------------------------------------------------------------------
# Report.

def fmt(x, spec=".3g"):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return format(x, spec)


def mib(b):
    return None if b is None else b / 2**20


def ratio(a, b):
    if a is None or b is None or b == 0:
        return None
    return a / b


def machine_info():
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = ""
    try:
        with open("/proc/meminfo") as f:
            mem = f"{int(f.readline().split()[1]) / 2**20:.0f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    try:
        commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "core"],
                               capture_output=True, text=True).stdout.strip()
        if dirty:
            commit += " (core/ has uncommitted changes)"
    except OSError:
        commit = "?"
    return {"cpu": cpu, "cores": os.cpu_count(), "memory": mem, "os": platform.platform(),
            "commit": commit, "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
            "load_average_at_start": os.getloadavg()}


def package_versions():
    out = {}
    for pkg in ("libvtk9-dev", "libmeshoptimizer-dev", "libcgal-dev"):
        p = subprocess.run(["dpkg-query", "-W", "-f=${Version}", pkg], capture_output=True, text=True)
        out[pkg] = p.stdout.strip() if p.returncode == 0 and p.stdout.strip() else "not installed"
    return out


def topo_cell(p):
    t = p.get("topology")
    if not t:
        return "–", "–"
    man = "yes" if t["manifold"] else f"**no** ({t['nonmanifold_edges']} nm edges)"
    chi = str(t["euler"])
    if t.get("duplicate_positions"):
        chi += f" ({t['duplicate_positions']} dup. vertices)"
    return man, chi


def input_table(res):
    lines = [
        "| pipeline | triangles | extract s | simplify s | **total s** (wall) | CPU s | peak RSS MiB | RMS (L2) | Hausdorff | manifold | χ |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for name in list(PIPELINES) + list(EXTRACT_ONLY):
        p = res["pipelines"][name]
        if "skipped" in p:
            lines.append(f"| {name} | skipped: {p['skipped']} ||||||||||")
            continue
        if p.get("failed") and "median" not in p:
            lines.append(f"| {name} | **FAILED**: {p['failed']} ||||||||||")
            continue
        m, d = p["median"], p.get("distance", {})
        man, chi = topo_cell(p)
        bold = "**" if name == OURS else ""
        lines.append(
            f"| {bold}{name}{bold} | {p['triangles']:,} | {fmt(m['extract_s'])} | "
            f"{fmt(m['simplify_s'])} | {bold}{fmt(m['wall_s'])}{bold} | {fmt(m['cpu_s'])} | "
            f"{fmt(mib(m['peak_rss_bytes']), '.1f')} | {fmt(d.get('L2'))} | {fmt(d.get('Linf'))} | "
            f"{man} | {chi} |")
    return lines


def ratio_rows(res):
    """ours / peer for wall time, CPU time, peak RSS, RMS and Hausdorff (< 1: ours smaller)."""
    rows = []
    o = res["pipelines"].get(OURS, {})
    if "median" not in o:
        return rows
    for peer in PEERS:
        p = res["pipelines"].get(peer, {})
        if "median" not in p:
            continue
        rows.append({
            "peer": peer,
            "wall": ratio(o["median"]["wall_s"], p["median"]["wall_s"]),
            "cpu": ratio(o["median"]["cpu_s"], p["median"]["cpu_s"]),
            "rss": ratio(o["median"]["peak_rss_bytes"], p["median"]["peak_rss_bytes"]),
            "l2": ratio(o.get("distance", {}).get("L2"), p.get("distance", {}).get("L2")),
            "linf": ratio(o.get("distance", {}).get("Linf"), p.get("distance", {}).get("Linf")),
            "tris": ratio(o["triangles"], p["triangles"]),
        })
    return rows


def ratio_table(results):
    lines = ["| input | peer | time (wall) | CPU time | peak RSS | RMS | Hausdorff | triangles |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for res in results:
        for r in ratio_rows(res):
            lines.append(f"| {res['name']} | {r['peer']} | {fmt(r['wall'], '.2f')} | "
                         f"{fmt(r['cpu'], '.2f')} | {fmt(r['rss'], '.2f')} | {fmt(r['l2'], '.2f')} | "
                         f"{fmt(r['linf'], '.2f')} | {fmt(r['tris'], '.3f')} |")
    return lines


def geomean_table(results):
    """Per peer, the geometric mean over inputs of each ours / peer ratio."""
    lines = ["| peer | inputs | time (wall) | CPU time | peak RSS | RMS | Hausdorff |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for peer in PEERS:
        rows = [r for res in results for r in ratio_rows(res) if r["peer"] == peer]
        if not rows:
            continue
        def gm(key):
            xs = [r[key] for r in rows if r[key]]
            return math.exp(sum(math.log(x) for x in xs) / len(xs)) if xs else None
        lines.append(f"| {peer} | {len(rows)} | {fmt(gm('wall'), '.2f')} | {fmt(gm('cpu'), '.2f')} | "
                     f"{fmt(gm('rss'), '.2f')} | {fmt(gm('l2'), '.2f')} | {fmt(gm('linf'), '.2f')} |")
    return lines


def targets_section(results):
    by = {r["name"]: r for r in results}
    lines = []

    def med(name, pipe, key):
        p = by.get(name, {}).get("pipelines", {}).get(pipe, {})
        return p.get("median", {}).get(key)

    def dist(name, pipe, key):
        return by.get(name, {}).get("pipelines", {}).get(pipe, {}).get("distance", {}).get(key)

    def best(name, pipe):
        runs = by.get(name, {}).get("pipelines", {}).get(pipe, {}).get("runs", [])
        walls = [r["wall_s"] for r in runs if r.get("wall_s") is not None]
        return min(walls) if walls else None

    for shape in ("pillowbox", "link"):
        name = f"{shape}-512"
        if name not in by:
            lines.append(f"- {name}: not run in this mode.")
            continue
        t = med(name, OURS, "wall_s")
        lines.append(f"- **{name}** (E0 = {by[name]['e0']:g}, tandem-lag keeps "
                     f"{by[name]['pipelines'][OURS]['triangles']:,} of "
                     f"{by[name]['pipelines'][OURS]['triangles_extracted']:,} triangles):")
        for peer in ("fe3d+meshopt", "fe3d+vtkqd"):
            pt = med(name, peer, "wall_s")
            lines.append(f"  - end-to-end time, tandem-lag vs {peer}: {fmt(t)} s vs {fmt(pt)} s "
                         f"= **{fmt(ratio(t, pt), '.2f')}×** (CPU: {fmt(med(name, OURS, 'cpu_s'))} s "
                         f"vs {fmt(med(name, peer, 'cpu_s'))} s = "
                         f"{fmt(ratio(med(name, OURS, 'cpu_s'), med(name, peer, 'cpu_s')), '.2f')}×; "
                         f"best wall of the repeats: {fmt(best(name, OURS))} s vs "
                         f"{fmt(best(name, peer))} s = "
                         f"{fmt(ratio(best(name, OURS), best(name, peer)), '.2f')}×)")
        r_o, r_p = med(name, OURS, "peak_rss_bytes"), med(name, "fe3d+meshopt", "peak_rss_bytes")
        lines.append(f"  - peak RSS, tandem-lag vs fe3d+meshopt: {fmt(mib(r_o), '.1f')} MiB vs "
                     f"{fmt(mib(r_p), '.1f')} MiB = **{fmt(ratio(r_o, r_p), '.2f')}×**")
        r256 = med(f"{shape}-256", OURS, "peak_rss_bytes")
        lines.append(f"  - tandem-lag peak RSS 512³ / 256³: {fmt(mib(r_o), '.1f')} / "
                     f"{fmt(mib(r256), '.1f')} MiB = **{fmt(ratio(r_o, r256), '.2f')}×** "
                     f"(the volume grows 8×, the surface 4×)")
        for peer in ("mc+cgal", "fe3d+vtkqd"):
            lines.append(f"  - RMS / Hausdorff vs {peer}: {fmt(dist(name, OURS, 'L2'))} / "
                         f"{fmt(dist(name, OURS, 'Linf'))} vs {fmt(dist(name, peer, 'L2'))} / "
                         f"{fmt(dist(name, peer, 'Linf'))} = "
                         f"**{fmt(ratio(dist(name, OURS, 'L2'), dist(name, peer, 'L2')), '.2f')}× / "
                         f"{fmt(ratio(dist(name, OURS, 'Linf'), dist(name, peer, 'Linf')), '.2f')}×**")
    bad = []
    for res in results:
        for name, p in res["pipelines"].items():
            t = p.get("topology")
            if t and not t["manifold"]:
                bad.append(f"{res['name']}/{name}")
    lines.append("- Manifold: every output of tandem-lag, tandem and classical is an orientable "
                 "2-manifold" if not any(b.split("/")[1] in ("tandem-lag", "tandem", "classical")
                                          for b in bad)
                 else "- Manifold: **some of our outputs are not manifold**")
    lines.append(f"  (non-manifold outputs overall: {', '.join(bad) if bad else 'none'}); "
                 "the Euler characteristic of every output is in the tables below.")
    return lines


def write_report(path, results, meta, args):
    L = []
    L.append("# tandem benchmark" + (" (quick mode)" if args.quick else ""))
    L.append("")
    L.append(f"Generated by `bash tests/bench/run.sh{' --quick' if args.quick else ''}` on "
             f"{meta['machine']['date']}; commit {meta['machine']['commit']}. "
             f"Machine: {meta['machine']['cpu']}, {meta['machine']['cores']} cores, "
             f"{meta['machine']['memory']}; {meta['machine']['os']}. Load average at start "
             f"{', '.join(f'{x:.1f}' for x in meta['machine']['load_average_at_start'])} "
             "(the machine is shared: wall times are noisy, CPU times less so).")
    L.append("")
    L.append(f"Peers: VTK {meta['packages']['libvtk9-dev']}, meshoptimizer "
             f"{meta['packages']['libmeshoptimizer-dev']}, CGAL {meta['packages']['libcgal-dev']} "
             f"(Debian packages). Repeats: {args.repeats}, medians reported.")
    L.append("")
    L.append("## Method")
    L.append("")
    L.append("- Every pipeline runs in its own process and reads the volume from the same raw + "
             "JSON files (ours and our extraction slice by slice; VTK reads the raw file whole "
             "into a vtkImageData of the file's voxel type).")
    L.append("- Pipelines: " + "; ".join(f"`{n}` = {d}" for n, (_, d) in PIPELINES.items()) + ".")
    L.append("- E0 (physical units) is fixed per input in `tests/bench/e0.json`: the value, "
             "found by a geometric search (`run.sh --calibrate`), at which tandem-lag keeps "
             "about 10% of the extracted triangles. Every peer is then asked for the triangle "
             "count tandem-lag reached (VTK: TargetReduction = 1 − ours/extracted; meshopt: "
             "target index count with the error bound left open; CGAL: stop at that face count).")
    L.append("- **total s** = wall time of the process, from fork to exit (reading, extraction, "
             "simplification, writing a binary PLY). CPU s = user + system time (wait4). "
             "Threads: VTK's FlyingEdges3D uses all cores (TBB); ours use all cores too (grids "
             "256 or more wide are split along x into 4 parts (81 to 255 wide: 2) extracted "
             "and simplified by a pool of workers, one per core, and merged at the end, see "
             "core/include/tandem/tandem.h; "
             "smaller grids extract layer k+1 while layer k is simplified); meshopt, VTK's "
             "decimation and CGAL run on one core. Peak RSS "
             "= ru_maxrss of the process, forked by a small launcher (`bench_run`) so that the "
             "driver's own footprint does not leak into it. extract/simplify s = the program's own phase times "
             "(for VTK, extract includes reading the raw file; for ours, reading is interleaved "
             "with extraction, and the phases of the parts are added up, so they can exceed "
             "the wall time; VTK QD's simplify includes vtkCleanPolyData).")
    L.append("- RMS (L2) and Hausdorff (L∞) distances: `tandem measure full.ply out.ply --json` "
             "against our full-resolution marching-cubes surface (`mc-only`), undirected (the "
             "larger of the two directions), area-uniform samples. Physical units.")
    L.append("- manifold / χ: `mesh_check` (tandem_core AnalyzeTopology) on the output as "
             "written; χ = V − E + F. \"dup. vertices\" = vertices sharing an exact position with "
             "another: on integer volumes marching cubes puts vertices exactly on grid points, "
             "and both extractions keep one vertex per grid edge (SPEC §2), so these are "
             "expected; they are topologically harmless. χ of the full-resolution surfaces can "
             "differ between FlyingEdges3D and ours where they resolve ambiguous cubes "
             "differently.")
    L.append("- Ratios are ours (tandem-lag) / peer: below 1 means ours is faster, smaller, or "
             "closer to the full-resolution surface.")
    L.append("")
    L.append("## Targets (issue 6)")
    L.append("")
    L.extend(targets_section(results))
    L.append("")
    L.append("## Ratios: tandem-lag / peer")
    L.append("")
    L.append("Geometric mean over all inputs:")
    L.append("")
    L.extend(geomean_table(results))
    L.append("")
    L.append("Per input:")
    L.append("")
    L.extend(ratio_table(results))
    L.append("")
    L.append("## Per input")
    for res in results:
        L.append("")
        grid = "×".join(str(g) for g in res["grid"])
        tgt = res.get("target_triangles")
        L.append(f"### {res['name']}")
        L.append("")
        L.append(f"{grid} {res['dtype']}, spacing {', '.join(f'{s:g}' for s in res['spacing'])}, "
                 f"iso {res['iso']:g}, E0 = {res['e0']:g}; extracted "
                 f"{fmt(res['pipelines'].get('mc-only', {}).get('triangles'), ',')} triangles, "
                 f"target {fmt(tgt, ',')}.")
        L.append("")
        L.extend(input_table(res))
    if meta["failures"]:
        L.append("")
        L.append("## Failures")
        L.append("")
        for f in meta["failures"]:
            L.append("```\n" + f.strip() + "\n```")
    L.append("")
    with open(path, "w") as f:
        f.write("\n".join(L))


def print_summary(results):
    log("")
    log("ratios tandem-lag / peer (wall, cpu, rss, rms, hausdorff):")
    for res in results:
        for r in ratio_rows(res):
            log(f"  {res['name']:34s} {r['peer']:13s} wall {fmt(r['wall'], '6.2f')}  cpu "
                f"{fmt(r['cpu'], '6.2f')}  rss {fmt(r['rss'], '6.2f')}  rms {fmt(r['l2'], '6.2f')}  "
                f"hausdorff {fmt(r['linf'], '6.2f')}")


# ----------------------------------------------------------------------------------------

def add_common_args(ap, report, results):
    """The flags bench.py and dense.py share; report / results: the default file names."""
    ap.add_argument("--bin", help="directory with tandem, bench_run, mesh_check and the peers")
    ap.add_argument("--only", action="append", help="only inputs whose name contains this (repeatable)")
    ap.add_argument("--data", default=os.path.normpath(os.path.join(ROOT, "..", "shared", "data")))
    ap.add_argument("--scratch", default=os.environ.get(
        "TANDEM_BENCH_SCRATCH", os.path.join(os.environ.get("TMPDIR", "/tmp"), "tandem-bench")))
    ap.add_argument("--report", help=f"Markdown report (default: tests/bench/{report}, or "
                                     f"SCRATCH/{report} with --quick)")
    ap.add_argument("--json", help=f"results JSON (default: beside the report, {results})")
    ap.add_argument("--keep", action="store_true", help="keep the output meshes in SCRATCH")
    ap.add_argument("--from-json", metavar="RESULTS", help=f"only rewrite the report from a "
                    f"{results} of an earlier run (runs nothing)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_args(ap, "REPORT.md", "results.json")
    ap.add_argument("--quick", action="store_true", help="64³/128³ + smallest shared volume, 1 repeat")
    ap.add_argument("--repeats", type=int, help="runs per pipeline (default 3, --quick 1)")
    ap.add_argument("--sizes", help="comma-separated synthetic grid sizes (overrides the mode's)")
    ap.add_argument("--calibrate", action="store_true", help="redo the E0 search and rewrite e0.json")
    args = ap.parse_args()
    if args.from_json:
        with open(args.from_json) as f:
            saved = json.load(f)
        args.quick = saved["meta"]["mode"] == "quick"
        args.repeats = saved["meta"]["repeats"]
        report = args.report or os.path.join(os.path.dirname(os.path.abspath(args.from_json)), "REPORT.md")
        write_report(report, saved["inputs"], saved["meta"], args)
        print_summary(saved["inputs"])
        log(f"wrote {report}")
        return
    if not args.bin:
        ap.error("--bin is required")
    args.repeats = args.repeats or (1 if args.quick else 3)
    args.skips_told = set()
    report = args.report or (os.path.join(args.scratch, "REPORT.md") if args.quick
                             else os.path.join(HERE, "REPORT.md"))
    results_json = args.json or os.path.join(os.path.dirname(report), "results.json")
    os.makedirs(args.scratch, exist_ok=True)

    bins = find_programs(args.bin, ("tandem", "bench_run", "mesh_check", "peer_vtk",
                                    "peer_mc_meshopt", "peer_mc_cgal"), "bench")
    vtk_modes = run_tool([bins["peer_vtk"], "--modes"]).split() if "peer_vtk" in bins else []

    t_start = time.perf_counter()
    inputs = make_inputs(args, bins["tandem"])
    e0_table = load_e0_table()
    failures, results = [], []
    changed = False
    for inp in inputs:
        entry = e0_table.get(inp.name)
        if entry is None or args.calibrate:
            log(f"searching E0 for {inp.name} (tandem-lag keeping ~10%)")
            entry = calibrate_e0(bins["tandem"], inp, args.scratch)
            e0_table[inp.name] = entry
            changed = True
        log(f"{inp.name}: E0 = {entry['e0']:g}")
        results.append(bench_input(inp, entry["e0"], args, bins, vtk_modes, failures))
    if changed and not args.quick:
        merged = load_e0_table()  # merge: another run may have added entries meanwhile
        merged.update({inp.name: e0_table[inp.name] for inp in inputs})
        with open(E0_FILE, "w") as f:
            json.dump(dict(sorted(merged.items())), f, indent=1)
            f.write("\n")
        log(f"wrote {E0_FILE}")

    meta = {"machine": machine_info(), "packages": package_versions(), "failures": failures,
            "mode": "quick" if args.quick else "full", "repeats": args.repeats,
            "elapsed_s": time.perf_counter() - t_start}
    finish("bench", report, results_json, results, meta,
           lambda: write_report(report, results, meta, args), lambda: print_summary(results))


def report_paths(args, ap, report_name, json_name, write):
    """The report and results paths of a run (tests/bench/NAME, or SCRATCH/NAME with --quick),
    or None after --from-json rewrote the report with write(report, saved) (runs nothing)."""
    if args.from_json:
        saved = load_sidecar(args.from_json)
        report = args.report or os.path.join(os.path.dirname(os.path.abspath(args.from_json)),
                                             report_name)
        write(report, saved)
        log(f"wrote {report}")
        return None
    if not args.bin:
        ap.error("--bin is required")
    report = args.report or (os.path.join(args.scratch, report_name) if args.quick
                             else os.path.join(HERE, report_name))
    results = args.json or os.path.join(os.path.dirname(report), json_name)
    for path in (report, results):  # a --report in a new folder is made, not a late crash
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    return report, results


def find_programs(bin_dir, progs, tool):
    """{program: path} of those of progs built in bin_dir; exits when tandem, bench_run or
    mesh_check is missing."""
    bins = {}
    for prog in progs:
        path = os.path.join(bin_dir, prog)
        if os.access(path, os.X_OK):
            bins[prog] = path
    for required in ("tandem", "bench_run", "mesh_check"):
        if required not in bins:
            sys.exit(f"{tool}: {bin_dir}/{required} is missing (build tests/bench first)")
    return bins


def finish(tool, report, results_json, results, meta, write, summary):
    """Writes the results JSON and (write()) the report, prints summary(), and exits with 1
    when meta lists failures."""
    with open(results_json, "w") as f:
        json.dump({"meta": meta, "inputs": results}, f, indent=1)
    write()
    summary()
    log(f"\nwrote {report} and {results_json} ({meta['elapsed_s']:.0f} s)")
    if meta["failures"]:
        log(f"\n{tool}: {len(meta['failures'])} FAILURE(S):")
        for f in meta["failures"]:
            log("  " + f.splitlines()[0])
        sys.exit(1)


if __name__ == "__main__":
    main()
