"""A small Dockerfile reader for the deploy checks (no Docker needed).

Handles what deploy/Dockerfile uses: comments, parser directives, backslash line
continuations, ARG substitution in FROM, named stages, ENV in both forms (k=v ... and the
legacy "k v"), exec-form (JSON) and shell-form ENTRYPOINT / CMD / HEALTHCHECK CMD, EXPOSE,
USER, COPY (with --from=, --chown=), RUN.
"""

import json
import re
import shlex


class Instruction:
    def __init__(self, keyword, args, line):
        self.keyword = keyword  # upper case
        self.args = args  # the text after the keyword, continuations joined
        self.line = line  # 1-based line of the keyword

    def __repr__(self):
        return f"{self.keyword} {self.args} (line {self.line})"


class Stage:
    def __init__(self, base, name, line):
        self.base = base
        self.name = name
        self.line = line
        self.instructions = []

    def all(self, keyword):
        return [i for i in self.instructions if i.keyword == keyword]

    def last(self, keyword):
        found = self.all(keyword)
        return found[-1] if found else None


def read_instructions(text):
    """Returns the instructions in order, with continuation lines joined."""
    out = []
    pending, start = None, 0
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.rstrip("\n")
        stripped = line.strip()
        if pending is None:
            if not stripped or stripped.startswith("#"):
                continue
            pending, start = "", number
        elif stripped.startswith("#"):
            continue  # comment lines inside a continued instruction are dropped
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        pending += line
        keyword, _, args = pending.strip().partition(" ")
        out.append(Instruction(keyword.upper(), args.strip(), start))
        pending = None
    if pending is not None:
        keyword, _, args = pending.strip().partition(" ")
        out.append(Instruction(keyword.upper(), args.strip(), start))
    return out


def parse(text):
    """Returns (global_args, stages): global ARG defaults and the stages in order."""
    global_args, stages = {}, []
    for ins in read_instructions(text):
        if ins.keyword == "ARG" and not stages:
            name, _, default = ins.args.partition("=")
            global_args[name.strip()] = default.strip()
            continue
        if ins.keyword == "FROM":
            words = [w for w in ins.args.split() if not w.startswith("--")]
            base = re.sub(r"\$\{?(\w+)\}?", lambda m: global_args.get(m.group(1), m.group(0)),
                          words[0])
            name = words[2] if len(words) >= 3 and words[1].upper() == "AS" else None
            stages.append(Stage(base, name, ins.line))
            continue
        if not stages:
            raise ValueError(f"line {ins.line}: {ins.keyword} before the first FROM")
        stages[-1].instructions.append(ins)
    return global_args, stages


def exec_or_shell(args):
    """ENTRYPOINT/CMD/HEALTHCHECK CMD argument: a list (exec form) or a str (shell form)."""
    args = args.strip()
    if args.startswith("["):
        value = json.loads(args)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ValueError(f"exec form must be a JSON array of strings: {args}")
        return value
    return args


def env_of(stage, stages):
    """ENV of a stage, inherited from the stage it is built FROM when that is a stage."""
    env = {}
    parent = next((s for s in stages if s.name and s.name == stage.base), None)
    if parent is not None:
        env.update(env_of(parent, stages))
    for ins in stage.all("ENV"):
        words = shlex.split(ins.args)
        if words and "=" not in words[0]:  # legacy form: ENV key value with spaces
            key, _, value = ins.args.partition(" ")
            env[key] = value.strip()
            continue
        for word in words:
            key, sep, value = word.partition("=")
            if not sep:
                raise ValueError(f"line {ins.line}: ENV word without '=': {word}")
            env[key] = re.sub(r"\$\{?(\w+)\}?", lambda m: env.get(m.group(1), ""), value)
    return env


def healthcheck_of(stage):
    """(options dict, command as list or str) of the stage's HEALTHCHECK, or None."""
    ins = stage.last("HEALTHCHECK")
    if ins is None:
        return None
    rest = ins.args
    options = {}
    while rest.startswith("--"):
        word, _, rest = rest.partition(" ")
        key, _, value = word[2:].partition("=")
        options[key] = value
        rest = rest.strip()
    if rest.upper() == "NONE":
        return options, None
    keyword, _, command = rest.partition(" ")
    if keyword.upper() != "CMD":
        raise ValueError(f"line {ins.line}: HEALTHCHECK needs CMD or NONE")
    return options, exec_or_shell(command)


def command_line(stage):
    """The exec-form ENTRYPOINT + CMD of a stage (raises on shell form: it loses signals)."""
    ep = stage.last("ENTRYPOINT")
    cmd = stage.last("CMD")
    entry = exec_or_shell(ep.args) if ep else []
    args = exec_or_shell(cmd.args) if cmd else []
    if isinstance(entry, str) or isinstance(args, str):
        raise ValueError("ENTRYPOINT and CMD must use the exec (JSON array) form, so that "
                         "tandem-server is PID 1 and receives SIGTERM")
    return entry + args


def copy_sources(stage):
    """[(sources, destination, from_stage_or_None)] of the stage's COPY instructions."""
    out = []
    for ins in stage.all("COPY"):
        words = shlex.split(ins.args)
        src_from = None
        while words and words[0].startswith("--"):
            key, _, value = words.pop(0)[2:].partition("=")
            if key == "from":
                src_from = value
        out.append((words[:-1], words[-1], src_from))
    return out
