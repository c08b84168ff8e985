"""Worker processes on this machine (``igi render``, ``igi serve``, benchmarks): started with
this Python, connected to a master's endpoint, stopped together; a dead one is a
:class:`~master.errors.UsageError`. :func:`local_cluster`: a loopback master with such workers."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from .errors import UsageError

# the folder that holds the packages (a source checkout's root): on the workers' PYTHONPATH
PACKAGE_ROOT = Path(__file__).resolve().parents[1]


def worker_command(endpoint: str, threads: int = 1, quiet: bool = True, name: str | None = None,
                   curve_keys: str | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "igi.worker.node", "--connect", endpoint, "--threads", str(threads),
           "--exit-with-master", "--parent-pid", str(os.getpid())]
    if curve_keys:
        cmd += ["--curve-keys", str(curve_keys), "--key-name", "worker"]
    if quiet:
        cmd.append("--quiet")
    if name:
        cmd += ["--name", name]
    return cmd


def worker_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PACKAGE_ROOT), env.get("PYTHONPATH", "")) if p)
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


class LocalWorkers:
    """N worker processes on this machine, connected to ``endpoint``; stopped together."""

    def __init__(self, endpoint: str, count: int, threads: int = 1, quiet: bool = True,
                 curve_keys: str | None = None):
        self.procs: list[subprocess.Popen] = []
        try:
            for i in range(count):
                self.procs.append(subprocess.Popen(worker_command(endpoint, threads, quiet, f"local{i}", curve_keys),
                                                   env=worker_env(), stdin=subprocess.DEVNULL))
        except BaseException:  # the ones already started do not outlive a failed start
            self.stop()
            raise

    def check(self) -> None:
        for p in self.procs:
            if p.poll() is not None:
                raise UsageError(f"a local worker exited with status {p.returncode} (see its log above)")

    def stop(self, timeout: float = 5.0) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for p in self.procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


HELLO_TIMEOUT = 120.0  # s for local workers to join (scene, BVH, kernels from numba's cache)
FIRST_RUN_HELLO_TIMEOUT = 900.0  # ... on a machine whose kernels are not compiled yet (~2 min on 2 cores)


def wait_workers(broker, workers: LocalWorkers, count: int, timeout: float | None = None) -> None:
    """Until ``count`` workers have joined; a worker that exits first, or ``timeout`` s (None:
    HELLO_TIMEOUT, or FIRST_RUN_HELLO_TIMEOUT unless the kernels are known compiled here —
    every worker compiles them before its HELLO), is a :class:`UsageError`."""
    if timeout is None:
        from igi.worker.kernels.warm import compiled_before

        # (None: cannot be told, as for a read-only install; a dead worker is still seen at once)
        timeout = FIRST_RUN_HELLO_TIMEOUT if compiled_before() is not True else HELLO_TIMEOUT
    deadline = time.monotonic() + timeout
    while not broker.wait_for_workers(count, 0.2):
        workers.check()
        if time.monotonic() > deadline:
            raise UsageError(f"only {len(broker.workers())} of {count} local workers connected in {timeout:.0f} s")


def supervise_workers(endpoint: str, count: int, threads: int = 1, quiet: bool = True,
                      curve_keys: str | None = None):
    """``igi serve``'s local workers, restarted when they die (master/supervisor.py)."""
    from .supervisor import Supervisor

    def spawn(i: int) -> subprocess.Popen:
        return subprocess.Popen(worker_command(endpoint, threads, quiet, f"local{i}", curve_keys),
                                env=worker_env(), stdin=subprocess.DEVNULL)
    return Supervisor(spawn, count)


class LocalCluster:
    """What :func:`local_cluster` yields: the master, its workers, and ``all_exited`` (set once
    every worker process has exited: the master was then stopped and its frames cancelled)."""

    def __init__(self, broker, workers: LocalWorkers):
        self.broker, self.workers = broker, workers
        self.all_exited = threading.Event()


@contextmanager
def local_cluster(scene, count: int, threads: int = 1, **broker_kw):
    """A master on loopback (``master.broker.Broker``, with ``broker_kw``) and ``count`` >= 1
    local worker processes, every one joined (one that dies first: :class:`UsageError`); on
    exit both are stopped. Should every worker exit later, the master is stopped, which cancels
    its frames (a waiting caller gets ``FrameCancelled``, not a hang)."""
    from .broker import Broker

    if count < 1:
        raise UsageError(f"a local cluster needs at least one worker, not {count}")
    with Broker(scene, bind="tcp://127.0.0.1:*", **broker_kw) as broker:
        workers = None
        done = threading.Event()
        try:
            workers = LocalWorkers(broker.endpoint, count, threads=threads)
            wait_workers(broker, workers, count)  # (it reports a worker that died while starting)
            cluster = LocalCluster(broker, workers)

            def watchdog():
                while not done.wait(0.5):
                    if all(p.poll() is not None for p in workers.procs):
                        cluster.all_exited.set()
                        broker.stop()
                        return
            threading.Thread(target=watchdog, name="local-workers-watchdog", daemon=True).start()
            yield cluster
        finally:
            done.set()
            broker.stop()
            if workers is not None:
                workers.stop()
