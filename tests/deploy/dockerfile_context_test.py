#!/usr/bin/env python3
"""Replays deploy/Dockerfile's build stage on the host, without Docker, up to CMake configure.

Copies exactly what the build stage COPYs (with Docker's COPY semantics) into a scratch
folder and runs the stage's `cmake -S . -B ...` configure line there (same -D options).
Catches a Dockerfile that forgets a folder the build now needs, or options that no longer
configure. Then checks that the build system it generates has the targets the runtime stage
copies (COPY --from=<build stage> <dir>/bin/<target>). Packages are not installed here:
deploy/install-deps.sh is what the host ran already (the same script the stage runs).
"""

import argparse
import fnmatch
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dockerfile  # noqa: E402


class Failure(Exception):
    pass


def dockerignore(context):
    """The patterns of CONTEXT/.dockerignore (comments and blank lines dropped)."""
    path = os.path.join(context, ".dockerignore")
    if not os.path.exists(path):
        raise Failure("no .dockerignore: the build context would include build trees and .git")
    with open(path) as f:
        return [ln.strip().rstrip("/") for ln in f if ln.strip() and not ln.startswith("#")]


def ignored(rel, patterns):
    """Docker's rule, as far as these patterns go: a path is excluded when it or one of its
    parent folders matches a pattern (`**/` matches any depth, including none)."""
    parts = rel.split("/")
    for i in range(1, len(parts) + 1):
        prefix = "/".join(parts[:i])
        for p in patterns:
            if fnmatch.fnmatchcase(prefix, p) or (
                    p.startswith("**/") and fnmatch.fnmatchcase(parts[i - 1], p[3:])):
                return True
    return False


def docker_copy(context, sources, dest, root, patterns):
    """Docker COPY of context-relative sources to dest (relative to root = WORKDIR),
    without what .dockerignore excludes."""
    target = os.path.join(root, dest)
    into_dir = dest.endswith("/") or dest in (".", "./") or len(sources) > 1
    for src in sources:
        path = os.path.join(context, src)
        if not os.path.exists(path):
            raise Failure(f"COPY {src}: not in the build context {context}")
        if ignored(os.path.normpath(src), patterns):
            raise Failure(f"COPY {src}: excluded from the build context by .dockerignore")

        def skip(folder, names):
            rel = os.path.relpath(folder, context)
            return [n for n in names
                    if ignored(os.path.normpath(os.path.join(rel, n)), patterns)]
        if os.path.isdir(path):  # a folder's contents go to dest
            shutil.copytree(path, target, dirs_exist_ok=True, ignore=skip)
        elif into_dir:
            os.makedirs(target, exist_ok=True)
            shutil.copy2(path, os.path.join(target, os.path.basename(src)))
        else:
            os.makedirs(os.path.dirname(target) or ".", exist_ok=True)
            shutil.copy2(path, target)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dockerfile", required=True)
    ap.add_argument("--context", required=True, help="the repository root (build context)")
    args = ap.parse_args()

    with open(args.dockerfile) as f:
        _, stages = dockerfile.parse(f.read())
    runtime = stages[-1]
    from_copies = [c for c in dockerfile.copy_sources(runtime) if c[2]]
    if not from_copies:
        raise Failure("the final stage copies nothing from a build stage")
    build_name = from_copies[0][2]
    build = next((s for s in stages if s.name == build_name), None)
    if build is None:
        raise Failure(f"COPY --from={build_name}: no stage of that name")

    workdir = "/"
    for ins in build.instructions:
        if ins.keyword == "WORKDIR":
            workdir = ins.args.strip()
    configure = None
    for ins in build.all("RUN"):
        m = re.search(r"cmake\s+-S\s+(\S+)\s+-B\s+(\S+)((?:\s+-D\S+)*)", ins.args)
        if m:
            configure = m
    if configure is None:
        raise Failure("the build stage has no `cmake -S SRC -B BUILD -D...` configure step")
    source_dir, build_dir, options = configure.group(1), configure.group(2), \
        shlex.split(configure.group(3))

    patterns = dockerignore(args.context)
    for must in (".git", "build*", "node_modules"):
        if must not in patterns:
            raise Failure(f".dockerignore does not exclude {must}")
    with tempfile.TemporaryDirectory(prefix="tandem-docker-context-") as tmp:
        root = os.path.join(tmp, workdir.lstrip("/"))
        os.makedirs(root, exist_ok=True)
        for sources, dest, src_from in dockerfile.copy_sources(build):
            if src_from is None:
                docker_copy(args.context, sources, dest, root, patterns)
        src = os.path.normpath(os.path.join(root, source_dir))
        out = os.path.join(tmp, build_dir.lstrip("/"))
        cmd = ["cmake", "-S", src, "-B", out] + options
        print("configure:", " ".join(cmd[:1] + ["-S", source_dir, "-B", build_dir] + options))
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            raise Failure(f"the build stage's configure fails on exactly the COPYed files:\n"
                          f"{r.stdout[-3000:]}{r.stderr[-3000:]}")
        help_out = subprocess.run(["cmake", "--build", out, "--target", "help"],
                                  capture_output=True, text=True, timeout=120).stdout
        targets = set(re.findall(r"^\.\.\. (\S+)", help_out, re.M))
        build_runs = " ; ".join(i.args for i in build.all("RUN"))
        for sources, _, src_from in from_copies:
            for s in sources:
                # The installed data (viewer page, three.js) and the DICOM module:
                # `cmake --install BUILD --prefix P` puts them in P/share/tandem and
                # P/lib/tandem (the module's target must exist).
                m = re.search(r"cmake\s+--install\s+(\S+)\s+--prefix\s+(\S+)", build_runs)
                prefix = m.group(2).rstrip("/") if m and m.group(1) == build_dir else None
                if prefix and s.rstrip("/") == prefix + "/share/tandem":
                    continue
                if prefix and s.rstrip("/") == prefix + "/lib/tandem":
                    if targets and "tandem_dicom" not in targets:
                        raise Failure(f"COPY --from={src_from} {s}: the configured build has "
                                      f"no target tandem_dicom (the DICOM module)")
                    continue
                if not s.startswith(build_dir.rstrip("/") + "/bin/"):
                    raise Failure(f"COPY --from={src_from} {s}: executables land in "
                                  f"{build_dir}/bin/ (CMAKE_RUNTIME_OUTPUT_DIRECTORY)")
                name = os.path.basename(s)
                if targets and name not in targets:
                    raise Failure(f"COPY --from={src_from} {s}: the configured build has no "
                                  f"target {name}")
        print(f"PASS: the build stage configures from its COPYed files and builds "
              f"{', '.join(os.path.basename(s) for c in from_copies for s in c[0])}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Failure as e:
        print(f"FAIL: {e}", file=sys.stderr)
        sys.exit(1)
