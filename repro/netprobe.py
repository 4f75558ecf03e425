"""Bounded first words with a server named on the command line (issue 29, item 9).

Ray and MLflow, given an address, retry a server that accepts the connection but never answers
(or answers in another protocol) for minutes: ``ray.init`` past 300 s, an MLflow client 120 s
per request times 7 retries.  Before either is asked, :func:`exchange` opens the connection,
sends a few bytes and reads the first bytes of the reply, all within one deadline
(:data:`PROBE_TIMEOUT_S`), so a silent listener or a server of another kind is refused in one
line in seconds.  The callers (:mod:`repro.engine.ray_executor`,
:mod:`repro.exporters.mlflow_store`) say what the reply must look like.
"""

from __future__ import annotations

import socket
import ssl
import time
from collections.abc import Callable

#: seconds from the connection attempt to the first bytes of the reply, all together
PROBE_TIMEOUT_S = 5.0
#: the most bytes of a reply read: the probes look at its first line or frame header only
MAX_REPLY_BYTES = 4096


def exchange(host: str, port: int, payload: bytes, *, enough: Callable[[bytes], bool],
             timeout: float | None = None, tls: bool = False) -> bytes:
    """Connect to ``host:port`` (TLS when ``tls``: the certificate is not checked, the probe
    only asks whether something answers and sends no secret), send ``payload`` and return the
    reply read until ``enough(reply)``, the peer closes or :data:`MAX_REPLY_BYTES` came.

    Raises :class:`TimeoutError` when the deadline (``timeout`` seconds for everything, by
    default :data:`PROBE_TIMEOUT_S`) passes first, :class:`OSError` when the connection fails
    (refused, reset, TLS)."""
    timeout = PROBE_TIMEOUT_S if timeout is None else timeout
    deadline = time.monotonic() + timeout

    def left() -> float:
        rest = deadline - time.monotonic()
        if rest <= 0:
            raise TimeoutError(f"no answer within {timeout:g} s")
        return rest

    sock = socket.create_connection((host, port), timeout=left())
    try:
        if tls:
            ctx = ssl.create_default_context()
            ctx.check_hostname = False
            ctx.verify_mode = ssl.CERT_NONE
            sock.settimeout(left())
            sock = ctx.wrap_socket(sock, server_hostname=host)
        sock.settimeout(left())
        sock.sendall(payload)
        reply = b""
        while not enough(reply) and len(reply) < MAX_REPLY_BYTES:
            sock.settimeout(left())
            chunk = sock.recv(MAX_REPLY_BYTES - len(reply))
            if not chunk:
                break
            reply += chunk
        return reply
    except socket.timeout:  # an alias of TimeoutError since 3.10; said for clarity
        raise TimeoutError(f"no answer within {timeout:g} s") from None
    finally:
        sock.close()
