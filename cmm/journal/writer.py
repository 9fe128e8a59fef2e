"""Append-only session journal in JSON Lines.

One event per line, flushed and fsync'ed before ``append`` returns, so a
hit the UI shows is on disk; a killed process loses nothing acknowledged.
JSON Lines (not SQLite, not a binary log) for the embedded default because:

- human-readable: a journal can be read, grepped and repaired with a text
  editor, and diffed between two sessions;
- torn tail recoverable: a process killed mid-write leaves at most one
  incomplete last line; every line before it is a complete event, so the
  reader keeps them all and names the damaged line;
- no server: a directory of ``*.jsonl`` files is the whole store.

On-disk format (unchanged since the first version, so old journals open):
one JSON object per line with ``seq`` (1, 2, ... per journal), ``time`` (wall
seconds since the epoch), ``kind`` and the event's fields (see
:mod:`cmm.journal.state` for the kinds). Non-finite floats are refused.

A writer holds an exclusive advisory lock (``flock``) on the file while it is
open, so the session store can refuse to rename or delete a session that is
being recorded; the lock dies with the process, even on SIGKILL.
"""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

try:  # POSIX; elsewhere sessions simply are not locked
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]


class JournalError(OSError):
    pass


class JournalBusy(JournalError):
    """The journal is open for writing by another process or station."""


def _default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"cannot record a {type(value).__name__} in the journal")


def encode_event(event: dict) -> str:
    """One journal line (without the newline)."""
    return json.dumps(event, default=_default, allow_nan=False)


def try_lock(fh: Any) -> bool:
    """Take an exclusive non-blocking advisory lock on an open file; False if someone holds it."""
    if fcntl is None:
        return True
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


def is_locked(path: str | Path) -> bool:
    """True if a writer holds the journal at ``path`` open."""
    if fcntl is None or not Path(path).exists():
        return False
    with open(path, "rb") as fh:
        if try_lock(fh):
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
            return False
        return True


class Journal:
    """Appends events to ``path`` (created with its directory if needed).

    Opening an existing journal whose tail is damaged (a torn last line from a
    killed writer) moves the damaged bytes to ``<path>.damaged-<time>`` and
    truncates the journal to its intact events before appending, so new
    events never follow garbage. The damage message stays in ``self.damage``.
    """

    def __init__(self, path: str | Path, *, lock: bool = True) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        # unbuffered: a write that fails (disk full) leaves no bytes behind in a buffer to be written
        # later under another event's seq; append() cuts a partly written line off the file instead
        self._file = open(self.path, "ab", buffering=0)
        self._broken: str | None = None  # why appending is refused (a failed write that could not be undone)
        if lock and not try_lock(self._file):
            self._file.close()
            raise JournalBusy(f"session journal {self.path} is already open for writing by another station")
        contents = read_events(self.path)
        self.damage = contents.damage
        if contents.damage is not None:
            self._cut_damaged_tail(contents.intact_bytes)
        self.seq = max((int(e.get("seq", 0)) for e in contents.events), default=0)

    def _cut_damaged_tail(self, intact_bytes: int) -> None:
        with open(self.path, "rb") as fh:
            fh.seek(intact_bytes)
            tail = fh.read()
        aside = self.path.with_name(f"{self.path.name}.damaged-{time.strftime('%Y%m%d-%H%M%S')}")
        aside.write_bytes(tail)
        os.truncate(self.path, intact_bytes)
        os.fsync(self._file.fileno())

    def append(self, kind: str, **data: Any) -> dict:
        """Write one event and fsync it; returns the event once it is on disk."""
        with self._lock:
            if self._file.closed:
                raise JournalError(f"session journal {self.path} is closed")
            if self._broken is not None:
                raise JournalError(self._broken)
            event = {"seq": self.seq + 1, "time": time.time(), "kind": kind, **data}
            line = encode_event(event)  # refuses NaN / unknown types before anything is written
            self._write(line.encode("utf-8") + b"\n", kind)
            self.seq += 1
            return event

    def _write(self, data: bytes, kind: str) -> None:
        """The whole line on disk, or nothing of it: a failed write is cut off so the event is not there.

        The event the caller is told failed must not turn up later (with the seq the next event gets).
        """
        fd = self._file.fileno()
        start = os.lseek(fd, 0, os.SEEK_END)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        except OSError as exc:
            why = exc.strerror or str(exc)
            try:
                os.ftruncate(fd, start)
                os.fsync(fd)
            except OSError as undo:
                self._broken = (f"session journal {self.path} is damaged at its end ({undo.strerror or undo}) "
                                f"after a failed write; no more events are recorded: open the session again")
            raise JournalError(exc.errno, f"the {kind} event could not be written to the session journal "
                                          f"{self.path} ({why}); it is not recorded") from exc

    @property
    def closed(self) -> bool:
        return self._file.closed

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.close()  # also releases the lock

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass
class JournalContents:
    events: list[dict]
    damage: str | None = None  # a sentence about a damaged tail, if any
    intact_bytes: int = 0  # length of the intact prefix of the file


_fast = msgspec.json.Decoder()  # several times faster than json.loads on a 200,000-line journal


def _decode(raw: bytes) -> Any:
    """One line's JSON; msgspec for speed, the json module's verdict (and wording) for anything msgspec refuses."""
    try:
        return _fast.decode(raw)
    except msgspec.DecodeError:
        return json.loads(raw.decode("utf-8"))


def parse_lines(lines: Any, source: str) -> JournalContents:
    """Events from an iterable of raw lines (bytes, each ending in b"\\n" unless torn)."""
    events: list[dict] = []
    offset = 0
    for lineno, raw in enumerate(lines, 1):
        try:
            if not raw.endswith(b"\n"):
                raw.decode("utf-8")
                raise ValueError("incomplete last line: the writer was stopped while writing it")
            if not raw.strip():
                raise ValueError("empty line")
            event = _decode(raw)
            if not isinstance(event, dict) or "kind" not in event:
                raise ValueError("not an event")
        except (UnicodeDecodeError, ValueError) as exc:
            return JournalContents(events, f"{source}: line {lineno} is damaged ({exc}); "
                                           f"the {len(events)} events before it are intact and shown, "
                                           f"everything from line {lineno} on is ignored", offset)
        events.append(event)
        offset += len(raw)
    return JournalContents(events, None, offset)


def read_events(path: str | Path) -> JournalContents:
    """Every intact event; a damaged line ends the read with a message naming it."""
    p = Path(path)
    if not p.exists():
        return JournalContents([])
    with open(p, "rb") as fh:
        return parse_lines(fh, str(p))
