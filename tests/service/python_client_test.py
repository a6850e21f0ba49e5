#!/usr/bin/env python3
"""The Python client (client/python/tandem_client.py) against the real tandem-server.

Starts tandem-server on 127.0.0.1, streams a NumPy volume through tandem_client.extract
and checks: the counts equal `tandem extract`'s on the same voxels (the README's promise
for every client), the Draco bytes decode (Debian's draco_decoder) to a PLY with exactly
the counts the server reported, uint16 / int16 / uint8 volumes are accepted, a big-endian
array is converted rather than misread, and bad requests come back as the server's status
(INVALID_ARGUMENT with its message) or a ValueError before anything is sent.
Run by ctest with PYTHONPATH=build/python; exits 77 (skip) without grpcio.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

try:
    import grpc
    import numpy as np
    import tandem_client
except ImportError as e:  # python3-grpcio / python3-protobuf / the generated stubs
    print(f"skipped: {e}")
    sys.exit(77)

failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        failures.append(what)


def ply_counts(path):
    """(vertices, faces) from a PLY header."""
    v = f = None
    with open(path, "rb") as fh:
        for raw in fh:
            line = raw.decode("ascii", "replace").strip()
            if line.startswith("element vertex"):
                v = int(line.split()[2])
            elif line.startswith("element face"):
                f = int(line.split()[2])
            elif line == "end_header":
                break
    return v, f


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin-dir", required=True)
    args = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="tandem-python-")
    server = subprocess.Popen(
        [os.path.join(args.bin_dir, "tandem-server"), "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = server.stdout.readline()  # "listening on HOST:PORT"
        check(line.startswith("listening on "), f"server started ({line.strip()!r})")
        address = line.split()[-1]

        # A float32 field, written as raw + JSON sidecar for the local CLI too.
        z, y, x = np.mgrid[-1:1:40j, -1:1:36j, -1:1:32j]
        vol = (x * x / 0.8 + y * y + z * z / 1.2).astype(np.float32)
        spacing = (0.06, 0.05, 0.05)
        raw = os.path.join(tmp, "v.raw")
        vol.astype("<f4").tofile(raw)
        with open(os.path.join(tmp, "v.json"), "w") as fh:
            json.dump({"dims": [32, 36, 40], "dtype": "float32", "spacing": list(spacing),
                       "origin": [0, 0, 0], "byte_order": "little", "raw_file": "v.raw"}, fh)
        subprocess.run([os.path.join(args.bin_dir, "tandem"), "extract", "--input",
                        os.path.join(tmp, "v.json"), "--iso", "0.5", "--error", "0.01",
                        "--out", os.path.join(tmp, "local.ply"), "--metrics",
                        os.path.join(tmp, "local.json")], check=True,
                       stdout=subprocess.DEVNULL)
        local = json.load(open(os.path.join(tmp, "local.json")))

        progress = []
        result = tandem_client.extract(vol, iso=0.5, error=0.01, server=address,
                                       spacing=spacing, preview_every=10,
                                       on_progress=progress.append)
        m = result.metrics
        check(m.triangles_final > 100, f"a surface came back ({m.triangles_final} triangles)")
        check((m.triangles_final, m.vertices_final, m.triangles_extracted) ==
              (local["triangles_final"], local["vertices_final"], local["triangles_extracted"]),
              f"counts equal tandem extract's ({m.triangles_final}, {m.vertices_final}, "
              f"{m.triangles_extracted} vs {local['triangles_final']}, "
              f"{local['vertices_final']}, {local['triangles_extracted']})")
        check(m.slices == 40 and (m.nx, m.ny, m.nz) == (32, 36, 40), "grid as sent, [z, y, x]")
        check(len(progress) > 0 and progress[-1].slices_consumed <= 40, "progress reported")
        check(len(result.previews) > 0, f"previews ({len(result.previews)})")

        drc = os.path.join(tmp, "remote.drc")
        result.save(drc)
        ply = os.path.join(tmp, "remote.ply")
        tandem_client.draco_to_ply(drc, ply)
        check(ply_counts(ply) == (m.vertices_final, m.triangles_final),
              f"the Draco bytes decode to the reported counts {ply_counts(ply)}")

        check(len(result.session_id) == 32, f"the stream's id ({result.session_id!r})")
        check(len(result.watch_key) == 32 and result.watch_key != result.session_id,
              f"the stream's watch key ({result.watch_key!r})")

        # NumPy arrays of the decoded mesh: the reported counts, indices in range, and the
        # local run's vertices (within Draco's quantization of the box).
        verts, faces = result.vertices, result.faces
        check(verts.shape == (m.vertices_final, 3) and verts.dtype == np.float32 and
              faces.shape == (m.triangles_final, 3) and faces.dtype == np.uint32 and
              int(faces.max()) < len(verts),
              f"vertices {verts.shape} {verts.dtype}, faces {faces.shape} {faces.dtype}")
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        box = np.array([31 * spacing[0], 35 * spacing[1], 39 * spacing[2]])
        check(bool((lo >= -1e-3).all() and (hi <= box + 1e-3).all()),
              f"vertices inside the grid's box ({lo}, {hi})")

        # Sealed chunks: in order, together the final mesh's triangles, and no FinalMesh.
        sealed = tandem_client.extract(vol, iso=0.5, error=0.01, server=address,
                                       spacing=spacing, sealed_chunks=True)
        check(len(sealed.sealed) >= 1 and sealed.draco == b"" and
              sum(c.triangles for c in sealed.sealed) == sealed.metrics.triangles_final and
              sealed.metrics.sealed_chunks == len(sealed.sealed),
              f"sealed chunks ({len(sealed.sealed)}, "
              f"{sum(c.triangles for c in sealed.sealed)} triangles of "
              f"{sealed.metrics.triangles_final})")
        check(sealed.faces.shape == (sealed.metrics.triangles_final, 3) and
              len(sealed.vertices) == sealed.metrics.vertices_final,
              f"sealed chunks welded by position: {len(sealed.vertices)} vertices, "
              f"{len(sealed.faces)} faces (reported {sealed.metrics.vertices_final}, "
              f"{sealed.metrics.triangles_final})")

        # Chunks welded by position: two triangles sent in two chunks share an edge.
        a = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
        b = (np.array([[1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
        wv, wf = tandem_client.weld_by_position([a, b])
        check(len(wv) == 4 and wf.shape == (2, 3) and
              set(map(tuple, wv[wf[0]])) >= {(1, 0, 0), (0, 1, 0)} and
              len(set(wf[0]) & set(wf[1])) == 2, "chunks weld into one mesh by position")

        # Integer types, and a big-endian array (converted, not misread as noise).
        for dtype, scale in ((np.uint16, 1000), (np.int16, 1000), (np.uint8, 100),
                             (np.uint32, 100000), (np.int64, 1000)):
            r = tandem_client.extract((vol * scale).astype(dtype), iso=0.5 * scale,
                                      error=0.01, server=address, spacing=spacing)
            check(r.metrics.triangles_final > 100, f"{np.dtype(dtype).name} volume meshed "
                  f"({r.metrics.triangles_final} triangles)")
        big = tandem_client.extract(vol.astype(">f4"), iso=0.5, error=0.01, server=address,
                                    spacing=spacing)
        check(big.metrics.triangles_final == m.triangles_final,
              "a big-endian float32 array gives the same mesh")

        # Errors: the server's status with its message; local checks before sending.
        try:
            tandem_client.extract(vol, iso=0.5, error=-1, server=address)
            check(False, "E0 < 0 refused")
        except grpc.RpcError as e:
            check(e.code() == grpc.StatusCode.INVALID_ARGUMENT and "error" in e.details(),
                  f"E0 < 0: {e.code().name}: {e.details()}")
        for bad, what in ((vol.astype(np.float64), "float64"), (vol[0], "2-D")):
            try:
                tandem_client.extract(bad, iso=0.5, error=0.01, server=address)
                check(False, f"{what} volume refused")
            except ValueError as e:
                check(True, f"{what} volume refused locally: {e}")

        # The module's command line: .npy in, .ply out.
        npy = os.path.join(tmp, "v.npy")
        np.save(npy, vol)
        cli = subprocess.run([sys.executable, tandem_client.__file__, "--server", address,
                              "--input", npy, "--iso", "0.5", "--error", "0.01", "--spacing",
                              ",".join(map(str, spacing)), "--out",
                              os.path.join(tmp, "cli.ply")],
                             capture_output=True, text=True)
        check(cli.returncode == 0 and
              ply_counts(os.path.join(tmp, "cli.ply"))[1] == m.triangles_final,
              f"python3 tandem_client.py --out cli.ply ({cli.stdout.strip()}{cli.stderr.strip()})")

        # --out names the format: STL and OBJ as their readers expect, .glb refused (exit 2)
        # before anything is streamed.
        def run_cli(out):
            return subprocess.run([sys.executable, tandem_client.__file__, "--server", address,
                                   "--input", npy, "--iso", "0.5", "--error", "0.01",
                                   "--spacing", ",".join(map(str, spacing)), "--out", out],
                                  capture_output=True, text=True)
        stl = os.path.join(tmp, "cli.stl")
        r = run_cli(stl)
        with open(stl, "rb") as fh:
            head = fh.read(84)
        stl_count = int.from_bytes(head[80:84], "little") if len(head) == 84 else -1
        check(r.returncode == 0 and not head.startswith(b"solid") and
              stl_count == m.triangles_final and
              os.path.getsize(stl) == 84 + 50 * m.triangles_final,
              f"--out cli.stl is a binary STL of {stl_count} triangles ({r.stderr.strip()})")
        obj = os.path.join(tmp, "cli.obj")
        r = run_cli(obj)
        with open(obj) as fh:
            obj_lines = fh.read().splitlines()
        check(r.returncode == 0 and
              sum(ln.startswith("v ") for ln in obj_lines) == m.vertices_final and
              sum(ln.startswith("f ") for ln in obj_lines) == m.triangles_final,
              f"--out cli.obj holds the mesh ({r.stderr.strip()})")
        glb = os.path.join(tmp, "cli.glb")
        r = run_cli(glb)
        check(r.returncode == 2 and ".glb" in r.stderr and "extension" in r.stderr and
              not os.path.exists(glb), f"--out cli.glb refused with exit 2 ({r.stderr.strip()})")

        # A label map (two touching boxes, uint16): --labels gives one file per label, each
        # the triangles `tandem extract --labels` gives it.
        seg = np.zeros((20, 18, 16), np.uint16)
        seg[4:14, 4:14, 3:8], seg[4:14, 4:14, 8:13] = 3, 7
        seg.astype("<u2").tofile(os.path.join(tmp, "seg.raw"))
        with open(os.path.join(tmp, "seg.json"), "w") as fh:
            json.dump({"dims": [16, 18, 20], "dtype": "uint16", "spacing": [1, 1, 1],
                       "origin": [0, 0, 0], "byte_order": "little", "raw_file": "seg.raw"}, fh)
        subprocess.run([os.path.join(args.bin_dir, "tandem"), "extract", "--input",
                        os.path.join(tmp, "seg.json"), "--labels", "--error", "0.5", "--out",
                        os.path.join(tmp, "seg_local") + "/"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        np.save(os.path.join(tmp, "seg.npy"), seg)
        r = subprocess.run([sys.executable, tandem_client.__file__, "--server", address,
                            "--input", os.path.join(tmp, "seg.npy"), "--labels", "--error",
                            "0.5", "--out", os.path.join(tmp, "seg_py") + "/"],
                           capture_output=True, text=True)
        counts = {f: (ply_counts(os.path.join(tmp, "seg_py", f)),
                      ply_counts(os.path.join(tmp, "seg_local", f))) for f in ("3.ply", "7.ply")
                  if os.path.exists(os.path.join(tmp, "seg_py", f))}
        check(r.returncode == 0 and len(counts) == 2 and all(a == b for a, b in counts.values()),
              f"--labels writes a file per label as tandem extract --labels ({counts}, "
              f"{r.stdout.strip()}{r.stderr.strip()})")
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
    if failures:
        print(f"{len(failures)} check(s) failed", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
