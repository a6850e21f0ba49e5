#!/usr/bin/env python3
"""Mesh files that other programs open: `tandem extract --out` as .ply, .obj, .stl and .glb
(plain, and Draco-compressed with --glb-draco: decoded by three.js's Draco decoder),
each read back by an independent reader (assimp, Debian's assimp-utils) with the counts the
CLI reported, and the .glb checked by the Khronos glTF validator (npm gltf-validator, from
package-lock.json via deploy/install-web.sh) with no error and no warning.
Exit 77 (ctest SKIP) with a message when assimp or the validator is not installed."""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile


def run(cmd):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin-dir", required=True)
    ap.add_argument("--source-dir", required=True)
    a = ap.parse_args()
    validator = os.path.join(a.source_dir, "node_modules", "gltf-validator")
    if shutil.which("assimp") is None or shutil.which("node") is None or not os.path.isdir(validator):
        print("SKIP: needs assimp (deploy/install-deps.sh) and node with gltf-validator "
              "(deploy/install-web.sh)")
        return 77
    tandem = os.path.join(a.bin_dir, "tandem")
    failures = []
    with tempfile.TemporaryDirectory() as d:
        vol = os.path.join(d, "link.json")
        r = run([tandem, "generate", "link", "--size", "48", "--out", vol])
        if r.returncode != 0:
            print(r.stdout, r.stderr)
            return 1
        for ext in ["ply", "obj", "stl", "glb", "draco.glb"]:
            out = os.path.join(d, "link." + ext)
            extra = ["--glb-draco"] if ext == "draco.glb" else []
            r = run([tandem, "extract", "--input", vol, "--error", "0.3", "--out", out] + extra)
            m = re.search(r"triangles final\s+(\d+) \((\d+) vertices\)", r.stdout + r.stderr)
            if r.returncode != 0 or not m:
                failures.append(f"{ext}: tandem extract failed: {r.stdout}{r.stderr}")
                continue
            triangles, vertices = int(m.group(1)), int(m.group(2))
            if ext == "draco.glb":  # assimp reads no Draco: the validator and Draco's decoder
                v = run(["node", os.path.join(a.source_dir, "tests", "formats", "validate_gltf.mjs"),
                         out, str(vertices), str(triangles)])
                print(v.stdout.strip())
                if v.returncode != 0:
                    failures.append(f"draco.glb: {v.stdout}{v.stderr}")
                continue
            info = run(["assimp", "info", out])
            faces = re.search(r"Faces:\s+(\d+)", info.stdout)
            verts = re.search(r"Vertices:\s+(\d+)", info.stdout)
            if info.returncode != 0 or not faces or int(faces.group(1)) != triangles:
                failures.append(f"{ext}: assimp read {faces and faces.group(1)} faces, "
                                f"expected {triangles}: {info.stdout[-400:]}{info.stderr[-400:]}")
            # STL has no shared vertices: only its faces are compared.
            elif ext != "stl" and (not verts or int(verts.group(1)) != vertices):
                failures.append(f"{ext}: assimp read {verts and verts.group(1)} vertices, "
                                f"expected {vertices}")
            else:
                print(f"ok {ext}: assimp reads {triangles} triangles" +
                      ("" if ext == "stl" else f", {vertices} vertices"))
            if ext == "glb":
                v = run(["node", os.path.join(a.source_dir, "tests", "formats", "validate_gltf.mjs"),
                         out, str(vertices), str(triangles)])
                print(v.stdout.strip())
                if v.returncode != 0:
                    failures.append(f"glb: the glTF validator says: {v.stdout}{v.stderr}")
    for f in failures:
        print("FAIL", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
