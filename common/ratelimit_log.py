"""Rate-limited, counted log lines (issue 20): one line per kind per interval.

A peer that sends 2,000 junk messages must not write 2,000 warning lines. :class:`RateLimitedLog`
writes the first message of a *kind* (a short fixed string chosen by the caller: "dropped",
"bad_result", ...) at once, counts the ones that follow within ``interval`` seconds without
writing them, and appends the count to the next line of that kind written after the interval::

    dropped message from w/1a2b: not a msgpack message (… 1,999 more 'dropped' in the last 10 s)

Every message is counted (:attr:`counts`, totals per kind, for stats and tests) whether it was
written or not; :meth:`flush` writes the pending suppressed counts (e.g. at shutdown). Used by the
master (``master/links.py``, ``master/frame_loop.py``) and the worker node (``worker/node.py``).
Thread-safe; the clock is injectable for tests.
"""
from __future__ import annotations

import collections
import logging
import threading
import time
from typing import Callable

DEFAULT_INTERVAL = 10.0  # seconds
MAX_KINDS = 256  # kinds remembered (the oldest is forgotten, with its pending count written)


class RateLimitedLog:
    def __init__(self, logger: logging.Logger, interval: float = DEFAULT_INTERVAL,
                 clock: Callable[[], float] = time.monotonic):
        self.logger = logger
        self.interval = float(interval)
        self.clock = clock
        self.counts: collections.Counter = collections.Counter()  # every call, per kind
        self.written: collections.Counter = collections.Counter()  # lines written, per kind
        self._state: collections.OrderedDict = collections.OrderedDict()  # kind -> [last written, suppressed]
        self._lock = threading.Lock()

    def warning(self, kind: str, msg: str, *args) -> bool:
        return self.log(logging.WARNING, kind, msg, *args)

    def info(self, kind: str, msg: str, *args) -> bool:
        return self.log(logging.INFO, kind, msg, *args)

    def log(self, level: int, kind: str, msg: str, *args) -> bool:
        """Log ``msg % args`` at ``level`` unless a line of ``kind`` was written less than
        ``interval`` s ago (then only counted). True when the line was written."""
        now = self.clock()
        with self._lock:
            self.counts[kind] += 1
            st = self._state.get(kind)
            if st is not None and now - st[0] < self.interval:
                st[1] += 1
                return False
            suppressed = st[1] if st is not None else 0
            since = now - st[0] if st is not None else 0.0
            self._state[kind] = [now, 0]
            self._state.move_to_end(kind)
            evicted = self._state.popitem(last=False) if len(self._state) > MAX_KINDS else None
            self.written[kind] += 1
        if suppressed:
            msg = f"{msg} (… {suppressed} more {kind!r} in the last {since:.0f} s)"
        self.logger.log(level, msg, *args)
        if evicted is not None and evicted[1][1]:
            self.logger.log(level, "%d more %r message(s) not shown", evicted[1][1], evicted[0])
        return True

    def flush(self, level: int = logging.WARNING) -> None:
        """Write one line per kind with suppressed messages not yet reported."""
        with self._lock:
            pending = [(k, st[1]) for k, st in self._state.items() if st[1]]
            for k, _ in pending:
                self._state[k][1] = 0
        for k, n in pending:
            self.logger.log(level, "%d more %r message(s) not shown", n, k)
