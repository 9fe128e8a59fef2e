"""Session stores: list, create, open, rename and delete recorded sessions.

Two backends share one API (:class:`SessionStore`):

- :class:`DirectoryStore` (the embedded default, no server): a directory of
  JSON Lines journals ``<name>.jsonl`` (see :mod:`cmm.session.journal`).
- :class:`PostgresStore`: tables ``cmm_sessions`` (id, name, created) and
  ``cmm_events`` (session_id, seq, event JSON text); each event is committed
  before ``append`` returns, so the same "acknowledged = durable" rule holds.

``open_store(spec)`` picks the backend from a directory path or a
``postgresql://`` URL.

Rename and delete of a session that is open for writing are REFUSED
(:class:`SessionBusy`): the writer holds an advisory lock (``flock`` on the
journal file, ``pg_advisory_lock`` on the PostgreSQL session), which the
operating system / server drop when the writer dies, so a crashed station
never leaves a session locked. Deleting needs the session to exist; the CLI
asks for confirmation unless ``--yes``.
"""

from __future__ import annotations

import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Protocol

from .journal import Journal, JournalBusy, JournalContents, encode_event, is_locked, parse_lines, read_events
from .model import Session

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._ -]{0,127}$")


class StoreError(RuntimeError):
    """A store action refused, in an operator's words."""


class SessionNotFound(StoreError):
    pass


class SessionBusy(StoreError):
    pass


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.match(name) or name.endswith((".", " ")):
        raise StoreError(f"{name!r} is not a usable session name: use letters, digits, '.', '_', '-' or spaces "
                         "(at most 128 characters, starting with a letter or digit)")
    return name


@dataclass(frozen=True)
class SessionInfo:
    name: str
    events: int
    modified: float  # wall seconds since the epoch
    open_for_writing: bool
    location: str


class Writer(Protocol):
    seq: int

    def append(self, kind: str, **data: Any) -> dict: ...

    def close(self) -> None: ...


class SessionStore(Protocol):
    location: str

    def list(self) -> list[SessionInfo]: ...

    def exists(self, name: str) -> bool: ...

    def create(self, name: str) -> Writer: ...

    def read(self, name: str) -> JournalContents: ...

    def rename(self, old: str, new: str) -> None: ...

    def delete(self, name: str) -> None: ...


def load_session(store: SessionStore, name: str) -> Session:
    """Open a recorded session (no machine needed); a damaged tail is reported in ``session.damage``."""
    from .bulk import gc_paused

    with gc_paused():  # a big journal would otherwise stall every thread of the station for seconds
        contents = store.read(name)
        return Session.from_events(contents.events, name, contents.damage)


# --------------------------------------------------------------------------- directory

_line_counts: dict[str, tuple[int, int, int]] = {}  # path -> (size, mtime_ns, lines): every open tab lists the store
_count_lock = threading.Lock()  # twenty tabs listing at once count a big journal once


def count_lines(path: Path, st: os.stat_result | None = None) -> int:
    """Lines (events) of a journal; cached by size and modification time, counted in 1 MB blocks."""
    st = st or path.stat()
    key = str(path)
    with _count_lock:
        cached = _line_counts.get(key)
        if cached is not None and cached[:2] == (st.st_size, st.st_mtime_ns):
            return cached[2]
        n = _count(path)
        _line_counts[key] = (st.st_size, st.st_mtime_ns, n)
        return n


def _count(path: Path) -> int:
    n, last = 0, b"\n"
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            n += block.count(b"\n")
            last = block[-1:]
    if last != b"\n":
        n += 1  # a torn last line counts, as it did when lines were iterated
    return n


class DirectoryStore:
    """The embedded store: ``<root>/<name>.jsonl`` journals."""

    def __init__(self, root: str | Path = "sessions") -> None:
        self.root = Path(root)
        self.location = str(self.root)

    def path(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.jsonl"

    def list(self) -> list[SessionInfo]:
        if not self.root.is_dir():
            return []
        out = []
        for p in sorted(self.root.glob("*.jsonl")):
            st = p.stat()
            out.append(SessionInfo(p.stem, count_lines(p, st), st.st_mtime, is_locked(p), str(p)))
        return out

    def exists(self, name: str) -> bool:
        return self.path(name).exists()

    def create(self, name: str, *, append: bool = False) -> Journal:
        p = self.path(name)
        if p.exists() and not append:
            raise StoreError(f"a session named {name!r} already exists in {self.location}")
        try:
            return Journal(p)
        except JournalBusy as exc:
            raise SessionBusy(str(exc)) from None

    def read(self, name: str) -> JournalContents:
        p = self.path(name)
        if not p.exists():
            raise SessionNotFound(f"there is no session {name!r} in {self.location}")
        return read_events(p)

    def _check_idle(self, name: str, action: str) -> Path:
        p = self.path(name)
        if not p.exists():
            raise SessionNotFound(f"there is no session {name!r} in {self.location}")
        if is_locked(p):
            raise SessionBusy(f"session {name!r} is being recorded by a station: close it before you {action} it")
        return p

    def rename(self, old: str, new: str) -> None:
        p = self._check_idle(old, "rename")
        q = self.path(new)
        if q.exists():
            raise StoreError(f"a session named {new!r} already exists in {self.location}")
        os.rename(p, q)

    def delete(self, name: str) -> None:
        self._check_idle(name, "delete").unlink()


# --------------------------------------------------------------------------- PostgreSQL

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
LOCK_SPACE = 0x434D4D  # "CMM": first key of the two-key advisory locks


def _connect(url: str) -> Any:
    try:
        import psycopg
    except ImportError:
        raise StoreError("the PostgreSQL session store needs psycopg: pip install 'cmm[postgres]'") from None
    try:
        return psycopg.connect(url, autocommit=True)
    except psycopg.Error as exc:
        raise StoreError(f"cannot connect to the session database: {exc}".strip()) from None


class PgWriter:
    """Appends events to one session; each INSERT is committed before ``append`` returns."""

    def __init__(self, url: str, session_id: int, name: str) -> None:
        self.name = name
        self.session_id = session_id
        self._conn = _connect(url)
        row = self._conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, session_id)).fetchone()
        if not row[0]:
            self._conn.close()
            raise SessionBusy(f"session {name!r} is already open for writing by another station")
        row = self._conn.execute("SELECT coalesce(max(seq), 0) FROM cmm_events WHERE session_id = %s",
                                 (session_id,)).fetchone()
        self.seq = int(row[0])

    def append(self, kind: str, **data: Any) -> dict:
        event = {"seq": self.seq + 1, "time": time.time(), "kind": kind, **data}
        line = encode_event(event)
        self._conn.execute("INSERT INTO cmm_events (session_id, seq, event) VALUES (%s, %s, %s)",
                           (self.session_id, event["seq"], line))
        self.seq += 1
        return event

    @property
    def closed(self) -> bool:
        return self._conn.closed

    def close(self) -> None:
        if not self._conn.closed:
            self._conn.close()  # ends the server session: the advisory lock goes with it


class PostgresStore:
    """Sessions in a PostgreSQL database (psycopg 3), selected by a ``postgresql://`` URL."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.location = re.sub(r"//([^:@/]*):[^@/]*@", r"//\1:***@", url)  # never print a password
        with _connect(url) as conn:
            conn.execute(SCHEMA)

    def _id(self, conn: Any, name: str) -> int:
        row = conn.execute("SELECT id FROM cmm_sessions WHERE name = %s", (check_name(name),)).fetchone()
        if row is None:
            raise SessionNotFound(f"there is no session {name!r} in {self.location}")
        return int(row[0])

    def list(self) -> list[SessionInfo]:
        with _connect(self.url) as conn:
            rows = conn.execute(
                "SELECT s.id, s.name, s.created, count(e.seq), "
                "coalesce(max((e.event::json->>'time')::double precision), s.created) "
                "FROM cmm_sessions s LEFT JOIN cmm_events e ON e.session_id = s.id "
                "GROUP BY s.id ORDER BY s.name").fetchall()
            out = []
            for sid, name, _created, n, modified in rows:
                busy = not self._try_lock(conn, sid)
                out.append(SessionInfo(name, int(n), float(modified), busy, f"{self.location}#{name}"))
            return out

    def _try_lock(self, conn: Any, sid: int) -> bool:
        ok = conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, sid)).fetchone()[0]
        if ok:
            conn.execute("SELECT pg_advisory_unlock(%s, %s)", (LOCK_SPACE, sid))
        return bool(ok)

    def exists(self, name: str) -> bool:
        with _connect(self.url) as conn:
            return conn.execute("SELECT 1 FROM cmm_sessions WHERE name = %s", (check_name(name),)).fetchone() is not None

    def create(self, name: str, *, append: bool = False) -> PgWriter:
        with _connect(self.url) as conn:
            row = conn.execute("INSERT INTO cmm_sessions (name, created) VALUES (%s, %s) "
                               "ON CONFLICT (name) DO NOTHING RETURNING id", (check_name(name), time.time())).fetchone()
            if row is None:
                if not append:
                    raise StoreError(f"a session named {name!r} already exists in {self.location}")
                sid = self._id(conn, name)
            else:
                sid = int(row[0])
        return PgWriter(self.url, sid, name)

    def read(self, name: str) -> JournalContents:
        with _connect(self.url) as conn:
            sid = self._id(conn, name)
            rows = conn.execute("SELECT event FROM cmm_events WHERE session_id = %s ORDER BY seq", (sid,)).fetchall()
        return parse_lines((r[0].encode("utf-8") + b"\n" for r in rows), f"{self.location}#{name}")

    def _locked(self, conn: Any, name: str, action: str) -> int:
        sid = self._id(conn, name)
        if not conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, sid)).fetchone()[0]:
            raise SessionBusy(f"session {name!r} is being recorded by a station: close it before you {action} it")
        return sid

    def rename(self, old: str, new: str) -> None:
        with _connect(self.url) as conn:
            sid = self._locked(conn, old, "rename")
            if conn.execute("SELECT 1 FROM cmm_sessions WHERE name = %s", (check_name(new),)).fetchone():
                raise StoreError(f"a session named {new!r} already exists in {self.location}")
            conn.execute("UPDATE cmm_sessions SET name = %s WHERE id = %s", (new, sid))

    def delete(self, name: str) -> None:
        with _connect(self.url) as conn:
            sid = self._locked(conn, name, "delete")
            conn.execute("DELETE FROM cmm_sessions WHERE id = %s", (sid,))


# --------------------------------------------------------------------------- selection


def is_url(spec: Any) -> bool:
    return isinstance(spec, str) and spec.startswith(("postgresql://", "postgres://"))


def open_store(spec: str | Path | SessionStore | None = None) -> SessionStore:
    """A store from a directory (default ``./sessions``) or a ``postgresql://`` URL
    (the environment variable CMM_SESSION_STORE gives the default)."""
    if spec is None:
        spec = os.environ.get("CMM_SESSION_STORE", "sessions")
    if not isinstance(spec, (str, Path)):
        return spec
    if is_url(spec):
        return PostgresStore(str(spec))
    return DirectoryStore(spec)


def open_session(ref: str | Path, store: str | Path | SessionStore | None = None) -> Session:
    """A session by name in a store, or directly by the path of a ``.jsonl`` journal."""
    p = Path(ref)
    if not is_url(store) and p.suffix == ".jsonl" and p.exists():
        contents = read_events(p)
        return Session.from_events(contents.events, p.stem, contents.damage)
    return load_session(open_store(store), str(ref))


def write_session(store: SessionStore, name: str, events: Iterator[dict] | list[dict]) -> None:
    """Write events (their kind and fields; seq and time are assigned anew, the original
    time is kept as ``recorded_time``) as a new session."""
    writer = store.create(name)
    try:
        for e in events:
            data = {k: v for k, v in e.items() if k not in ("seq", "time", "kind")}
            if "time" in e:
                data.setdefault("recorded_time", e["time"])
            writer.append(e["kind"], **data)
    finally:
        writer.close()

