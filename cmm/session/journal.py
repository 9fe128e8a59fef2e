"""Append-only session journal in JSON Lines.

One event per line, flushed and fsync'ed before ``append`` returns, so a
hit the UI shows is on disk; a killed process loses nothing acknowledged.
JSON Lines (not SQLite) because a journal must stay readable and
recoverable with a text editor: a torn last line is simply dropped on read.
"""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any


class JournalError(OSError):
    pass


def _default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"cannot record a {type(value).__name__} in the journal")


class Journal:
    """Appends events to ``path`` (created with its directory if needed)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._file = open(self.path, "a", encoding="utf-8")
        self.seq = sum(1 for _ in read_events(self.path).events)

    def append(self, kind: str, **data: Any) -> dict:
        with self._lock:
            self.seq += 1
            event = {"seq": self.seq, "time": time.time(), "kind": kind, **data}
            line = json.dumps(event, default=_default, allow_nan=False)
            self._file.write(line + "\n")
            self._file.flush()
            os.fsync(self._file.fileno())
            return event

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.close()


@dataclass
class JournalContents:
    events: list[dict]
    damage: str | None = None  # a sentence about a damaged tail, if any


def read_events(path: str | Path) -> JournalContents:
    """Every intact event; a damaged line ends the read with a message naming it."""
    events: list[dict] = []
    p = Path(path)
    if not p.exists():
        return JournalContents(events)
    with open(p, "rb") as fh:
        for lineno, raw in enumerate(fh, 1):
            try:
                text = raw.decode("utf-8")
                if not text.endswith("\n"):
                    raise ValueError("incomplete last line")
                event = json.loads(text)
                if not isinstance(event, dict) or "kind" not in event:
                    raise ValueError("not an event")
            except (UnicodeDecodeError, ValueError) as exc:
                return JournalContents(events, f"{p}: line {lineno} is damaged ({exc}); "
                                               f"the {len(events)} events before it are intact")
            events.append(event)
    return JournalContents(events)
