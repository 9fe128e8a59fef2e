"""Raw byte trace of the NMC link (the thesis program's "Datos Rx" box)."""

from __future__ import annotations

import functools
import threading
from collections import deque
from dataclasses import dataclass
from typing import Callable

from . import codec


@dataclass(frozen=True)
class TraceEntry:
    time: float  # seconds on the bus clock
    direction: str  # "tx" (host -> modules) or "rx" (modules -> host)
    data: bytes
    given_note: str | None = ""  # None: the command's description, worked out when first read

    @functools.cached_property
    def note(self) -> str:
        # the link sends hundreds of packets a second and the trace is read rarely: describe on demand
        return codec.describe(self.data) if self.given_note is None else self.given_note

    def format(self) -> str:
        note = f"  {self.note}" if self.note else ""
        return f"{self.time:12.6f} {self.direction.upper()} {self.data.hex(' ').upper()}{note}"


class ByteTrace:
    """A bounded, thread-safe record of every byte sent and received."""

    def __init__(self, maxlen: int = 4000) -> None:
        self._entries: deque[TraceEntry] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self._listeners: list[Callable[[TraceEntry], None]] = []
        self.enabled = True

    def record(self, time: float, direction: str, data: bytes, note: str | None = "") -> None:
        if not self.enabled or not data:
            return
        entry = TraceEntry(time, direction, bytes(data), note)
        with self._lock:
            self._entries.append(entry)
            listeners = list(self._listeners)
        for listener in listeners:
            listener(entry)

    def tx(self, time: float, data: bytes) -> None:
        self.record(time, "tx", data, None if data[:1] == bytes((codec.HEADER,)) else "")

    def rx(self, time: float, data: bytes, note: str = "") -> None:
        self.record(time, "rx", data, note)

    def subscribe(self, listener: Callable[[TraceEntry], None]) -> Callable[[], None]:
        with self._lock:
            self._listeners.append(listener)

        def unsubscribe() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return unsubscribe

    def entries(self, last: int | None = None) -> list[TraceEntry]:
        with self._lock:
            items = list(self._entries)
        return items if last is None else items[-last:]

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def dump(self, last: int | None = None) -> str:
        return "\n".join(e.format() for e in self.entries(last))
