"""Benchmarks of igi: ``igi bench NAME ...`` (the CLI finds them only through :data:`BENCHES`).

Each entry names a module of this package that defines ``add_arguments(parser)`` and
``run(args) -> int``; the module is imported only when its benchmark runs, so ``igi bench
--help`` stays cheap and a benchmark's optional dependencies (matplotlib, mitsuba, flip) are
needed only by that benchmark. Nothing in ``common``, ``worker`` or ``master`` imports this
package except the ``bench`` subcommand of ``master/cli.py`` (tests/test_architecture.py).

Shared helpers: :mod:`bench.report` (machine info, git commit, markdown tables, plots),
:mod:`bench.paths` (repository and shared-scene paths), :mod:`bench.stress_scenes` (stress and
synthetic scenes, also used by the tests), :mod:`bench.scaling_model` (the scaling simulator
behind ``igi bench scaling --model``).
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Bench:
    name: str
    module: str  # importable module path: defines add_arguments(parser) and run(args) -> int
    help: str


BENCHES: dict[str, Bench] = {b.name: b for b in [
    Bench("accuracy", "igi.bench.accuracy",
          "relMSE vs the Mitsuba references as frames accumulate (paper vs consistent), JSON + markdown"),
    Bench("contention", "igi.bench.core_contention",
          "one core's slowdown with N cores busy: compute-bound loop vs memory-streaming pass (many-core hosts)"),
    Bench("compare", "igi.bench.compare",
          "igi vs Mitsuba 3 path tracer at equal wall time (budgets), bias vs noise, flicker"),
    Bench("plan", "igi.bench.plan",
          "wall time with the render plan vs every pass forced on, at equal error; camera-only cost"),
    Bench("quality", "igi.bench.quality",
          "error vs wall time against the references over parameter sweeps (relMSE, RMSE, FLIP); Pareto front"),
    Bench("rays", "igi.bench.rays",
          "primary + shadow ray throughput of the whole pipeline against raw embreex on the same rays"),
    Bench("scaling", "igi.bench.scaling",
          "frames/s against worker count, bytes per frame, master merge+filter Mpixel/s, task latency"),
    Bench("stress", "igi.bench.stress",
          "stress scenes (finite images, transformed = untransformed) + scene-file fuzzing, JSON counts"),
    Bench("viewer-latency", "igi.bench.viewer_latency",
          "input-to-frame latency of a streaming master (and through the viewer's WebSocket with --ws)"),
]}


def load(name: str):
    """The module of benchmark ``name`` (KeyError for an unknown name)."""
    return importlib.import_module(BENCHES[name].module)
