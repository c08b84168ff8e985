"""Keep ``igi serve``'s local workers alive: a worker process that dies is started again.

    sup = Supervisor(spawn, count)          # spawn(i) -> subprocess.Popen of worker slot i
    events = sup.poll()                     # call every ~0.5 s: restarts due workers; departures
    sup.procs                               # the live processes
    sup.stop()

A slot whose process exits is logged (one WARNING with the exit status or signal) and restarted
after a back-off: :data:`BACKOFF` seconds, growing with each exit that follows a run shorter than
:data:`STABLE_AFTER` seconds (a worker that crashes at start does not spin), back to the first
step once a run lasted longer. Each exit is returned by :meth:`Supervisor.poll` as a
:class:`Departure` (``igi serve`` passes it to the viewer, whose overlay says which worker left
and why).
"""
from __future__ import annotations

import logging
import signal
import subprocess
import time
from dataclasses import dataclass
from typing import Callable

log = logging.getLogger("igi.supervisor")

BACKOFF = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)  # seconds before restart k (k = quick exits in a row)
STABLE_AFTER = 30.0  # a run at least this long resets the back-off


@dataclass
class Departure:
    slot: int
    name: str
    pid: int
    reason: str  # "killed by SIGKILL", "exited with status 3"
    restart_in: float | None  # seconds until the restart (None: not restarted)


def exit_reason(returncode: int | None) -> str:
    if returncode is None:
        return "running"
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exited with status {returncode}"


class Supervisor:
    def __init__(self, spawn: Callable[[int], subprocess.Popen], count: int, names: list[str] | None = None,
                 backoff: tuple[float, ...] = BACKOFF, stable_after: float = STABLE_AFTER, restart: bool = True):
        self._spawn = spawn
        self.names = names or [f"local{i}" for i in range(count)]
        self.backoff = backoff
        self.stable_after = stable_after
        self.restart = restart
        self._procs: list[subprocess.Popen | None] = []
        self._started: list[float] = []
        self._quick: list[int] = [0] * count  # quick exits in a row, per slot
        self._due: list[float | None] = [None] * count
        self.restarts = 0
        self.departures: list[Departure] = []
        for i in range(count):
            self._procs.append(spawn(i))
            self._started.append(time.monotonic())

    @property
    def procs(self) -> list[subprocess.Popen]:
        return [p for p in self._procs if p is not None and p.poll() is None]

    def poll(self) -> list[Departure]:
        """Notice exits (scheduling their restarts) and start the workers whose back-off is over."""
        now = time.monotonic()
        events = []
        for i, p in enumerate(self._procs):
            if p is not None and p.poll() is not None:
                ran = now - self._started[i]
                self._quick[i] = 0 if ran >= self.stable_after else self._quick[i] + 1
                delay = self.backoff[min(max(self._quick[i] - 1, 0), len(self.backoff) - 1)] if self.backoff else 0.0
                reason = exit_reason(p.returncode)
                ev = Departure(i, self.names[i], p.pid, reason, delay if self.restart else None)
                if self.restart:
                    log.warning("local worker %s (pid %d) %s after %.1f s; restarting in %.1f s",
                                ev.name, p.pid, reason, ran, delay)
                    self._due[i] = now + delay
                else:
                    log.warning("local worker %s (pid %d) %s", ev.name, p.pid, reason)
                self._procs[i] = None
                events.append(ev)
                self.departures.append(ev)
                del self.departures[:-50]
            if self._procs[i] is None and self._due[i] is not None and now >= self._due[i]:
                self._due[i] = None
                try:
                    self._procs[i] = self._spawn(i)
                except OSError as e:
                    log.error("cannot restart local worker %s: %s", self.names[i], e)
                    self._quick[i] += 1
                    self._due[i] = now + self.backoff[-1]
                    continue
                self._started[i] = now
                self.restarts += 1
                log.info("local worker %s restarted (pid %d)", self.names[i], self._procs[i].pid)
        return events

    def stop(self, timeout: float = 5.0) -> None:
        self._due = [None] * len(self._due)
        live = [p for p in self._procs if p is not None]
        for p in live:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for p in live:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
