"""What the master measures while it schedules: task latencies, the workers' reported render and
encode times, the loop thread's own cost per RESULT and per dispatch round (issue 19), frame
completions, wire bytes and traced rays. Bounded windows (deques), written by the loop thread;
:meth:`Meters.stats` turns them into the figures of ``Broker.stats()``.
"""
from __future__ import annotations

import collections

import numpy as np

from .scheduler import TIMEOUT_WINDOW

LATENCY_WINDOW = 2000  # task latencies kept for the stats
RAYS_WINDOW_S = 5.0  # rays per second: over the reports of the last 5 s


def _window(n: int = LATENCY_WINDOW) -> collections.deque:
    return collections.deque(maxlen=n)


class Meters:
    """Rolling measurements of the frame loop (see the module docstring)."""

    def __init__(self) -> None:
        self.latencies = _window()  # TASK sent -> RESULT accepted, s
        self.latency_per_pixel = _window(TIMEOUT_WINDOW)  # the same over the task's pixels (task timeouts)
        self.render_times = _window()  # reported by the workers
        self.encode_times = _window()
        self.merge_times = _window()  # decode + scatter of a RESULT's tile
        self.task_bytes = _window()
        self.result_times = _window()  # the loop thread's handling of one RESULT
        self.dispatch_times = _window()  # one dispatch round
        self.frame_times = _window(64)  # completion times
        self.frame_bytes = _window(64)
        self.rays = _window(4096)  # (time, rays traced)

    def worker_report(self, rays: int | None, previous_rays: int, timings: dict, now: float) -> int:
        """Record what a RESULT reports (cumulative ray count, render/encode times); returns the
        worker's new cumulative ray count."""
        if rays is not None:
            delta = rays - previous_rays if rays >= previous_rays else rays  # a new renderer restarts its counter
            previous_rays = rays
            self.rays.append((now, delta))
        if "render" in timings:
            self.render_times.append(timings["render"])
        if "encode" in timings:
            self.encode_times.append(timings["encode"])
        return previous_rays

    def frame_done(self, now: float, nbytes: int) -> None:
        self.frame_times.append(now)
        self.frame_bytes.append(nbytes)

    def fps(self) -> float:
        ft = list(self.frame_times)
        return (len(ft) - 1) / (ft[-1] - ft[0]) if len(ft) >= 2 and ft[-1] > ft[0] else 0.0

    def rays_per_s(self, now: float) -> float:
        recent = [(t, r) for t, r in self.rays if now - t <= RAYS_WINDOW_S]
        span = (now - recent[0][0]) if len(recent) >= 2 else 0.0
        return sum(r for _, r in recent[1:]) / span if span > 0 else 0.0

    def stats(self, now: float) -> dict:
        lat = np.array(self.latencies) if self.latencies else None
        return {
            "fps": self.fps(),
            "rays_per_s": self.rays_per_s(now),
            "bytes_per_frame": float(np.mean(self.frame_bytes)) if self.frame_bytes else 0.0,
            "task_latency_ms": None if lat is None else {
                "mean": float(lat.mean() * 1e3), "p50": float(np.percentile(lat, 50) * 1e3),
                "p95": float(np.percentile(lat, 95) * 1e3)},
            "task_render_ms": _mean_ms(self.render_times),
            "task_encode_ms": _mean_ms(self.encode_times),
            "task_merge_ms": _mean_ms(self.merge_times),
            "task_bytes": float(np.mean(self.task_bytes)) if self.task_bytes else None,
            # the loop thread's cost per RESULT (issue 19): handling it (decode excluded) and
            # one dispatch round, in µs
            "result_handle_us": _us_stats(self.result_times),
            "dispatch_us": _us_stats(self.dispatch_times),
        }


def _mean_ms(times) -> float | None:
    return float(np.mean(times) * 1e3) if times else None


def _us_stats(times) -> dict | None:
    if not times:
        return None
    a = np.asarray(times) * 1e6
    return {"mean": float(a.mean()), "p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95))}
