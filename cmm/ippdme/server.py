"""The I++ DME TCP server: one client at a time, CR LF lines, threads.

Per connection a reader thread feeds command lines to the executor
(:class:`~cmm.ippdme.executor.Dme`) and a writer thread sends the responses.
A client that stops reading is dropped once its responses back up (a bounded
queue, a send time-out); a client that disconnects, or is dropped, while the
machine moves leaves the machine stopped. A second client is told the
station is busy and disconnected.
"""

from __future__ import annotations

import queue
import select
import socket
import threading
from typing import Any

from . import protocol as P
from .backend import Backend
from .csy import CoordinateSystems
from .errors import IppError
from .executor import Dme
from .lines import read_lines
from .status import IppStatus
from .tools import Limits, ToolChanger

DEFAULT_PORT = 1294
OUT_QUEUE = 20000  # response lines waiting for a slow client before it is dropped
ENDING_WAIT = 10.0  # s a new client waits for an ending connection to release the machine (it stops any motion)


def parse_address(text: str | None, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """'HOST:PORT', ':PORT', 'PORT' or None -> (host, port)."""
    if not text:
        return default_host, DEFAULT_PORT
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = default_host, text
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"expected ADDRESS:PORT like 127.0.0.1:1294, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port {number} is outside 0..65535")
    return host.strip("[]") or default_host, number


class _Connection:
    def __init__(self, server: "IppServer", sock: socket.socket, peer: str, backend: Backend) -> None:
        self.server, self.sock, self.peer, self.backend = server, sock, peer, backend
        self.out: queue.Queue[str | None] = queue.Queue(OUT_QUEUE)
        self.alive = True
        self.reason = ""
        sock.settimeout(server.send_timeout)  # bounds sendall (a client that does not read)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # "&" then "%": no 40 ms Nagle/delayed-ACK stall
        if server.send_buffer:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, server.send_buffer)
        self.dme = Dme(backend, self.send, client=peer, status=server.status, tools=server.tools,
                       csy=server.csy)
        self.trace = server.trace
        self.writer = threading.Thread(target=self._write, name=f"ippdme-out-{peer}", daemon=True)
        self.reader = threading.Thread(target=self._read, name=f"ippdme-in-{peer}", daemon=True)

    def start(self) -> None:
        self.writer.start()
        self.reader.start()

    def send(self, line: str) -> None:
        if not self.alive:
            return
        if self.trace is not None:
            self.trace.append(("out", line))
        try:
            self.out.put_nowait(line)
        except queue.Full:
            self.drop("the client does not read its responses")

    def drop(self, reason: str) -> None:
        if self.alive:
            self.alive, self.reason = False, reason
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def _write(self) -> None:
        while True:
            line = self.out.get()
            if line is None or not self.alive:
                return
            try:
                self.sock.sendall(line.encode("ascii") + b"\r\n")
            except (OSError, UnicodeEncodeError) as exc:
                self.drop(f"sending failed ({exc}): the client does not read its responses or went away")
                return

    def _read(self) -> None:
        try:
            read_lines(self.sock, self._line, alive=lambda: self.alive, max_line=P.MAX_LINE,
                       on_overflow=lambda: self.send(P.error(P.UNSOLICITED, IppError(8, "Server", "line too long"))))
        finally:
            self.alive = False
            self.dme.close()
            self.backend.release()
            while True:  # nothing more goes out: wake the writer (the queue may be full)
                try:
                    self.out.get_nowait()
                except queue.Empty:
                    break
            self.out.put_nowait(None)
            try:
                self.sock.close()
            except OSError:
                pass
            self.server._gone(self)

    def peer_closed(self) -> bool:
        """The client has closed its end (the reader will see the end of the stream when it next runs)."""
        try:
            readable, _, _ = select.select([self.sock], [], [], 0)
            # readable with nothing to read is the end of the stream (the socket's time-out makes recv wait)
            return bool(readable) and self.sock.recv(1, socket.MSG_PEEK) == b""
        except (ValueError, OSError):  # closed here already
            return True

    def _line(self, raw: bytes) -> None:
        if not raw.strip():
            return  # an empty line carries no command: ignored
        line = raw.decode("latin-1")
        if self.trace is not None:
            self.trace.append(("in", line))
        self.dme.receive(line)


class IppServer:
    """``IppServer(backend).start()``; ``close()`` stops it and any client's motion."""

    def __init__(self, backend: Backend, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 status: IppStatus | None = None, send_timeout: float = 10.0, send_buffer: int | None = None,
                 trace: list | None = None) -> None:
        self.backend = backend
        self.status = status or IppStatus()
        self.send_timeout = send_timeout  # s a response may wait for the client to read before it is dropped
        self.send_buffer = send_buffer  # bytes of kernel send buffer per client (None: the system's)
        self.trace = trace  # (direction, line) pairs, for tests and debugging
        self.tools = ToolChanger.build(Limits.from_config(backend.config), backend.probes())
        self.csy = CoordinateSystems()
        self._sock = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET,
                                          reuse_port=False)
        self._sock.settimeout(0.25)  # accept() wakes up to notice close()
        self.host, self.port = self._sock.getsockname()[:2]
        self.status.listening = f"{self.host}:{self.port}"
        self._client: _Connection | None = None
        self._lock = threading.Lock()
        self._closing = False
        self._thread = threading.Thread(target=self._accept, name="ippdme-accept", daemon=True)

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def start(self) -> "IppServer":
        self._thread.start()
        return self

    def _accept(self) -> None:
        while not self._closing:
            try:
                sock, addr = self._sock.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            peer = f"{addr[0]}:{addr[1]}"
            if not self._free():
                self._refuse(sock, "another I++ DME client holds the machine")
                continue
            backend = self.backend.for_client(peer)
            why = backend.acquire()  # the station's control: browsers observe meanwhile
            if why is not None:
                self._refuse(sock, f"the station refused control: {why}")
                continue
            with self._lock:
                self._client = conn = _Connection(self, sock, peer, backend)
            self.status.connected(peer)
            conn.start()

    def _free(self) -> bool:
        """No client holds the machine. A client whose connection is ending (it closed its end, or its reader has
        seen that) is waited for until its reader has released the machine: a client that ends its session,
        closes and connects again at once is not refused because this server's threads had not run yet."""
        with self._lock:
            old = self._client
        if old is None:
            return True
        if old.alive and not old.peer_closed():
            return False
        old.reader.join(ENDING_WAIT)
        with self._lock:
            return self._client is None

    def _refuse(self, sock: socket.socket, why: str) -> None:
        """A client that cannot have the machine: one line saying so, then the connection is closed."""
        try:
            sock.settimeout(1.0)
            err = IppError(508, "Connect", why)
            # the spec's text, then why (who holds the machine): a client connecting is told whom to ask, and a
            # client matching the text by its start still sees "Bad context"
            line = P.error(P.UNSOLICITED, err)
            detail = "".join(ch if 32 <= ord(ch) < 127 and ch != '"' else "'" if ch == '"' else "?" for ch in why)
            line = line[:-2] + f': {detail}")' if detail else line
            sock.sendall(line.encode("ascii") + b"\r\n")
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        finally:
            sock.close()

    def _gone(self, conn: _Connection) -> None:
        with self._lock:
            if self._client is conn:
                self._client = None

    @property
    def client(self) -> str | None:
        with self._lock:
            return None if self._client is None else self._client.peer

    def close(self) -> None:
        self._closing = True
        try:
            self._sock.close()
        except OSError:
            pass
        with self._lock:
            conn = self._client
        if conn is not None:
            conn.drop("the server is shutting down")
            conn.reader.join(timeout=10)
        self._thread.join(timeout=2)

    def __enter__(self) -> "IppServer":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()
