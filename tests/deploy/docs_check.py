#!/usr/bin/env python3
"""Checks the promises the docs make about themselves:
- README.md is a front page: at most 250 lines, its first two lines the two set-up commands,
  and the second of them is what .ci/run runs first;
- the README's C++ snippet is examples/sphere.cc as it is built and run (from its includes on);
- every relative link in README.md and docs/*.md points at a file that exists.
Exit 0 when all hold, 1 with one line per broken promise otherwise."""
import argparse
import os
import re
import sys


def check(root):
    problems = []
    readme = open(os.path.join(root, "README.md"), encoding="utf-8").read()
    lines = readme.split("\n")
    if len(lines) > 251:  # the final newline leaves one empty element
        problems.append(f"README.md has {len(lines) - 1} lines; the front page keeps to 250")
    if not (lines[0].strip().startswith("bash deploy/install-deps.sh") and
            lines[1].strip() == "bash tests/run.sh"):
        problems.append("README.md's first two lines must be the two set-up commands")
    ci = open(os.path.join(root, ".ci", "run"), encoding="utf-8").read()
    if "\nbash tests/run.sh\n" not in ci:
        problems.append(".ci/run does not run the README's test command (bash tests/run.sh)")
    m = re.search(r"```cpp\n(.*?)```", readme, re.S)
    example = open(os.path.join(root, "examples", "sphere.cc"), encoding="utf-8").read()
    example = example[example.index("#include"):]
    if not m or m.group(1) != example:
        problems.append("README.md's C++ snippet differs from examples/sphere.cc (from its "
                        "first #include): copy the example into the README")
    pages = ["README.md"] + [os.path.join("docs", f) for f in sorted(os.listdir(
        os.path.join(root, "docs"))) if f.endswith(".md")]
    for page in pages:
        text = open(os.path.join(root, page), encoding="utf-8").read()
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path = os.path.normpath(os.path.join(root, os.path.dirname(page), target))
            if not os.path.exists(path):
                problems.append(f"{page}: link to {target}, which does not exist")
    return problems


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--root", required=True)
    problems = check(ap.parse_args().root)
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
