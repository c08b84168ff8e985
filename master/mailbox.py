"""How other threads get work onto the broker's loop thread: they post small closures to a
queue and wake the loop through a socketpair it polls; where they need an answer they wait on
a Future. Before the loop runs (``inline``) a posted closure runs at once in the caller's
thread; once the loop is gone (``closed``) it fails with :class:`FrameCancelled`.
"""
from __future__ import annotations

import concurrent.futures as cf
import queue
import socket
import threading
from typing import Any, Callable

from .frames import FrameCancelled


class Mailbox:
    """Closures for the loop thread (see the module docstring)."""

    def __init__(self) -> None:
        self._cmds: queue.SimpleQueue = queue.SimpleQueue()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_lock = threading.Lock()
        self.inline = True  # no loop thread yet: run closures in the caller's thread
        self.closed = False  # the loop is gone: closures fail

    def fileno(self) -> int:
        """The file descriptor the loop polls (readable after :meth:`wake`)."""
        return self._wake_r.fileno()

    def wake(self) -> None:
        with self._wake_lock:
            try:
                self._wake_w.send(b"\0")
            except (BlockingIOError, OSError):
                pass

    def drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, OSError):
            pass

    def post(self, fn: Callable[[], Any]) -> cf.Future:
        fut: cf.Future = cf.Future()
        if self.closed:
            fut.set_exception(FrameCancelled("master stopped"))
            return fut
        if self.inline:
            # Not started: run inline (single-threaded use before start()).
            try:
                fut.set_result(fn())
            except BaseException as e:
                fut.set_exception(e)
            return fut
        self._cmds.put((fn, fut))
        self.wake()
        return fut

    def call(self, fn: Callable[[], Any], timeout: float | None = 30.0) -> Any:
        return self.post(fn).result(timeout)

    def run_pending(self) -> None:
        """Loop thread: run the closures posted so far."""
        while True:
            try:
                fn, fut = self._cmds.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn())
            except BaseException as e:
                fut.set_exception(e)

    def close(self) -> None:
        for s in (self._wake_r, self._wake_w):
            s.close()
