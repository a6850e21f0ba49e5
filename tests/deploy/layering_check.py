#!/usr/bin/env python3
"""Checks the include and link graphs against docs/layering.md (the one home of the rules).

  layering_check.py --root SRC --links BUILD/layering_links.txt
  layering_check.py --root SRC --self-test     breaks a copy of the rules and expects errors

Fails (exit 1, one line per culprit) on an #include "..." crossing an arrow the table does not
list, on a link between the project's targets the table does not list, on an include of a
library that none of the including library's targets links (directly or through others), on
an include that reaches another library's files past its include root (<code>/include/, the
only public part of a library) or is spelled through a root's own path, and on a library file
that does not open its library's namespace (the namespace table).
The links file is written by tests/layering/CMakeLists.txt at generate time: one line per
target, `target: dep;dep;...` (its LINK_LIBRARIES and INTERFACE_LINK_LIBRARIES).
"""
import argparse
import os
import re
import sys

SKIP_DIRS = {".git", "node_modules", "tests", "build", "deploy", "examples", "docs"}
# Where a quoted include is looked up besides the including file's own folder and the
# libraries' include roots: the repository's root (on the programs' path) and the folders the
# tests' internal targets add.
EXTRA_ROOTS = ["", "core/src", "core/io"]
GENERATED = (".pb.h",)  # generated into the build tree: public without an include root


def parse_rules(text):
    """Rows of the table: name -> (targets, code paths, may-use set or None for '*')."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 4 or cells[0] in ("library", "") or set(cells[0]) <= set("-"):
            continue
        name, targets, code, uses = cells
        split = lambda s: [x.strip() for x in s.split(",") if x.strip() and x.strip() != "—"]
        rows[name] = (split(targets), split(code), None if uses == "*" else set(split(uses)))
    if not rows:
        raise SystemExit("layering_check: no rules table in the rules file")
    for name, (_, _, uses) in rows.items():
        for u in uses or ():
            if u not in rows:
                raise SystemExit(f"layering_check: row {name} may use unknown library {u}")
    return rows


def library_of(path, rows):
    """The row whose code path is the longest prefix of path (relative, '/'-separated)."""
    best, best_len = None, -1
    for name, (_, code, _) in rows.items():
        for c in code:
            hit = path == c if not c.endswith("/") else path.startswith(c)
            if hit and len(c) > best_len:
                best, best_len = name, len(c)
    return best


def parse_namespaces(text):
    """The namespace table (| library | namespace |): name -> namespace, '—' for none."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if (len(cells) == 2 and cells[0] not in ("library", "") and "/" not in cells[0]
                and not set(cells[0]) <= set("-")):
            out[cells[0]] = cells[1].strip("`")
    return out


def include_roots(root, rows):
    """Library -> its include roots ('<code>/include/', relative, '/'-terminated)."""
    out = {}
    for name, (_, code, _) in rows.items():
        out[name] = [c if c.endswith("include/") else c + "include/" for c in code
                     if c.endswith("/") and (c.endswith("include/") or
                                             os.path.isdir(os.path.join(root, c, "include")))]
    return out


def resolve(root, src_dir, inc, roots):
    if inc.endswith(GENERATED):
        return "proto/" + os.path.basename(inc)
    for base in [src_dir] + roots + EXTRA_ROOTS:
        cand = os.path.normpath(os.path.join(base, inc))
        if os.path.isfile(os.path.join(root, cand)):
            return cand.replace(os.sep, "/")
    return None


def library_files(root, rows):
    """(relative path, library, text) of every .cc/.h file that belongs to a library."""
    for d, dirs, files in os.walk(root):
        rel_dir = os.path.relpath(d, root)
        dirs[:] = [x for x in dirs if x not in SKIP_DIRS and not x.startswith("build")]
        for f in sorted(files):
            if not f.endswith((".cc", ".h")):
                continue
            rel = os.path.normpath(os.path.join(rel_dir, f)).replace(os.sep, "/")
            lib = library_of(rel, rows)
            if lib is not None:
                with open(os.path.join(root, rel), encoding="utf-8") as fh:
                    yield rel, lib, fh.read()


def include_arrows(root, rows, files):
    """(from library, to library, file, include, included file) for every include crossing
    libraries."""
    out = []
    roots = [r.rstrip("/") for rs in include_roots(root, rows).values() for r in rs]
    for rel, src, text in files:
        for m in re.finditer(r'^\s*#\s*include\s+"([^"]+)"', text, re.M):
            target = resolve(root, os.path.dirname(rel), m.group(1), roots)
            lib = library_of(target, rows) if target else None
            if lib is not None and lib != src:
                out.append((src, lib, rel, m.group(1), target))
    return out


def past_roots(root, rows, arrows, files):
    """Includes that reach another library past its include root, or name a root's path."""
    roots = include_roots(root, rows)
    errors = []
    for src, dst, path, inc, target in arrows:
        if target.endswith(GENERATED) or any(target.startswith(r) for r in roots[dst]):
            continue
        where = (f"only {', '.join(roots[dst])} is public" if roots[dst]
                 else f"{dst} has no include root (<code>/include/)")
        errors.append(f'{path}: #include "{inc}" reaches {target}, inside {dst}: {where}')
    for path, _, text in files:
        for m in re.finditer(r'^\s*#\s*include\s+"((?:[^"]*/)?include/[^"]*)"', text, re.M):
            errors.append(f'{path}: #include "{m.group(1)}" names an include root\'s path: '
                          f"include it as the root spells it (tandem/...)")
    return errors


def declares(text):
    """Whether a file declares anything a namespace should hold: not a header of macros alone,
    nor a program's main file."""
    if re.search(r"^int main\(", text, re.M):
        return False
    code = re.sub(r"//[^\n]*|/\*.*?\*/", "", text, flags=re.S)
    code = re.sub(r"^\s*#(?:[^\n]*\\\n)*[^\n]*", "", code, flags=re.M)
    return bool(code.strip())


def namespace_errors(rows, namespaces, files):
    """Library files that open no namespace of their library's, or another library's."""
    errors = []
    for name in rows:
        if name not in namespaces:
            errors.append(f"docs/layering.md: library {name} has no row in the namespace table")
    for path, lib, text in files:
        ns = namespaces.get(lib, "—")
        if ns in ("—", ""):
            continue
        opened = re.findall(r"^\s*namespace\s+(tandem[\w:]*)\s*\{", text, re.M)
        inside = lambda n: n == ns or n.startswith(ns + "::")
        if not any(inside(n) for n in opened) and declares(text):
            errors.append(f"{path}: opens no namespace {ns} ({lib}'s)")
        for n in opened:
            if not inside(n):
                errors.append(f"{path}: opens namespace {n}, outside {lib}'s {ns}")
    return errors


def parse_test_rules(text):
    """The tests' tables: folder -> the library whose internals it tests
    (| test folder | internals of |), and file -> (library, why) for the listed exceptions
    (| test file | internals of | why |)."""
    folders, files = {}, {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not cells or not cells[0].startswith("tests/"):
            continue
        if len(cells) == 2:
            folders[cells[0].rstrip("/") + "/"] = cells[1]
        elif len(cells) == 3:
            files[cells[0]] = cells[1]
    return folders, files


def test_files(root):
    for d, dirs, files in os.walk(os.path.join(root, "tests")):
        dirs[:] = [x for x in dirs if x != "node_modules" and not x.startswith("build")]
        for f in sorted(files):
            if f.endswith((".cc", ".h")):
                rel = os.path.relpath(os.path.join(d, f), root).replace(os.sep, "/")
                with open(os.path.join(root, rel), encoding="utf-8") as fh:
                    yield rel, fh.read()


def test_errors(root, rules_text):
    """A test includes the libraries' public roots; a test folder also the internals of the
    one library it tests, a listed file those of the library listed for it."""
    rows = parse_rules(rules_text)
    folders, exceptions = parse_test_rules(rules_text)
    roots = include_roots(root, rows)
    all_roots = [r.rstrip("/") for rs in roots.values() for r in rs]
    errors = []
    for rel, text in test_files(root):
        folder = max((f for f in folders if rel.startswith(f)), key=len, default=None)
        own = {folders[folder]} if folder else set()
        if rel in exceptions:
            own.add(exceptions[rel])
        for m in re.finditer(r'^\s*#\s*include\s+"([^"]+)"', text, re.M):
            inc = m.group(1)
            if "/include/" in "/" + inc:
                errors.append(f'{rel}: #include "{inc}" names an include root\'s path: '
                              f"include it as the root spells it (tandem/...)")
                continue
            target = resolve(root, os.path.dirname(rel), inc, all_roots)
            lib = library_of(target, rows) if target else None
            if (lib is None or target.endswith(GENERATED) or lib in own
                    or any(target.startswith(r) for r in roots[lib])):
                continue
            own_text = f"{folders[folder]}'s, which {folder} tests" if folder else "none"
            errors.append(f'{rel}: #include "{inc}" reaches {target}, inside {lib}: a test '
                          f"includes public roots and one library's internals ({own_text}; "
                          f"docs/layering.md's test tables)")
    return errors


def export_errors(root, rows, includes_text, build=None):
    """A target of the table that exports a source folder other than an include/ root (the
    repository's root above all): its users could reach every library's internals."""
    errors = []
    src = os.path.realpath(root)
    targets = {t for ts, _, _ in rows.values() for t in ts}
    for t, dirs in parse_links(includes_text).items():
        for d in dirs:
            if d.startswith("$<INSTALL_INTERFACE:"):
                continue
            d = re.sub(r"^\$<BUILD_INTERFACE:(.*)>$", r"\1", d)
            real = os.path.realpath(d)
            under = lambda top: real == top or real.startswith(top + os.sep)
            inside = under(src) and not (build and under(os.path.realpath(build)))
            if t in targets and inside and os.path.basename(real) != "include":
                rel = os.path.relpath(real, src).replace(os.sep, "/")
                errors.append(f"target {t} exports {rel if rel != '.' else 'the repository root'}"
                              f": a target exports only include roots (<code>/include/)")
    return errors


def parse_links(text):
    links = {}
    for line in text.splitlines():
        if ":" in line:
            t, deps = line.split(":", 1)
            links[t.strip()] = [d for d in deps.strip().split(";") if d]
    return links


def check(root, rules_text, links_text, includes_text=None, build=None):
    rows = parse_rules(rules_text)
    errors = []
    allowed = lambda a, b: rows[a][2] is None or b in rows[a][2]
    files = list(library_files(root, rows))
    arrows = include_arrows(root, rows, files)
    for src, dst, path, inc, target in arrows:
        if not allowed(src, dst):
            errors.append(f'{path}: #include "{inc}" makes {src} use {dst}, '
                          f"which docs/layering.md does not allow")
    errors += past_roots(root, rows, arrows, files)
    errors += namespace_errors(rows, parse_namespaces(rules_text), files)
    errors += test_errors(root, rules_text)
    if includes_text is not None:
        errors += export_errors(root, rows, includes_text, build)
    if links_text is None:
        return errors
    links = parse_links(links_text)
    lib_of_target = {t: name for name, (ts, _, _) in rows.items() for t in ts}
    for t in lib_of_target:
        if t not in links:
            errors.append(f"docs/layering.md names target {t}, which the build does not define")
    for t, deps in links.items():
        for d in deps:
            d = re.sub(r"^\$<LINK_ONLY:(.*)>$", r"\1", d)
            a, b = lib_of_target.get(t), lib_of_target.get(d)
            if a and b and a != b and not allowed(a, b):
                errors.append(f"target {t} links {d}: {a} -> {b} is not in docs/layering.md")

    def closure(lib):
        seen, todo = set(), list(rows[lib][0])
        while todo:
            t = todo.pop()
            for d in links.get(t, []):
                d = re.sub(r"^\$<LINK_ONLY:(.*)>$", r"\1", d)
                if d in lib_of_target and d not in seen:
                    seen.add(d)
                    todo.append(d)
        return {lib_of_target[t] for t in seen}

    for src, dst, path, inc, _ in arrows:
        if rows[src][2] is not None and allowed(src, dst) and dst not in closure(src):
            errors.append(f'{path}: #include "{inc}" uses {dst}, which no target of {src} links')
    return errors


def self_test(root, rules_text, links_text):
    """The checker must catch a forbidden include arrow and a forbidden link."""
    rows = parse_rules(rules_text)
    if check(root, rules_text, links_text):
        return ["self-test: the real tree must pass before the self-test"]
    problems = []
    # Forbid every arrow of io: its includes of the engine must now fail.
    broken = re.sub(r"^(\| io \|[^|]*\|[^|]*\|)[^|]*\|", r"\1 — |", rules_text, flags=re.M)
    if not any("makes io use engine" in e for e in check(root, broken, links_text)):
        problems.append("self-test: an io -> engine include was not caught with the arrow gone")
    if links_text is not None and "tandem_io" in rows["io"][0]:
        fake = links_text + "\ntandem_core: tandem_io\n"
        if not any("tandem_core links tandem_io" in e for e in check(root, rules_text, fake)):
            problems.append("self-test: an engine -> io link was not caught")
    problems += synthetic_self_test()
    problems += own_namespace_self_test(rules_text)
    return problems


def own_namespace_self_test(rules_text):
    """A file of io and one of the module loader that open only `namespace tandem` (the
    engine's) must each be reported under the real table."""
    import tempfile
    rows, namespaces = parse_rules(rules_text), parse_namespaces(rules_text)
    problems = []
    for lib in ("io", "module"):
        code = [c for c in rows[lib][1] if c.endswith("/")]
        ns = namespaces.get(lib, "—")
        if not code or ns in ("—", "", "tandem"):
            problems.append(f"self-test: {lib} has no namespace of its own in docs/layering.md")
            continue
        rel = code[0] + "stray.cc"
        with tempfile.TemporaryDirectory() as tree:
            os.makedirs(os.path.join(tree, code[0]))
            with open(os.path.join(tree, rel), "w", encoding="utf-8") as fh:
                fh.write("namespace tandem {\nint Stray();\n}  // namespace tandem\n")
            errors = namespace_errors(rows, namespaces, library_files(tree, rows))
        if not any(e.startswith(f"{rel}: opens no namespace {ns}") for e in errors):
            problems.append(f"self-test: not caught: {rel} opening tandem, not {ns}")
    return problems


def synthetic_self_test():
    """A two-library tree with one of each culprit: each must be reported."""
    import tempfile
    rules = ("| library | targets | code | may use |\n|---|---|---|---|\n"
             "| a | ta | a/ | — |\n| b | tb | b/ | a |\n\n"
             "| library | namespace |\n|---|---|\n| a | `tandem::a` |\n| b | `tandem::b` |\n\n"
             "| test folder | internals of |\n|---|---|\n| tests/a | a |\n| tests/b | b |\n\n"
             "| test file | internals of | why |\n|---|---|---|\n"
             "| tests/b/listed_test.cc | a | its reason |\n")
    files = {
        "a/include/tandem/a/pub.h": "namespace tandem::a {}\n",
        "a/own.h": "namespace tandem::a {}\n",
        "b/past.cc": '#include "a/own.h"\nnamespace tandem::b {}\n',
        "b/spelled.cc": '#include "a/include/tandem/a/pub.h"\nnamespace tandem::b {}\n',
        "b/fine.cc": '#include "tandem/a/pub.h"\nnamespace tandem::b {}\n',
        "b/stray.cc": "namespace tandem::a {}\n",
        "b/none.cc": "namespace {}\n",
        "b/macros.h": "// Only macros.\n#define B_ONE 1\n#define B_TWO \\\n  2\n",
        "tests/a/own_test.cc": '#include "a/own.h"\n',
        "tests/b/reach_test.cc": '#include "a/own.h"\n',
        "tests/b/listed_test.cc": '#include "a/own.h"\n',
        "tests/b/spelled_test.cc": '#include "a/include/tandem/a/pub.h"\n',
        "tests/b/pub_test.cc": '#include "tandem/a/pub.h"\n#include "b/past.cc"\n',
        "tests/c/loose_test.cc": '#include "b/past.cc"\n',
    }
    expect = ['b/past.cc: #include "a/own.h" reaches a/own.h, inside a',
              'b/spelled.cc: #include "a/include/tandem/a/pub.h" names an include root',
              "b/stray.cc: opens no namespace tandem::b",
              "b/stray.cc: opens namespace tandem::a, outside b's",
              "b/none.cc: opens no namespace tandem::b",
              'tests/b/reach_test.cc: #include "a/own.h" reaches a/own.h, inside a',
              'tests/b/spelled_test.cc: #include "a/include/tandem/a/pub.h" names an include',
              'tests/c/loose_test.cc: #include "b/past.cc" reaches b/past.cc, inside b',
              "target ta exports the repository root"]
    with tempfile.TemporaryDirectory() as tree:
        for rel, text in files.items():
            os.makedirs(os.path.join(tree, os.path.dirname(rel)), exist_ok=True)
            with open(os.path.join(tree, rel), "w", encoding="utf-8") as fh:
                fh.write(text)
        errors = check(tree, rules, None, f"ta: {tree}\ntb: $<BUILD_INTERFACE:{tree}/b/include>\n")
    missed = [e for e in expect if not any(x.startswith(e) for x in errors)]
    extra = [x for x in errors if not any(x.startswith(e) for e in expect)]
    return ([f"self-test: not caught: {e}" for e in missed] +
            [f"self-test: reported on a sound file: {x}" for x in extra])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--rules", default=None, help="default: ROOT/docs/layering.md")
    ap.add_argument("--links", default=None, help="BUILD/layering_links.txt")
    ap.add_argument("--includes", default=None,
                    help="BUILD/layering_includes.txt: each target's exported include folders")
    ap.add_argument("--self-test", action="store_true")
    args = ap.parse_args()
    rules_path = args.rules or os.path.join(args.root, "docs", "layering.md")
    with open(rules_path, encoding="utf-8") as fh:
        rules_text = fh.read()
    links_text = None
    if args.links:
        with open(args.links, encoding="utf-8") as fh:
            links_text = fh.read()
    includes_text, build = None, None
    if args.includes:
        with open(args.includes, encoding="utf-8") as fh:
            includes_text = fh.read()
        build = os.path.dirname(os.path.abspath(args.includes))
    errors = check(args.root, rules_text, links_text, includes_text, build)
    if args.self_test and not errors:
        errors = self_test(args.root, rules_text, links_text)
    for e in errors:
        print(e)
    print(f"layering_check: {len(errors)} problem(s)")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
