"""A small I++ DME client for scripts and tests, and `cmm ippdme-client`.

    with IppClient("127.0.0.1", 1294) as c:
        c.call("StartSession()")
        c.call("Home()")
        print(c.call("Get(X(), Y(), Z())").data)

``call`` sends a command with the next tag and returns its transaction (the
responses with its tag up to "%"). ``received`` keeps every line, daemon
reports and E0000 events included, in arrival order.
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .lines import read_lines
from .protocol import Response, data_items, parse_response


class IppClientError(RuntimeError):
    pass


@dataclass
class Transaction:
    tag: str
    command: str
    responses: list[Response] = field(default_factory=list)

    @property
    def data(self) -> list[str]:
        return [r.body for r in self.responses if r.kind == "#"]

    @property
    def errors(self) -> list[Response]:
        return [r for r in self.responses if r.kind == "!"]

    @property
    def ok(self) -> bool:
        return not any(r.severity is not None and r.severity >= 2 for r in self.errors)

    def values(self) -> dict[str, list]:
        """The first data line as {name: values}: Get(X(), Y()) -> {'X': [..], 'Y': [..]}."""
        return {name: vals for name, vals in data_items(self.data[0])} if self.data else {}


class IppClient:
    def __init__(self, host: str = "127.0.0.1", port: int = 1294, timeout: float = 60.0) -> None:
        self.timeout = timeout
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.received: list[Response] = []  # every response line, in arrival order
        self._cond = threading.Condition()
        self._closed = False
        self._next = 1
        self._event_next = 1
        self._thread = threading.Thread(target=self._read, name="ippdme-client", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        def take(raw: bytes) -> None:
            resp = parse_response(raw.decode("ascii"))
            with self._cond:
                self.received.append(resp)
                self._cond.notify_all()

        try:
            read_lines(self.sock, take)
        finally:
            with self._cond:
                self._closed = True
                self._cond.notify_all()

    def next_tag(self, event: bool = False) -> str:
        if event:
            tag, self._event_next = f"E{self._event_next:04d}", self._event_next % 9999 + 1
        else:
            tag, self._next = f"{self._next:05d}", self._next % 99999 + 1
        return tag

    def send_line(self, line: str) -> None:
        self.sock.sendall(line.encode("ascii") + b"\r\n")

    def send(self, command: str, tag: str | None = None) -> str:
        """Send without waiting; returns the tag (an E tag for fast-queue commands)."""
        name = command.split("(", 1)[0].strip()
        tag = tag or self.next_tag(event=name.endswith("E"))
        self.send_line(f"{tag} {command}")
        return tag

    def wait(self, tag: str, kind: str = "%", timeout: float | None = None, start: int = 0) -> int:
        """Wait for a response of ``kind`` with ``tag``; returns its index in ``received``."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        with self._cond:
            while True:
                for i in range(start, len(self.received)):
                    r = self.received[i]
                    if r.tag == tag and r.kind == kind:
                        return i
                if self._closed:
                    raise IppClientError(f"the server closed the connection before {tag} {kind}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise IppClientError(f"no {kind} for {tag} within the time-out")
                self._cond.wait(left)

    def transaction(self, tag: str, command: str = "", start: int = 0, timeout: float | None = None) -> Transaction:
        end = self.wait(tag, "%", timeout, start)
        with self._cond:
            return Transaction(tag, command, [r for r in self.received[start:end + 1] if r.tag == tag])

    def call(self, command: str, timeout: float | None = None) -> Transaction:
        with self._cond:
            start = len(self.received)
        tag = self.send(command)
        return self.transaction(tag, command, start, timeout)

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        self._thread.join(timeout=2)

    def __enter__(self) -> "IppClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- NIST .prg files ---------------------------------------------------------------------


def read_records(path: str | Path) -> list[str]:
    """Records of a NIST .prg/.res file: one per record, records separated by a line '\\\\', ended by ':' lines."""
    text = Path(path).read_bytes().decode("latin-1").replace("\r", "")
    records, current = [], []
    for line in text.split("\n"):
        if line == "\\\\":
            if current:
                records.append("\n".join(current))
            current = []
        elif line == ":":
            break
        elif line.strip() or current:
            current.append(line)
    if any(c.strip() for c in current):
        records.append("\n".join(current))
    return records


def run_program(client: IppClient, commands: list[str], timeout: float | None = None,
                before: Callable[[str], None] | None = None) -> list[Response]:
    """Send tagged command lines one transaction at a time, as the NIST test client does.

    The next command goes out after the previous one is complete, except
    that an AbortE after a move goes out as soon as the move is acknowledged,
    so it stops the move.
    Returns everything received from the first command on. ``before(line)``
    runs before each line is sent (a test sets up its artifacts there).
    """
    with client._cond:
        start = len(client.received)
    for i, line in enumerate(commands):
        tag = line[:5]
        if before is not None:
            before(line)
        with client._cond:
            sent_at = len(client.received)
        client.send_line(line)
        nxt = commands[i + 1] if i + 1 < len(commands) else ""
        moving = line[6:].split("(", 1)[0].strip() in ("GoTo", "PtMeas", "Home")
        abort_next = moving and nxt[6:].split("(", 1)[0].strip() == "AbortE"
        try:
            acked = client.wait(tag, "&", timeout, sent_at)
            if not abort_next:
                client.wait(tag, "%", timeout, acked)
        except IppClientError:
            # a line the server refused with an unsolicited error (illegal tag) has no transaction
            if not any(r.tag == "E0000" and r.kind == "!" for r in client.received[sent_at:]):
                raise
    with client._cond:
        return list(client.received[start:])


# --- the command line ------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("address", nargs="?", default="127.0.0.1:1294", help="server ADDRESS:PORT (default 127.0.0.1:1294)")
    parser.add_argument("-c", "--command", action="append", default=[],
                        help='a command without tag, e.g. -c "Get(X(), Y(), Z())"; repeatable; tags are added')
    parser.add_argument("-f", "--file", help="a NIST-style .prg file (tagged commands, records separated by \\\\)")
    parser.add_argument("--session", action="store_true", help="wrap the commands in StartSession() ... EndSession()")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for each transaction")


def run(args: argparse.Namespace) -> int:
    from .server import parse_address

    try:
        host, port = parse_address(args.address)
    except ValueError as exc:
        print(f"cmm ippdme-client: {exc}", file=sys.stderr)
        return 2
    try:
        client = IppClient(host, port, timeout=args.timeout)
    except OSError as exc:
        print(f"cmm ippdme-client: cannot connect to {host}:{port}: {exc}", file=sys.stderr)
        return 1
    try:
        return _run(client, args)
    except (OSError, IppClientError) as exc:
        refusal = [r for r in client.received if r.tag == "E0000" and r.kind == "!"]
        said = ""
        if refusal:
            said = f"; the server said: {refusal[-1].body}"
            if refusal[-1].error_number == 508:
                said += " (another I++ DME client holds the machine, or the station refused control)"
        print(f"cmm ippdme-client: {exc}{said}", file=sys.stderr)
        return 1


def _run(client: IppClient, args: argparse.Namespace) -> int:
    failed = False
    with client:
        if args.file:
            try:
                lines = read_records(args.file)
            except OSError as exc:
                print(f"cmm ippdme-client: cannot read {args.file}: {exc}", file=sys.stderr)
                return 2
            for line in lines:
                print(f"> {line}")
            for r in run_program(client, lines, args.timeout):
                print(f"< {r.tag} {r.kind} {r.body}".rstrip())
                failed |= r.kind == "!" and (r.severity or 0) >= 2
        commands = (["StartSession()"] if args.session else []) + args.command + (["EndSession()"] if args.session else [])
        for command in commands:
            t = client.call(command, args.timeout)
            print(f"> {t.tag} {command}")
            for r in t.responses:
                print(f"< {r.tag} {r.kind} {r.body}".rstrip())
            failed |= not t.ok
    return 1 if failed else 0
