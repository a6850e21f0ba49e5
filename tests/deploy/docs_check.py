#!/usr/bin/env python3
"""Checks the promises the docs make about themselves:
- README.md is a front page: at most 250 lines, its first two lines the two set-up commands,
  and the second of them is what .ci/run runs first;
- the README's C++ snippet is examples/sphere.cc as it is built and run (from its includes on);
- every relative link in README.md and docs/*.md points at a file that exists;
- docs/decisions.md's entries are numbered headings in order and its index lists exactly them.
Exit 0 when all hold, 1 with one line per broken promise otherwise. `--fix-decisions` rewrites
the log's numbering and index (a new entry may be added as a `### Title` heading, or as a
paragraph opening with its **bold title**, anywhere in its part)."""
import argparse
import os
import re
import sys


def _anchor(title):
    return re.sub(r"[^a-z0-9 -]", "", title.lower()).replace(" ", "-")


def decisions_fixed(text):
    """The decision log with its entries numbered in order and its index rebuilt."""
    lines, out, entries = text.split("\n"), [], []
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln == "## Index":  # dropped here and rebuilt below
            i += 1
            while i < len(lines) and not lines[i].startswith("## "):
                i += 1
            continue
        if ln.startswith("## "):
            entries.append(("part", ln[3:]))
            out.append(ln)
        elif ln.startswith("### "):
            title = re.sub(r"^\d+\.\s*", "", ln[4:])
            entries.append(("entry", title))
            out.append(f"### {sum(k == 'entry' for k, _ in entries)}. {title}")
        elif ln.startswith("**") and (i == 0 or not lines[i - 1].strip()):
            para = ln
            while "**" not in para[2:] and i + 1 < len(lines):
                i += 1
                para += " " + lines[i]
            m = re.match(r"^\*\*(.+?)\*\*[:.]?\s*(.*)$", para)
            title = m.group(1).rstrip(".:")
            entries.append(("entry", title))
            out += [f"### {sum(k == 'entry' for k, _ in entries)}. {title}", ""]
            if m.group(2):
                out.append(m.group(2))
        else:
            out.append(ln)
        i += 1
    index, n = ["## Index"], 0
    for kind, title in entries:
        if kind == "part":
            index += ["", f"**{title}**", ""]
        else:
            n += 1
            index.append(f"- [{n}. {title}](#{_anchor(f'{n}. {title}')})")
    first = next(j for j, ln in enumerate(out) if ln.startswith("## "))
    return "\n".join(out[:first] + index + [""] + out[first:])


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
    log = open(os.path.join(root, "docs", "decisions.md"), encoding="utf-8").read()
    if decisions_fixed(log) != log:
        problems.append("docs/decisions.md: entries not numbered in order or the index out of "
                        "date (run tests/deploy/docs_check.py --root . --fix-decisions)")
    return problems


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--root", required=True)
    ap.add_argument("--fix-decisions", action="store_true")
    args = ap.parse_args()
    if args.fix_decisions:
        path = os.path.join(args.root, "docs", "decisions.md")
        text = open(path, encoding="utf-8").read()
        open(path, "w", encoding="utf-8").write(decisions_fixed(text))
    problems = check(args.root)
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
