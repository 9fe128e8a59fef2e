"""The PostgreSQL session store's writer: every event in a local journal first, uploaded in the background.

A hit is never refused because the shop's database is down. :class:`SpooledWriter` appends each event to a
local JSON Lines journal (fsync'ed before ``append`` returns, exactly as the embedded store) in the spool folder,
and wakes the process's :class:`SessionUploader`. The uploader (one thread per database and spool folder in a
process, the trends store's approach: journal first, upload what waits) sends the journal's lines in order, in
transactions of up to ``BATCH`` events, each ``INSERT ... ON CONFLICT DO NOTHING`` on the (session, seq) key: an
upload cut off after the commit and sent again stores nothing twice, and the database's rows are the journal's
lines byte for byte. After an outage it reconnects with a doubling back-off (0.5 s to 30 s), asks the database
how far the session got, and catches up from there. A closed session's journal is deleted once the database
has every line; one left by a station that stopped while the database was down is uploaded by the next
process that opens the store (``cmm sessions``, the station).

The spool folder: ``CMM_SESSION_SPOOL``, else ``~/.local/state/cmm/session-spool/<host_port_database>``.

What the operator sees while the database is down: ``status_text()`` ("database offline, N events waiting",
the station's status bar), never a database error; the session records on.

A session created while the database is down takes its name in the database when it comes back. If another
station created that name in the meantime (its events differ from this journal's at the same sequence numbers),
this journal is uploaded as ``<name> (recorded offline)`` instead, and the status says so: nothing is lost and
nothing is mixed.
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
from pathlib import Path
from typing import Any

from .writer import Journal, is_locked, try_lock

SCHEMA = """
CREATE TABLE IF NOT EXISTS cmm_sessions (
    id      bigserial PRIMARY KEY,
    name    text NOT NULL UNIQUE,
    created double precision NOT NULL
);
CREATE TABLE IF NOT EXISTS cmm_events (
    session_id bigint NOT NULL REFERENCES cmm_sessions(id) ON DELETE CASCADE,
    seq        integer NOT NULL,
    event      text NOT NULL,   -- the journal line, byte-identical to the JSON Lines format
    PRIMARY KEY (session_id, seq)
);
"""


def pg_schema() -> str:
    """The session tables (created if missing)."""
    return SCHEMA

LOCK_SPACE = 0x434D4D  # "CMM": first key of the two-key advisory locks (as cmm.journal.store)
OFFLINE_SUFFIX = " (recorded offline)"


def default_spool(location: str) -> Path:
    env = os.environ.get("CMM_SESSION_SPOOL")
    if env:
        return Path(env)
    base = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    where = re.sub(r"^postgres(ql)?://([^@/]*@)?", "", location).split("?")[0]
    return base / "cmm" / "session-spool" / (re.sub(r"[^A-Za-z0-9._-]+", "_", where).strip("_") or "default")


def connect(url: str, timeout: float = 3.0) -> Any:
    """A connection with TCP keepalives and a user timeout: a server that vanished is noticed in seconds."""
    import psycopg

    return psycopg.connect(url, autocommit=True, connect_timeout=max(1, round(timeout)), keepalives=1,
                           keepalives_idle=5, keepalives_interval=2, keepalives_count=2,
                           tcp_user_timeout=int(timeout * 2000))


def _words(exc: BaseException) -> str:
    """The error's first line (psycopg adds hints on further lines), or its type."""
    lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__


class _File:
    """What the uploader knows of one spool journal."""

    def __init__(self, name: str) -> None:
        self.name = name  # the session's name here
        self.target = name  # the session's name in the database (OFFLINE_SUFFIX after a name conflict)
        self.offset = 0  # bytes of the journal the database has
        self.uploaded = 0  # the last seq the database has (0: none, or not known yet)
        self.checked = False  # the journal's start was compared with the database's session of that name
        self.local_seq = 0  # the last seq journalled
        self.sid: int | None = None
        self.base = 0  # seq the database had when this process created the writer (events before are there)


class SessionUploader:
    """Uploads the spool folder's journals to the database in the background (see the module docstring)."""

    BATCH = 500
    RETRY_MIN, RETRY_MAX = 0.5, 30.0
    POLL = 5.0  # seconds between looks at the folder while connected (appends wake it at once)

    def __init__(self, url: str, spool: Path, connect_timeout: float = 3.0) -> None:
        self.url, self.spool, self.connect_timeout = url, Path(spool), connect_timeout
        self.spool.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Condition(self._lock)
        self._conn: Any = None
        self._files: dict[str, _File] = {}
        self._active: set[str] = set()  # sessions a writer of this process has open
        self._unlock: list[str] = []  # sessions closed here whose advisory lock is to go
        self._locked: dict[int, int] = {}  # session id -> advisory locks this connection holds on it
        self.connected = False
        self.tried = False
        self.error = ""
        self.since = 0.0  # when the database was lost
        self.backoff = self.RETRY_MIN
        self.next_try = 0.0
        self.uploaded = 0  # events uploaded by this process
        self.conflicts: list[str] = []
        for p in sorted(self.spool.glob("*.jsonl")):  # left by a station stopped while the database was down
            f = self._file(p.stem)
            f.local_seq = _last_seq(p)
        self._thread = threading.Thread(target=self._loop, name="session-upload", daemon=True)
        self._thread.start()

    # --- writers ---------------------------------------------------------------------------------

    def path(self, name: str) -> Path:
        return self.spool / f"{name}.jsonl"

    def _file(self, name: str) -> _File:
        f = self._files.get(name)
        if f is None:
            f = self._files[name] = _File(name)
        return f

    def register(self, name: str, *, append: bool, exists_error: Any, busy_error: Any) -> int:
        """A writer opens ``name``: when the database is reachable, its session is created (or, with ``append``,
        found) and locked against other stations now; the seq the database has is returned (0 when offline)."""
        with self._lock:
            f = self._file(name)
            conn = self._connection(force=True)
            self._active.add(name)
            if conn is None:
                return 0
            try:
                sid, created = self._session_id(conn, name)
                if not created and not append:
                    raise exists_error
                if not self._lock_session(conn, sid):
                    raise busy_error
                f.sid = sid
                row = conn.execute("SELECT coalesce(max(seq), 0) FROM cmm_events WHERE session_id = %s",
                                   (sid,)).fetchone()
                f.base = int(row[0])
                return f.base
            except Exception as exc:
                if exc is exists_error or exc is busy_error:
                    self._active.discard(name)
                    raise
                self._lost(exc)
                return 0

    def appended(self, name: str, seq: int) -> None:
        """A writer journalled event ``seq``: no lock is taken here (an upload in flight to a server that vanished
        can hold the uploader's lock for seconds; a hit never waits for it)."""
        f = self._files.get(name)
        if f is None:
            with self._lock:
                f = self._file(name)
        f.local_seq = seq
        self._wake.set()

    def release(self, name: str, flush: float = 0.0) -> None:
        """A writer closed ``name``: its advisory lock goes (in the uploader's thread: closing never waits for the
        database); with ``flush`` seconds, wait (while the database is reachable) until its events are uploaded."""
        self._active.discard(name)
        self._unlock.append(name)
        self._wake.set()
        if flush > 0:
            end = time.monotonic() + flush
            self.wait_uploaded(name, flush)
            with self._idle:  # and the lock released, so the session can be renamed at once
                while name in self._unlock and self.connected and time.monotonic() < end:
                    self._wake.set()
                    self._idle.wait(0.1)

    def _release_locks(self) -> None:
        while self._unlock:
            name = self._unlock[0]
            f = self._files.get(name)
            if not (name in self._active or f is None or f.sid is None or f.sid not in self._locked
                    or self._conn is None):
                try:
                    self._conn.execute("SELECT pg_advisory_unlock(%s, %s)", (LOCK_SPACE, f.sid))
                    self._locked[f.sid] -= 1
                    if self._locked[f.sid] <= 0:
                        del self._locked[f.sid]
                except Exception as exc:  # noqa: BLE001 - the lock ends with the connection anyway
                    self._lost(exc)
            self._unlock.remove(name)

    def wait_uploaded(self, name: str | None = None, timeout: float = 10.0) -> bool:
        """Wait until the database has every journalled event (of ``name``, or all); False when it did not
        within ``timeout`` (a real-time wait: the database is a real server)."""
        end = time.monotonic() + timeout
        with self._idle:
            while self.pending(name):
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._wake.set()
                self._idle.wait(min(left, 0.2))
            return True

    # --- state ---------------------------------------------------------------------------------

    def pending(self, name: str | None = None) -> int:
        """Events journalled and not yet in the database (lock-free: the status bar asks it five times a second)."""
        if name is not None:
            f = self._files.get(name)
            files = [] if f is None else [f]
        else:
            files = list(self._files.values())
        return sum(max(0, f.local_seq - max(f.uploaded, f.base)) for f in files)

    def status_text(self) -> str:
        """"database offline, N events waiting" while it is down (with the reason), else "" (or the conflicts).
        Lock-free, as :meth:`pending`."""
        n = self.pending()
        tail = "; ".join(self.conflicts[-2:])
        if self.connected or not self.tried:
            return tail
        lost = time.strftime("%H:%M:%S", time.localtime(self.since)) if self.since else "start-up"
        return (f"database offline, {n} event{'s' if n != 1 else ''} waiting (since {lost}: "
                f"{self.error or 'not reached'}; the session records on and uploads when it is back)"
                + (f"; {tail}" if tail else ""))

    # --- the connection ----------------------------------------------------------------------------

    def _connection(self, force: bool = False) -> Any:

        if self._conn is not None and not self._conn.closed:
            return self._conn
        if not force and time.monotonic() < self.next_try:
            return None
        self.tried = True
        try:
            self._conn = connect(self.url, self.connect_timeout)
            with self._conn.transaction():
                self._conn.execute("SELECT pg_advisory_xact_lock(%s, %s)", (LOCK_SPACE, 0x53455353))  # "SESS"
                self._conn.execute(SCHEMA)
        except Exception as exc:  # noqa: BLE001 - psycopg's OperationalError and friends: offline
            self._lost(exc)
            return None
        self.connected, self.error, self.backoff = True, "", self.RETRY_MIN
        self._locked.clear()
        for f in self._files.values():  # the database may have restarted: ask again how far each session got
            f.checked = f.checked and f.sid is not None
            f.sid = None
        for name in list(self._active):  # the sessions open here are this station's again
            try:
                f = self._files[name]
                f.sid, _ = self._session_id(self._conn, f.target)
                self._lock_session(self._conn, f.sid)
            except Exception as exc:  # noqa: BLE001
                self._lost(exc)
                return None
        return self._conn

    def _lost(self, exc: BaseException) -> None:
        if self.connected or not self.since:
            self.since = time.time()
        self.connected, self.error = False, _words(exc)
        self.next_try = time.monotonic() + self.backoff
        self.backoff = min(self.backoff * 2.0, self.RETRY_MAX)
        self._drop_connection()
        self._locked.clear()

    def _drop_connection(self) -> None:
        """Close the connection if any (a dead one may fail to close: that is fine) and forget it."""
        if self._conn is not None:
            try:
                self._conn.close()
            except Exception:  # noqa: BLE001
                pass
        self._conn = None

    def _session_id(self, conn: Any, name: str, created: float | None = None) -> tuple[int, bool]:
        row = conn.execute("INSERT INTO cmm_sessions (name, created) VALUES (%s, %s) ON CONFLICT (name) DO NOTHING "
                           "RETURNING id", (name, created or time.time())).fetchone()
        if row is not None:
            return int(row[0]), True
        return int(conn.execute("SELECT id FROM cmm_sessions WHERE name = %s", (name,)).fetchone()[0]), False

    def _lock_session(self, conn: Any, sid: int) -> bool:
        ok = bool(conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, sid)).fetchone()[0])
        if ok:
            self._locked[sid] = self._locked.get(sid, 0) + 1
        return ok

    # --- uploading ---------------------------------------------------------------------------------

    def _loop(self) -> None:
        while not self._stop.is_set():
            if self.connected:
                self._wake.wait(self.POLL)
            else:  # offline: appends do not wake it (each would only cost the station time); the back-off does
                self._stop.wait(max(0.05, self.next_try - time.monotonic()))
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self.sync()
            except Exception as exc:  # noqa: BLE001 - the journal keeps every event; the next round tries again
                with self._lock:
                    self._lost(exc)
            with self._idle:
                self._idle.notify_all()

    def sync(self) -> int:
        """Upload what waits, in order; returns how many events were sent."""
        sent = 0
        with self._lock:
            for p in self.spool.glob("*.jsonl"):
                if p.stem not in self._files:
                    self._file(p.stem).local_seq = _last_seq(p)
            if not self.pending() and self.connected:
                self._release_locks()
                self._forget_done()
                return 0
            conn = self._connection()
            if conn is None:
                return 0
            self._release_locks()
            for f in list(self._files.values()):
                sent += self._upload(conn, f)
            self._forget_done()
        return sent

    def _upload(self, conn: Any, f: _File) -> int:
        path = self.path(f.name)
        if not path.exists():
            return 0
        if f.name not in self._active and is_locked(path):
            return 0  # another process records it: its own uploader sends it
        fresh = f.sid is None  # first look on this connection: ask the database how far the session got
        if fresh:
            f.sid, _ = self._session_id(conn, f.target, _first_time(path))
            if f.name in self._active:
                self._lock_session(conn, f.sid)
        if f.uploaded >= f.local_seq and not fresh:
            return 0
        db_max = f.uploaded if not fresh and f.checked else int(conn.execute(
            "SELECT coalesce(max(seq), 0) FROM cmm_events WHERE session_id = %s", (f.sid,)).fetchone()[0])
        if not f.checked:
            f.checked = True
            first = _first_line(path)
            if first is not None and db_max >= first[0] and f.offset == 0 and f.base < first[0]:
                row = conn.execute("SELECT event FROM cmm_events WHERE session_id = %s AND seq = %s",
                                   (f.sid, first[0])).fetchone()
                if row is not None and row[0] != first[1]:  # another station's session of the same name
                    f.target = _free_name(conn, f.name + OFFLINE_SUFFIX)
                    f.sid, _ = self._session_id(conn, f.target, _first_time(path))
                    if f.name in self._active:
                        self._lock_session(conn, f.sid)
                    self.conflicts.append(f"session {f.name!r} was created by another station while the database "
                                          f"was down: this station's events are in {f.target!r}")
                    db_max = 0
        if db_max < f.uploaded:  # the database lost what it had (restored from a backup): send it all again
            f.offset = 0
        f.uploaded = db_max
        sent = 0
        while True:
            batch, end = _read_batch(path, f.offset, f.uploaded, self.BATCH)
            if not batch:
                f.offset = max(f.offset, end)
                return sent
            with conn.transaction():
                with conn.cursor() as cur:
                    cur.executemany("INSERT INTO cmm_events (session_id, seq, event) VALUES (%s, %s, %s) "
                                    "ON CONFLICT DO NOTHING", [(f.sid, seq, line) for seq, line in batch])
            f.offset, f.uploaded = end, batch[-1][0]
            sent += len(batch)
            self.uploaded += len(batch)

    def _forget_done(self) -> None:
        """A closed session whose every event the database has: its journal goes."""
        for name, f in list(self._files.items()):
            if name in self._active or name in self._unlock or f.uploaded < f.local_seq:
                continue
            path = self.path(name)
            if not path.exists():
                del self._files[name]
                continue
            if f.local_seq == 0 and f.uploaded == 0 and f.sid is None:
                continue  # not looked at yet
            try:
                with open(path, "rb") as fh:
                    if not try_lock(fh):
                        continue
                    if _last_seq(path) > f.uploaded:
                        continue
                    path.unlink()
                del self._files[name]
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=5)
        with self._lock:
            self._drop_connection()


def _read_batch(path: Path, offset: int, after: int, limit: int) -> tuple[list[tuple[int, str]], int]:
    """Up to ``limit`` complete lines with seq > ``after`` from byte ``offset``; (seq, line) and the offset after
    the last line read."""
    out: list[tuple[int, str]] = []
    with open(path, "rb") as fh:
        fh.seek(offset)
        pos = offset
        for raw in fh:
            if not raw.endswith(b"\n"):
                break  # being written, or a torn tail: the next round (or the next open) decides
            line = raw[:-1].decode("utf-8")
            try:
                seq = int(json.loads(line).get("seq", 0))
            except (ValueError, AttributeError):
                break
            pos += len(raw)
            if seq > after:
                out.append((seq, line))
                if len(out) >= limit:
                    break
        return out, pos


def _first_line(path: Path) -> tuple[int, str] | None:
    batch, _ = _read_batch(path, 0, -1, 1)
    return batch[0] if batch else None


def _first_time(path: Path) -> float | None:
    first = _first_line(path)
    if first is None:
        return None
    try:
        return float(json.loads(first[1]).get("time"))
    except (TypeError, ValueError):
        return None


def _last_seq(path: Path) -> int:
    """The last complete line's seq (reads the file's end only)."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            fh.seek(max(0, size - 65536))
            lines = fh.read().split(b"\n")
    except OSError:
        return 0
    for raw in reversed(lines[:-1]):  # the last element follows the last newline (empty or torn)
        try:
            return int(json.loads(raw).get("seq", 0))
        except (ValueError, AttributeError):
            continue
    return 0


def _free_name(conn: Any, name: str) -> str:
    k, candidate = 1, name
    while conn.execute("SELECT 1 FROM cmm_sessions WHERE name = %s", (candidate,)).fetchone():
        k += 1
        candidate = f"{name} {k}"
    return candidate


_uploaders: dict[tuple[str, str], SessionUploader] = {}
_uploaders_lock = threading.Lock()


def uploader(url: str, spool: Path) -> SessionUploader:
    """The process's uploader for this database and spool folder (started on first use)."""
    key = (url, str(Path(spool).resolve()))
    with _uploaders_lock:
        up = _uploaders.get(key)
        if up is None or up._stop.is_set():
            up = _uploaders[key] = SessionUploader(url, Path(spool))
        return up


class SpooledWriter:
    """A session writer of the PostgreSQL store: the local journal now, the database in the background."""

    FLUSH_ON_CLOSE = 5.0  # seconds close() waits for the upload while the database is reachable

    def __init__(self, up: SessionUploader, name: str, journal: Journal, base: int) -> None:
        self.name, self._up, self._journal = name, up, journal
        self._journal.seq = max(self._journal.seq, base)  # continue after what the database has
        up.appended(name, self._journal.seq)

    @property
    def seq(self) -> int:
        return self._journal.seq

    @property
    def path(self) -> Path:
        return self._journal.path

    @property
    def damage(self) -> str | None:
        return self._journal.damage

    def append(self, kind: str, **data: Any) -> dict:
        event = self._journal.append(kind, **data)  # fsync'ed here; a database outage cannot refuse it
        self._up.appended(self.name, event["seq"])
        return event

    def pending(self) -> int:
        return self._up.pending(self.name)

    def upload_status(self) -> str:
        return self._up.status_text()

    @property
    def closed(self) -> bool:
        return self._journal.closed

    def close(self) -> None:
        if self._journal.closed:
            return
        self._journal.close()
        self._up.release(self.name, flush=self.FLUSH_ON_CLOSE if self._up.connected else 0.0)

    def __enter__(self) -> "SpooledWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
