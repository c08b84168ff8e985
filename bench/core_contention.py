"""How much slower one core's work gets as more cores are busy: the machine's share of a
scaling run's CPU inflation (``igi bench scaling`` measures a task's render time growing with
the number of busy workers; this says how much of that any program would see).

Runs N copies of two fixed workloads at once in separate processes — a compute-bound compiled
loop (scalar float math in registers: turbo, hyperthread siblings, other tenants) and a
memory-bound numpy pass (streams 64 MiB arrays: shared memory bandwidth and last-level cache)
— and prints each one's mean seconds per copy against one copy alone. JSON on stdout.

    python bench/core_contention.py [--copies 1,2,4,8,16]
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import time

import numpy as np


def _compute(reps: int) -> float:
    from numba import njit

    @njit(cache=False)
    def loop(n):
        x, y = 1.0, 0.5
        for i in range(n):
            x = x * 0.9999999 + y * 1e-7
            y = y * 0.9999998 + x * 2e-7
        return x + y

    loop(10)
    _START.wait()  # every copy compiled: the timed loops overlap
    t0 = time.perf_counter()
    loop(reps)
    return time.perf_counter() - t0


def _memory(reps: int) -> float:
    a = np.ones(8 << 20)  # 64 MiB
    b = np.empty_like(a)
    b[:] = 0.0  # pages touched before the clock
    _START.wait()  # every copy allocated: the timed passes overlap
    t0 = time.perf_counter()
    for _ in range(reps):
        np.multiply(a, 1.0000001, out=b)
        np.add(b, 1.0, out=a)
    return time.perf_counter() - t0


_START = None  # the copies' barrier, set in each pool process


def _set_start(barrier) -> None:
    global _START
    _START = barrier


def _run(kind: str, copies: int, reps: int) -> list[float]:
    fn = _compute if kind == "compute" else _memory
    ctx = mp.get_context("fork")
    with ctx.Pool(copies, initializer=_set_start, initargs=(ctx.Barrier(copies),)) as pool:
        return pool.map(fn, [reps] * copies, chunksize=1)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--copies", default=None, help="comma-separated copy counts (default 1,2,4,… up to the cores)")
    p.add_argument("--compute-reps", type=int, default=300_000_000, help="iterations of the compute loop")
    p.add_argument("--memory-reps", type=int, default=40, help="passes over the 64 MiB arrays")
    p.add_argument("-o", "--out", default="artifacts/bench-contention", help="output prefix: writes PREFIX.json")


def run(a: argparse.Namespace) -> int:
    cores = os.cpu_count() or 1
    counts = [int(c) for c in a.copies.split(",")] if a.copies else sorted({1, 2, 4, 8, 16, cores} & set(range(1, cores + 1)))
    out = {"benchmark": "contention", "machine": {"cpu": platform.processor() or platform.machine(), "cores": cores,
                                                  "python": platform.python_version(), "numpy": np.__version__},
           "settings": {"copies": counts, "compute_reps": a.compute_reps, "memory_reps": a.memory_reps},
           "points": []}
    base = {}
    for kind, reps in (("compute", a.compute_reps), ("memory", a.memory_reps)):
        for n in counts:
            ts = _run(kind, n, reps)
            mean = float(np.mean(ts))
            base.setdefault(kind, mean)
            out["points"].append({"kind": kind, "copies": n, "mean_s": mean, "max_s": float(max(ts)),
                                  "inflation": mean / base[kind]})
            print(f"{kind:8s} {n:3d} copies: {mean:.3f} s each (x{mean / base[kind]:.2f})", flush=True)
    path = a.out + ".json"
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "w") as f:
        json.dump(out, f, indent=2)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    raise SystemExit(run(parser.parse_args()))
