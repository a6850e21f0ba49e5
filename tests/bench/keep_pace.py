#!/usr/bin/env python3
"""Does a paced stream keep pace? (issue 25: "tandem-client stream --rate R keeps pace: at a
rate 80% of the measured maximum, the final mesh arrives within 2 s of the last slice and the
backlog never grows").

For each volume, against one tandem-server on 127.0.0.1 (default flags, except
--session-memory-mb when a volume needs more than the default budget):
  1. stream it unpaced, `--repeats` times: the measured maximum R_max = slices / median wall;
  2. stream it paced at --rate 0.8 R_max (`--verbose`: each Progress line carries the slices
     the server has consumed and the slices the client has sent), and record
     - the lag: the client's exit (final mesh and metrics received and written) minus the
       moment the last slice was due (first Progress + (nz - 1) / R: the client paces slice z
       at start + z / R, and sends nothing before the first Progress); and the arrival lag,
       the same for the moment the final mesh had arrived (--verbose's "received" line),
       before the client writes it (a sealed stream's .drc is the welded chunks encoded
       again, about 0.8 s for a million triangles);
     - the backlog, sent - consumed, at every Progress: its largest value, and its largest
       value over the first and over the second half of the stream (a backlog that "never
       grows" has a second-half maximum no larger than the first half's, give or take a
       slice of transport).
Nothing is asserted; the figures are printed as a Markdown table (and written to --report).

    /usr/bin/python3 tests/bench/keep_pace.py --bin build/bin --volume V.json [--volume ...]
        [--repeats 3] [--fraction 0.8] [--session-memory-mb N] [--seal] [--report FILE]
"""

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import dense  # noqa: E402  (Server: a tandem-server on a free loopback port)


def stream(client, address, volume, workdir, rate=0.0, extra=()):
    """One tandem-client stream; returns (wall s, progress [(t, consumed, sent)], t received)."""
    out = os.path.join(workdir, "out.drc")
    cmd = [client, "stream", "--server", address, "--input", volume, "--out", out,
           "--timeout", "3600", "--verbose", *extra]
    if rate > 0:
        cmd += ["--rate", f"{rate:.6g}"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    progress = []
    tail = []
    received = []

    def read():
        for line in proc.stderr:
            t = time.perf_counter() - t0
            tail.append(line)
            del tail[:-20]
            # Only the slice counts: a finishing line ("progress finishing=\"...\" ...") quotes
            # a phrase with spaces.
            if line.startswith("progress slices="):
                fields = dict(kv.split("=", 1) for kv in line.split()[1:])
                progress.append((t, int(fields["slices"]), int(fields["sent"])))
            elif line.startswith("received "):
                received.append(t)

    reader = threading.Thread(target=read)
    reader.start()
    rc = proc.wait()
    wall = time.perf_counter() - t0
    reader.join()
    if rc != 0:
        raise RuntimeError(f"tandem-client exited {rc}:\n{''.join(tail)}")
    return wall, progress, (received[0] if received else wall)


def paced_figures(wall, progress, nz, rate, received):
    first = progress[0][0]
    due = first + (nz - 1) / rate
    backlog = [(t, sent - consumed) for t, consumed, sent in progress if consumed > 0]
    mid = first + (nz / rate) / 2
    first_half = [b for t, b in backlog if t <= mid]
    second_half = [b for t, b in backlog if mid < t <= due]
    return {
        "lag_s": wall - due,
        "arrival_lag_s": received - due,
        "backlog_max": max((b for _, b in backlog), default=0),
        "backlog_first_half": max(first_half, default=0),
        "backlog_second_half": max(second_half, default=0),
    }


def nz_of(volume):
    import json
    with open(volume) as f:
        return int(json.load(f)["dims"][2])


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True, help="directory of tandem-server and tandem-client")
    ap.add_argument("--volume", action="append", required=True, help="a .json volume")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fraction", type=float, default=0.8)
    ap.add_argument("--session-memory-mb", type=int, default=0)
    ap.add_argument("--report", help="also write the table to this file")
    ap.add_argument("--seal", action="store_true",
                    help="stream with tandem-client --seal (sealed chunks)")
    args = ap.parse_args()
    extra = ["--seal"] if args.seal else []
    # A SIGTERM unwinds like an exception, so that the server below is stopped too.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    server_bin = os.path.join(args.bin, "tandem-server")
    client_bin = os.path.join(args.bin, "tandem-client")
    flags = ["--session-memory-mb", str(args.session_memory_mb)] if args.session_memory_mb else []
    rows = []
    with tempfile.TemporaryDirectory(prefix="keep-pace-") as work:
        server = dense.Server(server_bin, flags, os.path.join(work, "server.stderr"))
        try:
            for volume in args.volume:
                nz = nz_of(volume)
                walls = [stream(client_bin, server.address, volume, work, extra=extra)[0]
                         for _ in range(args.repeats)]
                r_max = nz / statistics.median(walls)
                rate = args.fraction * r_max
                wall, progress, received = stream(client_bin, server.address, volume, work, rate,
                                                  extra)
                f = paced_figures(wall, progress, nz, rate, received)
                rows.append((os.path.basename(volume), nz, walls, r_max, rate, wall, f))
                print(f"{os.path.basename(volume)}: R_max {r_max:.2f} slices/s (walls "
                      f"{', '.join(f'{w:.2f}' for w in walls)} s); at {rate:.2f} slices/s: mesh "
                      f"arrived {f['arrival_lag_s']:.2f} s and written {f['lag_s']:.2f} s after "
                      f"the last slice was due, backlog max {f['backlog_max']} (first half "
                      f"{f['backlog_first_half']}, second half {f['backlog_second_half']})",
                      flush=True)
        finally:
            server.stop()
    lines = ["| volume | slices | unpaced wall s (each run) | R_max slices/s | paced at | "
             "mesh arrived after the last slice | written | backlog max (1st half / 2nd half) |",
             "|---|---:|---|---:|---:|---:|---:|---|"]
    for name, nz, walls, r_max, rate, wall, f in rows:
        lines.append(f"| {name} | {nz} | {', '.join(f'{w:.2f}' for w in walls)} | {r_max:.2f} | "
                     f"{rate:.2f} | {f['arrival_lag_s']:.2f} s | {f['lag_s']:.2f} s | "
                     f"{f['backlog_max']} "
                     f"({f['backlog_first_half']} / {f['backlog_second_half']}) |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.report:
        with open(args.report, "w") as out:
            out.write(table)


if __name__ == "__main__":
    main()
