#!/usr/bin/env python3
"""tandem-server reads no volume, so it must link none of the volume readers' libraries
(tandem_io and what it brings: libtiff, blosc, zstd, nifticlib; GDCM). Two checks:
- the link closure CMake computed for the target (a line per library: NAME<TAB>CHAIN), which
  holds even where the linker's --as-needed would drop an unused library from the binary;
- the binary's DT_NEEDED entries (readelf -d), what the container's runtime must provide.
Exit 0 when neither names a forbidden library, 1 with a line per culprit (and the chain of
targets that brings it) otherwise."""
import argparse
import re
import subprocess
import sys

FORBIDDEN = re.compile(r"tandem_io\b|tiff|blosc|zstd|nifti|znz|gdcm", re.IGNORECASE)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--closure", required=True, help="NAME<TAB>CHAIN lines written by CMake")
    ap.add_argument("--binary", required=True, help="the built tandem-server")
    args = ap.parse_args()
    problems = []
    with open(args.closure, encoding="utf-8") as f:
        for line in f:
            name, _, chain = line.rstrip("\n").partition("\t")
            if FORBIDDEN.search(name):
                problems.append(f"links {name} (through {chain})")
    needed = subprocess.run(["readelf", "-d", args.binary], capture_output=True, text=True)
    if needed.returncode != 0:
        print(f"readelf -d {args.binary} failed: {needed.stderr.strip()}")
        return 1
    for m in re.finditer(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", needed.stdout):
        if FORBIDDEN.search(m.group(1)):
            problems.append(f"needs {m.group(1)} at run time (readelf -d)")
    for p in problems:
        print(f"tandem-server {p}")
    if not problems:
        print("tandem-server links no volume reader library")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
