#!/usr/bin/env python3
"""Static checks of everything in deploy/ (CI: ctest deploy_manifests). Needs python3-yaml.

Every *.yaml / *.yml under deploy/ is parsed (all documents). Kubernetes documents need
apiVersion, kind and metadata.name, and then, by kind:
  Deployment   selector matches the pod labels; every container has an image, cpu and
               memory requests and limits (requests <= limits), liveness and readiness
               probes on a declared container port, and the restricted security context:
               runAsNonRoot, readOnlyRootFilesystem, allowPrivilegeEscalation: false,
               capabilities.drop [ALL], seccompProfile RuntimeDefault (pod or container
               level); runAsUser, if set, is the Dockerfile's USER.
  Service      ports (port, targetPort naming a container port), a selector that selects
               a Deployment's pods.
  HorizontalPodAutoscaler  autoscaling/v2, scaleTargetRef names a Deployment here,
               min <= max replicas, a cpu Resource metric.
  PodDisruptionBudget      selects a Deployment's pods.
  NetworkPolicy  when a container serves --metrics-listen beyond loopback (plain HTTP, no
               authentication), a NetworkPolicy must select its pods for Ingress, admit
               the metrics port only from selected pods (a namespaceSelector or podSelector
               with labels; no ipBlock, no rule open to every source), and still admit the
               gRPC port.
The Compose file (a document with "services"): every service has image or build; the
server (the service whose image runs tandem-server) has a healthcheck; every service running
tandem-client depends on the server with condition: service_healthy.
deploy/Dockerfile: two or more stages FROM Debian 12; the build stage runs
deploy/install-deps.sh --product (what the programs need, not the tests) and configures with
-DTANDEM_BUILD_TESTS=OFF; the final stage runs install-deps.sh --runtime, copies only
tandem-server and tandem-client from the build stage (and the installed share/tandem and
lib/tandem, the viewer's files and the DICOM and viewer modules), runs as USER 10001, EXPOSEs 50051
(the port the Kubernetes container declares), has a HEALTHCHECK, and an exec-form
ENTRYPOINT ["tandem-server"].
--self-test breaks copies of the real files in memory and checks each break is reported.
"""

import argparse
import copy
import glob
import os
import re
import sys

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dockerfile  # noqa: E402

try:
    import yaml
except ImportError:
    print("FAIL: python3-yaml is missing (deploy/install-deps.sh installs it)", file=sys.stderr)
    sys.exit(1)

IMAGE_USER = "10001"
PORT = 50051


def parse_quantity(q):
    """Kubernetes quantity -> float (cpu in cores, memory in bytes)."""
    s = str(q).strip()
    m = re.fullmatch(r"([0-9.]+)([a-zA-Z]*)", s)
    if not m:
        raise ValueError(f"bad quantity {q!r}")
    n, unit = float(m.group(1)), m.group(2)
    factors = {"": 1, "m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12,
               "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
    if unit not in factors:
        raise ValueError(f"bad quantity unit in {q!r}")
    return n * factors[unit]


def get(d, *path, default=None):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return default
        d = d[key]
    return d


def selects(selector, labels):
    return bool(selector) and all(labels.get(k) == v for k, v in selector.items())


class Checker:
    def __init__(self):
        self.errors = []
        self.checked = []

    def err(self, where, what):
        self.errors.append(f"{where}: {what}")

    # --- Kubernetes -------------------------------------------------------------------
    def check_k8s(self, docs, image_user):
        deployments = [(w, d) for w, d in docs if d.get("kind") == "Deployment"]
        for where, d in docs:
            for key in ("apiVersion", "kind"):
                if not d.get(key):
                    self.err(where, f"missing {key}")
            if not get(d, "metadata", "name"):
                self.err(where, "missing metadata.name")
            self.checked.append(f"{where} {d.get('kind')}/{get(d, 'metadata', 'name')}")
        for where, d in deployments:
            self.check_deployment(where, d, image_user)
        self.check_network_policies(docs, deployments)
        pod_labels = [get(d, "spec", "template", "metadata", "labels", default={}) or {}
                      for _, d in deployments]
        container_ports = {}
        for _, d in deployments:
            for c in get(d, "spec", "template", "spec", "containers", default=[]) or []:
                for p in c.get("ports", []) or []:
                    container_ports[p.get("name")] = p.get("containerPort")
                    container_ports[p.get("containerPort")] = p.get("containerPort")
        names = {get(d, "metadata", "name") for _, d in deployments}
        for where, d in docs:
            kind = d.get("kind")
            if kind == "Service":
                ports = get(d, "spec", "ports", default=[]) or []
                if not ports:
                    self.err(where, "Service has no spec.ports")
                for p in ports:
                    if not p.get("port"):
                        self.err(where, f"Service port without 'port': {p}")
                    target = p.get("targetPort", p.get("port"))
                    if target not in container_ports:
                        self.err(where, f"Service targetPort {target!r} is no container port "
                                        f"of the Deployment ({sorted(map(str, container_ports))})")
                sel = get(d, "spec", "selector", default={}) or {}
                if not any(selects(sel, labels) for labels in pod_labels):
                    self.err(where, f"Service selector {sel} selects no Deployment's pods")
            elif kind == "HorizontalPodAutoscaler":
                if d.get("apiVersion") != "autoscaling/v2":
                    self.err(where, f"HPA apiVersion is {d.get('apiVersion')}, want autoscaling/v2")
                ref = get(d, "spec", "scaleTargetRef", default={}) or {}
                if ref.get("kind") != "Deployment" or ref.get("name") not in names:
                    self.err(where, f"HPA scaleTargetRef {ref} is not a Deployment defined here "
                                    f"({sorted(names)})")
                lo, hi = get(d, "spec", "minReplicas", default=1), get(d, "spec", "maxReplicas")
                if not isinstance(hi, int) or lo > hi:
                    self.err(where, f"HPA needs minReplicas <= maxReplicas (got {lo}, {hi})")
                metrics = get(d, "spec", "metrics", default=[]) or []
                if not any(get(m, "resource", "name") == "cpu" for m in metrics):
                    self.err(where, "HPA has no cpu Resource metric")
            elif kind == "PodDisruptionBudget":
                sel = get(d, "spec", "selector", "matchLabels", default={}) or {}
                if not any(selects(sel, labels) for labels in pod_labels):
                    self.err(where, f"PDB selector {sel} selects no Deployment's pods")
        return container_ports

    def check_deployment(self, where, d, image_user):
        spec = get(d, "spec", "template", "spec", default={}) or {}
        labels = get(d, "spec", "template", "metadata", "labels", default={}) or {}
        if not selects(get(d, "spec", "selector", "matchLabels", default={}), labels):
            self.err(where, "spec.selector.matchLabels does not match the pod template labels")
        pod_sc = spec.get("securityContext", {}) or {}
        containers = spec.get("containers", []) or []
        if not containers:
            self.err(where, "Deployment has no containers")
        for c in containers:
            cw = f"{where} container {c.get('name')}"
            if not c.get("image"):
                self.err(cw, "no image")
            res = c.get("resources", {}) or {}
            for kind in ("requests", "limits"):
                for r in ("cpu", "memory"):
                    if get(res, kind, r) is None:
                        self.err(cw, f"no resources.{kind}.{r}")
            for r in ("cpu", "memory"):
                req, lim = get(res, "requests", r), get(res, "limits", r)
                try:
                    if req is not None and lim is not None and \
                            parse_quantity(req) != parse_quantity(lim):
                        self.err(cw, f"resources.requests.{r} {req} != limits.{r} {lim}: "
                                     "the pod must be Guaranteed QoS")
                except ValueError as e:
                    self.err(cw, str(e))
            ports = {p.get("containerPort") for p in c.get("ports", []) or []}
            names = {p.get("name") for p in c.get("ports", []) or []}
            for probe in ("livenessProbe", "readinessProbe"):
                p = c.get(probe)
                if not p:
                    self.err(cw, f"no {probe}")
                    continue
                grpc_port = get(p, "grpc", "port")
                if grpc_port is None and "exec" not in p:
                    self.err(cw, f"{probe} is neither a grpc probe nor an exec health check")
                if grpc_port is not None and grpc_port not in ports | names:
                    self.err(cw, f"{probe} probes port {grpc_port}, not a declared containerPort")
            self.check_termination(cw, c, spec)
            for a in (c.get("args") or []):
                if isinstance(a, str) and a.startswith("--metrics-listen="):
                    mport = int(a.rsplit(":", 1)[1])
                    if mport not in ports:
                        self.err(cw, f"--metrics-listen port {mport} is not a declared "
                                     "containerPort")
            sc = c.get("securityContext", {}) or {}

            def eff(*path):
                v = get(sc, *path)
                return v if v is not None else get(pod_sc, *path)
            if eff("runAsNonRoot") is not True:
                self.err(cw, "securityContext.runAsNonRoot must be true")
            if sc.get("readOnlyRootFilesystem") is not True:
                self.err(cw, "securityContext.readOnlyRootFilesystem must be true")
            if sc.get("allowPrivilegeEscalation") is not False:
                self.err(cw, "securityContext.allowPrivilegeEscalation must be false")
            if "ALL" not in (get(sc, "capabilities", "drop", default=[]) or []):
                self.err(cw, "securityContext.capabilities.drop must contain ALL")
            if eff("seccompProfile", "type") != "RuntimeDefault":
                self.err(cw, "seccompProfile.type must be RuntimeDefault")
            if sc.get("privileged"):
                self.err(cw, "privileged container")
            user = eff("runAsUser")
            if user is not None and image_user is not None and str(user) != image_user:
                self.err(cw, f"runAsUser {user} differs from the Dockerfile's USER {image_user}")

    def check_network_policies(self, docs, deployments):
        """A metrics port bound beyond loopback has no authentication: a NetworkPolicy must
        admit only Prometheus's pods to it, and still admit the gRPC port."""
        policies = [(w, d) for w, d in docs if d.get("kind") == "NetworkPolicy"]

        def selective(sel):
            return isinstance(sel, dict) and bool(sel.get("matchLabels") or
                                                  sel.get("matchExpressions"))

        def restricted(peer):
            return "ipBlock" not in peer and (selective(peer.get("podSelector")) or
                                              selective(peer.get("namespaceSelector")))

        for where, d in deployments:
            labels = get(d, "spec", "template", "metadata", "labels", default={}) or {}
            for c in get(d, "spec", "template", "spec", "containers", default=[]) or []:
                cw = f"{where} container {c.get('name')}"
                listen = next((a.split("=", 1)[1] for a in (c.get("args") or [])
                               if isinstance(a, str) and a.startswith("--metrics-listen=")), None)
                if not listen:
                    continue
                host, port = listen.rsplit(":", 1)
                if host.strip("[]") in ("localhost", "::1") or host.startswith("127."):
                    continue
                mport = int(port)
                ports = c.get("ports", []) or []
                metrics = {mport} | {p.get("name") for p in ports if p.get("containerPort") == mport}
                grpc = {PORT} | {p.get("name") for p in ports if p.get("containerPort") == PORT}
                selecting = [(w, p) for w, p in policies
                             if selects(get(p, "spec", "podSelector", "matchLabels",
                                            default={}), labels)
                             and "Ingress" in (get(p, "spec", "policyTypes") or ["Ingress"])]
                if not selecting:
                    self.err(cw, f"--metrics-listen {listen} serves metrics without "
                                 "authentication and no NetworkPolicy selects the pods: add one "
                                 f"that admits only Prometheus to port {mport}")
                    continue
                grpc_admitted = False
                for pw, p in selecting:
                    for rule in get(p, "spec", "ingress", default=[]) or []:
                        rports = rule.get("ports") or []

                        def covers(names):
                            return not rports or any(rp.get("port") in names or
                                                     rp.get("port") is None for rp in rports)
                        grpc_admitted |= covers(grpc)
                        peers = rule.get("from") or []
                        if covers(metrics) and (not peers or
                                                not all(restricted(x) for x in peers)):
                            self.err(pw, f"the metrics port {mport} is admitted from every "
                                         "source or an ipBlock: admit only Prometheus's pods "
                                         "(a namespaceSelector and podSelector with labels)")
                if not grpc_admitted:
                    self.err(cw, f"no NetworkPolicy rule admits the gRPC port {PORT}: clients "
                                 "and the probes could not reach it")

    def check_termination(self, cw, c, spec):
        """The pod's grace period covers the server's drain: delay + grace + 30 s for the
        workers; a drain delay needs a liveness probe that stays SERVING meanwhile."""
        def arg(name, default):
            for a in (c.get("args") or []) + (c.get("command") or []):
                if isinstance(a, str) and a.startswith(f"--{name}="):
                    return float(a.split("=", 1)[1])
            return default
        delay, grace = arg("drain-delay-seconds", 0.0), arg("grace-seconds", 10.0)
        need = delay + grace + 30
        have = spec.get("terminationGracePeriodSeconds", 30)
        if have < need:
            self.err(cw, f"terminationGracePeriodSeconds {have} < --drain-delay-seconds {delay:g}"
                         f" + --grace-seconds {grace:g} + 30 s for the workers")
        live = c.get("livenessProbe") or {}
        if delay > 0 and "grpc" in live and not get(live, "grpc", "service"):
            self.err(cw, "livenessProbe asks the empty service, NOT_SERVING during the drain "
                         "delay: use service: liveness")

    # --- Compose ----------------------------------------------------------------------
    def check_compose(self, where, doc):
        services = doc.get("services") or {}
        if not services:
            self.err(where, "Compose file without services")
            return
        self.checked.append(f"{where} compose services {sorted(services)}")

        def runs(svc, binary):
            entry = svc.get("entrypoint")
            if entry is not None:
                first = entry[0] if isinstance(entry, list) else str(entry).split()[0]
                return os.path.basename(first) == binary
            # No entrypoint override: the image's (tandem-server) when it is the runtime image.
            return binary == "tandem-server" and "target" not in (svc.get("build") or {})
        servers = [n for n, s in services.items() if runs(s or {}, "tandem-server")]
        clients = [n for n, s in services.items() if runs(s or {}, "tandem-client")]
        if not servers:
            self.err(where, "no service runs tandem-server")
        if not clients:
            self.err(where, "no service runs tandem-client")
        for name, svc in services.items():
            svc = svc or {}
            if not svc.get("image") and not svc.get("build"):
                self.err(where, f"service {name} has neither image nor build")
        for name in servers:
            hc = services[name].get("healthcheck") or {}
            if not hc.get("test") or hc.get("disable"):
                self.err(where, f"server service {name} has no healthcheck")
        for name in clients:
            deps = services[name].get("depends_on") or {}
            for server in servers:
                cond = get(deps, server, "condition") if isinstance(deps, dict) else None
                if cond != "service_healthy":
                    self.err(where, f"client service {name} must depend on {server} with "
                                    f"condition: service_healthy (has {deps})")

    # --- Dockerfile -------------------------------------------------------------------
    def check_dockerfile(self, where, text):
        try:
            _, stages = dockerfile.parse(text)
        except ValueError as e:
            self.err(where, str(e))
            return None
        self.checked.append(f"{where} stages {[s.name for s in stages]}")
        if len(stages) < 2:
            self.err(where, "not multi-stage")
            return None
        for s in stages:
            if not re.fullmatch(r"(docker\.io/)?(library/)?debian:(12|bookworm)([-.\w]*)?(@\S+)?",
                                s.base):
                self.err(where, f"stage {s.name or '?'} (line {s.line}) is FROM {s.base}, "
                                f"not Debian 12")
        runtime = stages[-1]
        copies = dockerfile.copy_sources(runtime)
        from_stage = {c[2] for c in copies if c[2]}
        build = next((s for s in stages if s.name in from_stage), None)
        if build is None:
            self.err(where, "the final stage copies nothing from a named build stage")
        else:
            runs = " ; ".join(i.args for i in build.all("RUN"))
            if not re.search(r"(^|[\s;&|])(bash\s+)?(\./)?deploy/install-deps\.sh\s+--product"
                             r"\s*(&&|;|$)", runs):
                self.err(where, "the build stage does not run deploy/install-deps.sh --product "
                                "(the programs' packages)")
            if "-DTANDEM_BUILD_TESTS=OFF" not in runs:
                self.err(where, "the build stage does not configure -DTANDEM_BUILD_TESTS=OFF")
        runs = " ; ".join(i.args for i in runtime.all("RUN"))
        if not re.search(r"install-deps\.sh\s+--runtime", runs):
            self.err(where, "the final stage does not install deploy/install-deps.sh --runtime")
        # Besides the two binaries, only the installed data folder (the viewer's page and
        # three.js, `cmake --install` into a staging prefix) and the modules' folder (DICOM,
        # viewer) may come from the build stage.
        shared = [s for c in copies if c[2] for s in c[0]
                  if s.rstrip("/").endswith(("/share/tandem", "/lib/tandem"))]
        copied = sorted(os.path.basename(s) for c in copies if c[2] for s in c[0] if s not in shared)
        if copied != ["tandem-client", "tandem-server"]:
            self.err(where, f"the final stage copies {copied} from the build stage; want only "
                            f"tandem-server and tandem-client (and share/tandem, lib/tandem)")
        user = runtime.last("USER")
        image_user = user.args.split(":")[0] if user else None
        if image_user != IMAGE_USER:
            self.err(where, f"the final stage runs as USER {image_user}, want {IMAGE_USER}")
        exposed = {p.split("/")[0] for i in runtime.all("EXPOSE") for p in i.args.split()}
        if str(PORT) not in exposed:
            self.err(where, f"the final stage does not EXPOSE {PORT}")
        hc = dockerfile.healthcheck_of(runtime)
        if hc is None or hc[1] is None:
            self.err(where, "the final stage has no HEALTHCHECK")
        try:
            argv = dockerfile.command_line(runtime)
            ep = dockerfile.exec_or_shell(runtime.last("ENTRYPOINT").args) \
                if runtime.last("ENTRYPOINT") else None
            if ep != ["tandem-server"]:
                self.err(where, f'ENTRYPOINT is {ep}, want ["tandem-server"]')
            del argv
        except ValueError as e:
            self.err(where, str(e))
        return image_user


def load(deploy_dir):
    """(yaml docs [(where, doc)], dockerfile text or None), paths relative to deploy/.."""
    root = os.path.dirname(os.path.abspath(deploy_dir))
    files = sorted(glob.glob(os.path.join(deploy_dir, "**", "*.yaml"), recursive=True) +
                   glob.glob(os.path.join(deploy_dir, "**", "*.yml"), recursive=True))
    docs = []
    for path in files:
        rel = os.path.relpath(path, root)
        with open(path) as f:
            for i, doc in enumerate(yaml.safe_load_all(f)):
                if doc is not None:
                    docs.append((f"{rel}#{i}", doc))
    text = None
    dfile = os.path.join(deploy_dir, "Dockerfile")
    if os.path.exists(dfile):
        with open(dfile) as f:
            text = f.read()
    return docs, text


def check(docs, dockerfile_text):
    c = Checker()
    image_user = IMAGE_USER
    if dockerfile_text is not None:
        image_user = c.check_dockerfile("deploy/Dockerfile", dockerfile_text)
    k8s = []
    for where, doc in docs:
        if not isinstance(doc, dict):
            c.err(where, "not a mapping")
        elif "kind" in doc or "apiVersion" in doc:
            k8s.append((where, doc))
        elif "services" in doc:
            c.check_compose(where, doc)
        else:
            c.err(where, "neither a Kubernetes object nor a Compose file")
    if not any(d.get("kind") == "Deployment" for _, d in k8s):
        c.err("deploy/", "no Kubernetes Deployment found")
    ports = c.check_k8s(k8s, image_user)
    if PORT not in ports:
        c.err("deploy/k8s", f"no container declares port {PORT} (the Dockerfile's EXPOSE)")
    return c


def self_test(docs, text):
    """Each mutation of the real files must produce an error mentioning `expect`."""
    def first(kind):
        return next(d for _, d in docs if isinstance(d, dict) and d.get("kind") == kind)

    def container(ds):
        return next(d for _, d in ds if d.get("kind") == "Deployment")[
            "spec"]["template"]["spec"]["containers"][0]

    def compose(ds):
        return next(d for _, d in ds if "services" in d)

    def first_in(ds, kind):
        return next(d for _, d in ds if isinstance(d, dict) and d.get("kind") == kind)
    cases = [
        ("readOnlyRootFilesystem", lambda ds: container(ds)["securityContext"].pop(
            "readOnlyRootFilesystem")),
        ("capabilities.drop", lambda ds: container(ds)["securityContext"].pop("capabilities")),
        ("resources.limits.memory", lambda ds: container(ds)["resources"]["limits"].pop("memory")),
        ("readinessProbe", lambda ds: container(ds).pop("readinessProbe")),
        ("terminationGracePeriodSeconds", lambda ds: next(d for _, d in ds if d.get("kind") ==
                                                          "Deployment")["spec"]["template"]
         ["spec"].update(terminationGracePeriodSeconds=130)),
        ("Guaranteed QoS", lambda ds: container(ds)["resources"]["limits"].update(cpu="4")),
        ("--metrics-listen port", lambda ds: container(ds)["ports"].pop()),
        ("service: liveness", lambda ds: container(ds)["livenessProbe"]["grpc"].pop("service")),
        ("no image", lambda ds: container(ds).pop("image")),
        ("scaleTargetRef", lambda ds: next(d for _, d in ds if d.get("kind") ==
                                           "HorizontalPodAutoscaler")["spec"]["scaleTargetRef"]
         .update(name="nope")),
        ("selects no Deployment", lambda ds: next(d for _, d in ds if d.get("kind") == "Service")
         ["spec"].update(selector={"app": "other"})),
        ("no NetworkPolicy selects the pods", lambda ds: ds.__setitem__(
            slice(None), [(w, d) for w, d in ds if d.get("kind") != "NetworkPolicy"])),
        ("admitted from every source", lambda ds: first_in(ds, "NetworkPolicy")["spec"]
         ["ingress"][1].pop("from")),
        ("admitted from every source", lambda ds: first_in(ds, "NetworkPolicy")["spec"]
         ["ingress"][1]["from"].append({"ipBlock": {"cidr": "0.0.0.0/0"}})),
        ("admits the gRPC port", lambda ds: first_in(ds, "NetworkPolicy")["spec"]
         ["ingress"].pop(0)),
        ("service_healthy", lambda ds: compose(ds)["services"]["client"].pop("depends_on")),
        ("neither image nor build", lambda ds: [compose(ds)["services"]["sample"].pop(k, None)
                                                for k in ("image", "build")]),
    ]
    first("Deployment")  # the real files must have one
    failed = 0
    for expect, mutate in cases:
        ds = copy.deepcopy([(w, d) for w, d in docs])
        mutate(ds)
        errors = check(ds, text).errors
        if not any(expect in e for e in errors):
            print(f"self-test FAIL: breaking '{expect}' was not reported ({errors})")
            failed += 1
    for expect, mutated in [("USER", re.sub(r"(?m)^USER .*$", "", text)),
                            ("HEALTHCHECK", re.sub(r"(?ms)^HEALTHCHECK .*?\n(?=\S)", "", text)),
                            ("--runtime", text.replace("--runtime", "")),
                            ("--product", text.replace("--product", "")),
                            ("Debian 12", text.replace("debian:12", "ubuntu:24.04"))]:
        if not any(expect in e for e in check(docs, mutated).errors):
            print(f"self-test FAIL: breaking '{expect}' in the Dockerfile was not reported")
            failed += 1
    print(f"self-test: {len(cases) + 5 - failed} of {len(cases) + 5} breaks reported")
    return failed == 0


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--deploy-dir", default=os.path.join(here, "..", "..", "deploy"))
    ap.add_argument("--self-test", action="store_true")
    args = ap.parse_args()
    docs, text = load(args.deploy_dir)
    c = check(docs, text)
    for line in c.checked:
        print(f"checked {line}")
    if c.errors:
        for e in c.errors:
            print(f"FAIL: {e}", file=sys.stderr)
        return 1
    if args.self_test and not self_test(docs, text):
        return 1
    print(f"PASS: {len(docs)} YAML documents and the Dockerfile")
    return 0


if __name__ == "__main__":
    sys.exit(main())
