#!/usr/bin/env python3
"""The parser and the model behind scaling.sh (issue 65 item 3): where a `tandem extract`
run's CPU goes, by what can run side by side, and the wall time that predicts on C cores.

  scaling.py classify PERF_SCRIPT.txt TIME.txt METRICS.json --input NAME --parts P
      one line of JSON: the run's CPU seconds by class (see CLASSES), from `perf script -F
      pid,tid,time,ip,sym` of a `perf record --call-graph dwarf` run on one core, scaled to
      the process's user + sys (TIME.txt: `/usr/bin/time -f "%U %S %e"`).
  scaling.py crop VOLUME.json --parts P --out DIR
      writes the P slabs of the volume as volumes of their own (the columns `tandem extract
      --parts P` gives each slab, core/src/slabs.cc MakeSlabs), DIR/slab{p}.json.
  scaling.py model WORK.jsonl... [--pairs PAIRS.jsonl]...
      prints the measured table and the model's wall times for 1, 2, 4, 8, 16 cores (runs
      repeated over several files count by their medians).

The classes, by the engine function a sample's call chain passes through (first match):
  slabs    StepSlab, FinishSlab, FinishAtError, ApproachTarget: a slab's own chain of steps,
           side by side with the other slabs' (decision 32), one core a slab at most
  sag      the final sag correction (CorrectSag, VertexNormals): in ranges over every core
  merge    MergeSlabs: serial
  seams    the rest of FinishWhole (SIMPLIFY from the welded seams, TidyDegenerate): serial
  write    WriteMesh, Snapshot: serial
  report   the summary's measures (MakeReport, on another thread beside the write)
  read     the main thread while the slices stream in (mapping, the copy into the ring)
  startup  the main thread before the first slice (loader, opening the volume)
A sample whose chain ends in a frame the unwinder could not pass (a kernel mremap, memmove)
takes the class of the nearest classified sample of its thread.
"""
import argparse
import bisect
import json
import os
import statistics
import sys

CLASSES = ["slabs", "read", "sag", "merge", "seams", "write", "report", "startup", "other"]
RULES = [
    ("slabs", ("tandem::StepSlab", "tandem::FinishSlab", "tandem::FinishAtError",
               "tandem::ApproachTarget")),
    ("sag", ("CorrectSag", "tandem::VertexNormals")),
    ("merge", ("tandem::MergeSlabs",)),
    ("seams", ("tandem::FinishWhole",)),
    ("write", ("WriteMesh", "::Snapshot")),
    ("report", ("MakeReport",)),
    ("read", ("RunSessions",)),
]


def read_samples(path):
    samples, cur = [], None
    for line in open(path, errors="replace"):
        if not line.strip():
            if cur:
                samples.append(cur)
            cur = None
            continue
        if not line.startswith("\t"):
            head = line.split()
            # comm pid/tid time:  (the comm may hold spaces: read from the right)
            t = float(head[-1].rstrip(":"))
            pid, tid = head[-2].split("/")
            cur = {"pid": int(pid), "tid": int(tid), "time": t, "chain": []}
        elif cur is not None:
            parts = line.split(None, 1)
            cur["chain"].append(parts[1].strip() if len(parts) > 1 else "?")
    if cur:
        samples.append(cur)
    return samples


def classify(args):
    samples = read_samples(args.perf)
    # The tandem process: the pid with the most samples (taskset and time are short).
    by_pid = {}
    for s in samples:
        by_pid[s["pid"]] = by_pid.get(s["pid"], 0) + 1
    pid = max(by_pid, key=by_pid.get)
    samples = [s for s in samples if s["pid"] == pid]
    for s in samples:
        text = " | ".join(s["chain"])
        s["cls"] = None
        for cls, keys in RULES:
            if any(k in text for k in keys):
                s["cls"] = cls
                break
    first_read = min((s["time"] for s in samples if s["cls"] == "read"), default=0.0)
    for s in samples:  # the main thread before its first slice
        if s["cls"] is None and s["tid"] == pid and s["time"] < first_read:
            s["cls"] = "startup"
    by_tid = {}
    for s in samples:
        if s["cls"] is not None:
            by_tid.setdefault(s["tid"], []).append(s)
    for s in samples:
        if s["cls"] is not None:
            continue
        known = by_tid.get(s["tid"], [])
        if not known:
            s["cls"] = "other"
            continue
        times = [k["time"] for k in known]
        i = bisect.bisect_left(times, s["time"])
        near = [known[j] for j in (i - 1, i) if 0 <= j < len(known)]
        s["cls"] = min(near, key=lambda k: abs(k["time"] - s["time"]))["cls"]
    user, sys_, wall = (float(x) for x in open(args.time).read().split()[-3:])
    cpu = user + sys_
    counts = {c: 0 for c in CLASSES}
    for s in samples:
        counts[s["cls"]] += 1
    n = max(1, len(samples))
    metrics = json.load(open(args.metrics))
    out = {
        "input": args.input, "parts": args.parts, "cpu_s": round(cpu, 3),
        "wall_one_core_s": wall, "samples": len(samples),
        "triangles": metrics.get("triangles_final"),
        "extracted": metrics.get("triangles_extracted"),
        "contractions": metrics.get("contractions"), "evaluations": metrics.get("evaluations"),
        "session_cpu_s": round(metrics["time_s"]["extract"] + metrics["time_s"]["simplify"], 3),
    }
    out.update({c: round(cpu * counts[c] / n, 3) for c in CLASSES})
    print(json.dumps(out))


def crop(args):
    meta = json.load(open(args.volume))
    nx, ny, nz = meta["dims"]
    size = {"uint8": 1, "int8": 1, "uint16": 2, "int16": 2, "float32": 4}[meta["dtype"]]
    raw = os.path.join(os.path.dirname(os.path.abspath(args.volume)), meta["raw_file"])
    os.makedirs(args.out, exist_ok=True)
    p_count = args.parts
    cols = [(p * (nx - 1) // p_count, (p + 1) * (nx - 1) // p_count) for p in range(p_count)]
    outs = [open(os.path.join(args.out, f"slab{p}.raw"), "wb") for p in range(p_count)]
    row = nx * size
    with open(raw, "rb") as f:
        for _ in range(ny * nz):
            r = f.read(row)
            for (c0, c1), o in zip(cols, outs):
                o.write(r[c0 * size:(c1 + 1) * size])
    for p, ((c0, c1), o) in enumerate(zip(cols, outs)):
        o.close()
        m = dict(meta)
        m["dims"] = [c1 - c0 + 1, ny, nz]
        m["raw_file"] = f"slab{p}.raw"
        m.pop("sha256", None)
        if "raw_bytes" in m:
            m["raw_bytes"] = (c1 - c0 + 1) * ny * nz * size
        m["description"] = f"columns {c0}..{c1} of {args.volume}"
        with open(os.path.join(args.out, f"slab{p}.json"), "w") as o2:
            json.dump(m, o2)


def predict(r, cores, imbalance):
    """Wall seconds of run r (measured on one core with r['parts'] slabs) on `cores` cores."""
    p = r["parts"]
    lanes = min(cores, p)
    slab_max = r["slabs"] / p * imbalance  # the longest slab's chain
    # The slices come in on one thread (the reader), beside the slabs.
    stream = max(slab_max, r["read"], (r["slabs"] + r["read"]) / cores, r["slabs"] / lanes)
    return serial_part(r, cores) + stream + r["sag"] / cores


def serial_part(r, cores):
    # The report runs beside the write on a second core (on one core after it).
    report = max(0.0, r["report"] - r["write"]) if cores > 1 else r["report"]
    return r["startup"] + r["merge"] + r["seams"] + r["write"] + r["other"] + report


def merged_runs(rows):
    """One row per (input, parts): the median of each figure over repeated runs."""
    groups = {}
    for r in rows:
        groups.setdefault((r["input"], r["parts"]), []).append(r)
    out = []
    for (name, parts), rs in groups.items():
        m = dict(rs[0])
        for k, v in rs[0].items():
            if isinstance(v, (int, float)) and k != "parts":
                m[k] = statistics.median(x[k] for x in rs if x.get(k) is not None)
        m["repeats"] = len(rs)
        out.append(m)
    return out


def model(args):
    rows = [json.loads(l) for f in args.work for l in open(f) if l.strip()]
    runs = merged_runs([r for r in rows if r.get("kind", "run") == "run"])
    slabs = [r for r in rows if r.get("kind") == "slab"]
    pairs = [json.loads(l) for f in (args.pairs or []) if os.path.exists(f)
             for l in open(f) if l.strip()]
    for name in dict.fromkeys(r["input"] for r in runs):
        rs = sorted((r for r in runs if r["input"] == name), key=lambda r: r["parts"])
        print(f"\n## {name}\n")
        print("CPU seconds by class, each run on one core (perf samples scaled to user + sys; "
              "the median of the repeats):\n")
        print("| parts | repeats | triangles | contractions | evaluations | CPU | slabs | read "
              "| sag | merge | seams | write | report | startup | other | longest slab / mean |")
        print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        imb = {}
        for r in rs:
            # The longest slab over the mean, by its contractions (deterministic) where the
            # slab runs counted them, else by their CPU (noisy under load).
            ss, key = {}, "session_cpu_s"
            mine = [s for s in slabs if s["input"] == name and s["parts"] == r["parts"]]
            if mine and all(s.get("contractions") is not None for s in mine):
                key = "contractions"
            for s in mine:
                ss.setdefault(s["slab"], []).append(s[key])
            measured = len(ss) == r["parts"] and r["parts"] > 1
            if measured:
                per = [statistics.median(v) for v in ss.values()]
                imb[r["parts"]] = max(per) / statistics.mean(per)
            else:
                imb[r["parts"]] = 1.0
            shown = f"{imb[r['parts']]:.3f} ({'contractions' if key != 'session_cpu_s' else 'CPU'})" \
                if measured else ("1" if r["parts"] == 1 else "not measured (1)")
            count = lambda k: f"{int(r[k]):,}" if r.get(k) is not None else "n/a"
            print(f"| {r['parts']} | {r['repeats']} | {int(r['triangles']):,} | "
                  f"{count('contractions')} | {count('evaluations')} | {r['cpu_s']:.2f} | " +
                  " | ".join(f"{r[c]:.2f}" for c in CLASSES) + f" | {shown} |")
        print("\nModel: wall seconds on C cores with parts = C, against the same run on one "
              "core (its CPU: the same work, so the speed-up is the split's structure; CPU "
              "between part counts moves with the load, the contractions do not):\n")
        print("| cores = parts | one core | C cores (model) | speed-up | efficiency | "
              "serial share | reading / longest slab |")
        print("|---:|---:|---:|---:|---:|---:|---:|")
        for r in rs:
            c = r["parts"]
            t1, tc = predict(r, 1, imb[c]), predict(r, c, imb[c])
            slab_max = r["slabs"] / c * imb[c]
            print(f"| {c} | {t1:.2f} | {tc:.2f} | {t1 / tc:.2f}× | {t1 / tc / c:.2f} | "
                  f"{(serial_part(r, c) + r['sag'] / c) / tc:.0%} | "
                  f"{r['read'] / slab_max:.2f} |")
        for pr in (p for p in pairs if p["input"] == name):
            r = next((x for x in rs if x["parts"] == pr["parts"]), None)
            if r is None:
                continue
            t_1, t_2 = predict(r, 1, imb[r["parts"]]), predict(r, 2, imb[r["parts"]])
            print(f"\n1 against 2 cores, --parts {pr['parts']}: model {t_1:.2f} / {t_2:.2f} s = "
                  f"{t_1 / t_2:.2f}×; measured (median wall of {pr['n']} pairs, one core / two): "
                  f"{pr['one']:.2f} / {pr['two']:.2f} s, ratio {pr['ratio']:.2f}× "
                  f"(pairs {pr['ratio_min']:.2f}–{pr['ratio_max']:.2f}).")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("classify")
    c.add_argument("perf")
    c.add_argument("time")
    c.add_argument("metrics")
    c.add_argument("--input", required=True)
    c.add_argument("--parts", type=int, required=True)
    k = sub.add_parser("crop")
    k.add_argument("volume")
    k.add_argument("--parts", type=int, required=True)
    k.add_argument("--out", required=True)
    m = sub.add_parser("model")
    m.add_argument("work", nargs="+")
    m.add_argument("--pairs", action="append")
    a = ap.parse_args()
    {"classify": classify, "crop": crop, "model": model}[a.cmd](a)


if __name__ == "__main__":
    sys.exit(main())
