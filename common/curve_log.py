"""Log CURVE denials (issue 20): a CURVE master says, at INFO, whom it turned away and why.

Two ways a peer is denied, two sources:

- *Unknown key* (it speaks CURVE with a key not in DIR/workers/): the ZAP authenticator decides;
  :class:`LoggingAuthenticator` (pyzmq's ThreadAuthenticator) logs the denial with the peer
  address the ZAP request carries.
- *No CURVE at all* (a plain NULL worker, a wrong master key, junk): the ZMTP handshake fails
  before any ZAP request; :class:`HandshakeMonitor` reads the ROUTER's socket-monitor events.
  libzmq (4.3, monitor v1) reports the listening endpoint, not the peer, for these, so the
  line names the endpoint and says the peer address is not reported.

Both go through :class:`common.ratelimit_log.RateLimitedLog`: a worker that retries every
second writes one line per peer (or reason) per interval, with the count of repeats.
"""
from __future__ import annotations

import logging

import zmq
from zmq.auth.thread import ThreadAuthenticator

from .ratelimit_log import RateLimitedLog

DENIAL_INTERVAL = 60.0  # seconds: one line per peer (or reason) per minute

log = logging.getLogger("igi.master")


def denial_log() -> RateLimitedLog:
    return RateLimitedLog(log, interval=DENIAL_INTERVAL)


class LoggingAuthenticator(ThreadAuthenticator):
    """ThreadAuthenticator that logs every ZAP denial at INFO with the peer's address."""

    _peer = "?"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.denials = denial_log()

    async def handle_zap_message(self, msg: list) -> None:
        self._peer = msg[3].decode("utf-8", "replace")[:64] if len(msg) > 3 else "?"
        await super().handle_zap_message(msg)

    def _send_zap_reply(self, request_id, status_code, status_text, user_id="anonymous") -> None:
        if status_code != b"200":
            peer = self._peer
            self.denials.info(f"zap:{peer}", "CURVE: denied worker at %s: %s (key not in the accepted "
                          "workers' keys)", peer, bytes(status_text).decode("utf-8", "replace")[:80])
        super()._send_zap_reply(request_id, status_code, status_text, user_id)


_REASONS = {
    0x11000002: "it does not speak CURVE (plain NULL security?) — ZMTP mechanism mismatch",
    0x11000001: "ZMTP handshake failed (not a ZeroMQ peer?)",
}


class HandshakeMonitor:
    """Socket-monitor events of a CURVE server socket: a failed handshake (before ZAP) is logged
    at INFO, rate-limited (one line per interval whatever the reason: one failed connection
    often reports twice, e.g. a mechanism mismatch then the closed pipe). ``socket`` goes into the owner's poller; call
    :meth:`drain` when it is readable and :meth:`close` before the server socket closes."""

    EVENTS = zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL

    def __init__(self, sock: zmq.Socket):
        self.endpoint = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.socket = sock.get_monitor_socket(self.EVENTS)
        self._server = sock
        self.count = 0
        self.denials = denial_log()

    def drain(self) -> None:
        from zmq.utils.monitor import recv_monitor_message

        while True:
            try:
                ev = recv_monitor_message(self.socket, zmq.NOBLOCK)
            except (zmq.Again, zmq.ZMQError):
                return
            if ev.get("event") not in (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL):
                continue
            self.count += 1
            value = ev.get("value")
            why = _REASONS.get(value, f"handshake failed (code {value:#x})" if isinstance(value, int) else "handshake failed")
            self.denials.info("handshake", "CURVE: denied a peer on %s: %s (peer address not "
                          "reported by ZeroMQ for handshake failures)", self.endpoint, why)

    def close(self) -> None:
        try:
            self._server.disable_monitor()
        except zmq.ZMQError:
            pass
        self.socket.close(0)
