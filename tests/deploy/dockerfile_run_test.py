#!/usr/bin/env python3
"""Runs deploy/Dockerfile's final stage on the host, without Docker.

Reads the runtime stage's ENTRYPOINT + CMD, ENV, EXPOSE and HEALTHCHECK and runs exactly
that command line (tandem-server from the build's bin folder, found through PATH as in the
image) with exactly that environment, except that the listen address becomes
127.0.0.1:<free port>, set through the same mechanism the Dockerfile uses (the --listen
flag if CMD/ENTRYPOINT has one, else TANDEM_LISTEN). Then:
  1. the server prints "listening on 127.0.0.1:<port>" (so TANDEM_LISTEN was honoured);
  2. the Dockerfile's own HEALTHCHECK command succeeds (SERVING), run as Docker would;
  3. `tandem-client info` answers, and shows the limits that CMD/ENV set;
  4. SIGTERM (the STOPSIGNAL) makes it exit 0.
A second run adds TANDEM_* variables to check that the environment configures what no flag
sets and that a flag beats its variable (the documented precedence).
Exit 77 (ctest SKIP) with a message when tandem-server / tandem-client are not built.
"""

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dockerfile  # noqa: E402

SKIP = 77

# tandem-client info line label -> (server flag, environment variable)
LIMITS = {
    "max sessions": ("--max-sessions", "TANDEM_MAX_SESSIONS"),
    "max voxels per slice": ("--max-voxels-per-slice", "TANDEM_MAX_VOXELS_PER_SLICE"),
    "max slices": ("--max-slices", "TANDEM_MAX_SLICES"),
    "max message bytes": ("--max-message-bytes", "TANDEM_MAX_MESSAGE_BYTES"),
}


class Failure(Exception):
    pass


def free_port():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def flag_value(argv, flag):
    for i, a in enumerate(argv):
        if a == flag and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith(flag + "="):
            return a[len(flag) + 1:]
    return None


def set_listen(argv, env, addr):
    """Points the command line at addr the way the Dockerfile configures it."""
    argv = list(argv)
    how = None
    for i, a in enumerate(argv):
        if a == "--listen" and i + 1 < len(argv):
            argv[i + 1] = addr
            how = "--listen flag"
        elif a.startswith("--listen="):
            argv[i] = "--listen=" + addr
            how = "--listen flag"
    if "TANDEM_LISTEN" in env:
        env["TANDEM_LISTEN"] = addr  # also keeps a shell-form HEALTHCHECK in step
        how = how or "TANDEM_LISTEN"
    if how is None:
        raise Failure("the Dockerfile sets the listen address neither with --listen in "
                      "ENTRYPOINT/CMD nor with ENV TANDEM_LISTEN")
    return argv, how


class Server:
    def __init__(self, argv, env, cwd, log_path):
        self.log = open(log_path, "w")
        self.proc = subprocess.Popen(argv, env=env, cwd=cwd, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=self.log, text=True)
        self.lines = []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_listening(self, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self.lines:
                if line.startswith("listening on "):
                    return line[len("listening on "):].strip()
            if self.proc.poll() is not None:
                return None
            time.sleep(0.05)
        return None

    def stop(self, sig=signal.SIGTERM, timeout=60):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return None
        finally:
            self.thread.join(timeout=5)
            self.log.close()

    def stderr_text(self):
        self.log.flush()
        with open(self.log.name) as f:
            return f.read()


def run(cmd, env, cwd, timeout=30):
    return subprocess.run(cmd, env=env, cwd=cwd, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=timeout)


def healthcheck_command(health, exposed, port):
    """The HEALTHCHECK command as Docker would run it, pointed at our port."""
    _, command = health
    if isinstance(command, str):
        return ["/bin/sh", "-c", command.replace(f":{exposed}", f":{port}")]
    return [a.replace(f":{exposed}", f":{port}") for a in command]


def parse_info(text):
    values = {}
    for line in text.splitlines():
        m = re.match(r"^(max [a-z ]+?)\s{2,}(\S+)", line)
        if m:
            values[m.group(1)] = m.group(2)
    return values


def start_checked(argv, env, workdir, addr, log_path, how):
    server = Server(argv, env, workdir, log_path)
    listening = server.wait_listening(30)
    if listening is None:
        rc = server.stop(signal.SIGKILL, 5)
        raise Failure(f"tandem-server did not print 'listening on ...' within 30 s "
                      f"(exit status {rc}); stderr:\n{server.stderr_text()}")
    if listening != addr:
        server.stop(signal.SIGKILL, 5)
        raise Failure(f"asked for {addr} through {how}, but tandem-server is listening on "
                      f"{listening}: it ignored {how}")
    return server


def expected_limits(argv, env):
    """What info must show: a flag on the command line wins over its variable."""
    out = {}
    for label, (flag, var) in LIMITS.items():
        value = flag_value(argv, flag)
        source = f"{flag} on the command line"
        if value is None and var in env:
            value, source = env[var], f"{var}={env[var]} in the environment"
        if value is not None:
            out[label] = (value, source)
    return out


def check_info(client_env, workdir, addr, argv, env):
    info = run(["tandem-client", "info", "--server", addr, "--timeout", "10"], client_env,
               workdir)
    if info.returncode != 0:
        raise Failure(f"tandem-client info --server {addr} failed ({info.returncode}):\n"
                      f"{info.stdout}{info.stderr}")
    shown = parse_info(info.stdout)
    for label, (value, source) in expected_limits(argv, env).items():
        if shown.get(label) != value:
            raise Failure(f"'{label}' is {shown.get(label)} but {source} asks for {value}; "
                          f"tandem-client info said:\n{info.stdout}")
    return info.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dockerfile", required=True)
    ap.add_argument("--bin-dir", required=True, help="the build's bin folder")
    args = ap.parse_args()

    bin_dir = os.path.abspath(args.bin_dir)
    missing = [b for b in ("tandem-server", "tandem-client")
               if not os.access(os.path.join(bin_dir, b), os.X_OK)]
    if missing:
        print(f"SKIP: {', '.join(missing)} not built in {bin_dir} (configure with "
              f"TANDEM_BUILD_SERVICE=ON and build them first); deploy/Dockerfile not run")
        return SKIP

    with open(args.dockerfile) as f:
        _, stages = dockerfile.parse(f.read())
    runtime = stages[-1]
    argv = dockerfile.command_line(runtime)
    if not argv or argv[0] != "tandem-server":
        raise Failure(f"the final stage's ENTRYPOINT + CMD should start with tandem-server: "
                      f"{argv}")
    image_env = dockerfile.env_of(runtime, stages)
    exposed = [p.split("/")[0] for ins in runtime.all("EXPOSE") for p in ins.args.split()]
    health = dockerfile.healthcheck_of(runtime)
    if health is None or health[1] is None:
        raise Failure("the final stage has no HEALTHCHECK")

    with tempfile.TemporaryDirectory(prefix="tandem-dockerfile-") as workdir:
        # The image's environment: its ENV over a bare base (no TANDEM_* from this host).
        base_env = {"PATH": f"{bin_dir}:/usr/local/bin:/usr/bin:/bin", "HOME": workdir,
                    "LANG": "C.UTF-8"}
        client_env = dict(base_env)

        # Run 1: exactly the image's command line and environment.
        port = free_port()
        addr = f"127.0.0.1:{port}"
        env = dict(base_env, **image_env)
        run_argv, how = set_listen(argv, env, addr)
        print(f"run 1: {' '.join(run_argv)}")
        print(f"       env {' '.join(f'{k}={v}' for k, v in image_env.items())} "
              f"(listen address through {how} -> {addr})")
        server = start_checked(run_argv, env, workdir, addr,
                               os.path.join(workdir, "server1.log"), how)
        try:
            hc = healthcheck_command(health, exposed[0] if exposed else "50051", port)
            deadline = time.monotonic() + 20
            while True:
                result = run(hc, env, workdir)
                if result.returncode == 0:
                    break
                if time.monotonic() > deadline:
                    raise Failure(f"the HEALTHCHECK command {hc} keeps failing "
                                  f"({result.returncode}):\n{result.stdout}{result.stderr}")
                time.sleep(0.5)
            print(f"HEALTHCHECK {hc}: {result.stdout.strip()}")
            check_info(client_env, workdir, addr, run_argv, env)
            print("tandem-client info: answers, limits as configured")
        finally:
            rc = server.stop(signal.SIGTERM, 60)
        if rc != 0:
            raise Failure(f"after SIGTERM tandem-server exited with {rc} (want 0); stderr:\n"
                          f"{server.stderr_text()}")
        print("SIGTERM: exited 0")

        # Run 2: the environment configures what no flag sets; a flag beats its variable.
        port = free_port()
        addr = f"127.0.0.1:{port}"
        env = dict(base_env, **image_env)
        env["TANDEM_MAX_SLICES"] = "1234"
        if flag_value(argv, "--max-sessions") is not None:
            env["TANDEM_MAX_SESSIONS"] = str(int(flag_value(argv, "--max-sessions")) + 1)
        run_argv, how = set_listen(argv, env, addr)
        extra = {k: env[k] for k in ("TANDEM_MAX_SLICES", "TANDEM_MAX_SESSIONS") if k in env}
        print(f"run 2: same, plus {' '.join(f'{k}={v}' for k, v in extra.items())}")
        server = start_checked(run_argv, env, workdir, addr,
                               os.path.join(workdir, "server2.log"), how)
        try:
            check_info(client_env, workdir, addr, run_argv, env)
            print("tandem-client info: environment honoured, flags win over variables")
        finally:
            rc = server.stop(signal.SIGTERM, 60)
        if rc != 0:
            raise Failure(f"after SIGTERM tandem-server exited with {rc} (want 0)")
    print("PASS: deploy/Dockerfile's command line serves on the host")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Failure as e:
        print(f"FAIL: {e}", file=sys.stderr)
        sys.exit(1)
