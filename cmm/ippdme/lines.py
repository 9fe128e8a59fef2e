"""Reading CRLF-terminated lines from a socket (client and server share it)."""

from __future__ import annotations

import socket
from typing import Callable


def read_lines(sock: socket.socket, on_line: Callable[[bytes], None], *, alive: Callable[[], bool] = lambda: True,
               max_line: int | None = None, on_overflow: Callable[[], None] | None = None) -> None:
    """Call ``on_line`` for each line (terminator stripped, a lone LF accepted) until the peer closes.

    Returns when the socket is closed, fails, or ``alive()`` turns false (checked at each receive
    timeout). A partial line longer than ``max_line`` is dropped and reported through ``on_overflow``.
    """
    buf = b""
    skipping = False  # the rest of an oversized line is dropped up to its end: one error per line, not per chunk
    while alive():
        try:
            chunk = sock.recv(65536)
        except socket.timeout:
            continue
        except OSError:
            return
        if not chunk:
            return
        if skipping:
            end = chunk.find(b"\n")
            if end < 0:
                continue
            skipping, chunk = False, chunk[end + 1:]
        buf += chunk
        while b"\n" in buf:
            raw, buf = buf.split(b"\n", 1)
            on_line(raw[:-1] if raw.endswith(b"\r") else raw)
        if max_line is not None and len(buf) > max_line:
            buf, skipping = b"", True
            if on_overflow is not None:
                on_overflow()
