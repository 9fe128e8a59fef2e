"""What the browser (or any observer) can read about the I++ DME client: who, what it does, what it measured."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

MAX_POINTS = 10000  # kept for display; the session journal has them all


@dataclass
class IppStatus:
    listening: str = ""  # "host:port" the server listens on
    client: str | None = None  # "host:port" of the connected client
    connected_at: float | None = None
    in_session: bool = False
    command: str = ""  # the command being executed ("" when idle)
    last_error: str = ""
    commands: int = 0
    points: list[tuple[float, float, float]] = field(default_factory=list)  # measured tip centres, machine mm
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def connected(self, client: str) -> None:
        with self._lock:
            self.client, self.connected_at, self.command, self.last_error = client, time.time(), "", ""
            self.points = []
            self.commands = 0

    def disconnected(self) -> None:
        with self._lock:
            self.client, self.connected_at, self.command, self.in_session = None, None, "", False

    def running(self, command: str) -> None:
        with self._lock:
            self.command = command
            if command:
                self.commands += 1

    def failed(self, message: str) -> None:
        with self._lock:
            self.last_error = message

    def measured(self, point) -> None:
        with self._lock:
            self.points.append(tuple(float(v) for v in point))  # type: ignore[arg-type]
            del self.points[:-MAX_POINTS]

    def snapshot(self) -> dict:
        """A consistent copy for a UI thread."""
        with self._lock:
            return {"listening": self.listening, "client": self.client, "connected_at": self.connected_at,
                    "in_session": self.in_session, "command": self.command, "last_error": self.last_error,
                    "commands": self.commands, "points": list(self.points)}


def ippdme_markdown(status: IppStatus) -> str:
    """One line for the station's status panel: is an I++ DME client driving the machine, and what is it doing."""
    snap = status.snapshot()
    if snap["client"] is None:
        return f"I++ DME: listening on {snap['listening']}, no client" if snap["listening"] else ""
    parts = [f"**I++ DME client {snap['client']} has control** (this page observes; STOP still works)"]
    if snap["command"]:
        text = snap["command"] if len(snap["command"]) <= 60 else snap["command"][:57] + "..."
        parts.append(f"running `{text}`")
    parts.append(f"{len(snap['points'])} points measured")
    if snap["last_error"]:
        parts.append(f"last error: {snap['last_error'][:120]}")
    return " · ".join(parts)
