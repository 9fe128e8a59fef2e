"""Session stores: list, create, open, rename and delete recorded sessions.

Two backends share one API (:class:`SessionStore`):

- :class:`DirectoryStore` (the embedded default, no server): a directory of
  JSON Lines journals ``<name>.jsonl`` (see :mod:`cmm.journal.writer`).
- :class:`PostgresStore`: tables ``cmm_sessions`` (id, name, created) and
  ``cmm_events`` (session_id, seq, event JSON text). Each event is fsync'ed to a
  local journal (the spool folder) before ``append`` returns, so the same
  "acknowledged = durable" rule holds, and uploaded in the background
  (:mod:`cmm.journal.store_pg`): a database outage never refuses an event.

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

import json
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Protocol

from .session import Session
from .writer import Journal, JournalBusy, JournalContents, is_locked, parse_lines, read_events

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


LOCK_SPACE = 0x434D4D  # "CMM": first key of the two-key advisory locks


def json_seq(raw: bytes) -> int:
    """The seq of one journal line (0 when it has none)."""
    try:
        return int(json.loads(raw).get("seq", 0))
    except (ValueError, AttributeError):
        return 0


class PostgresStore:
    """Sessions in a PostgreSQL database (psycopg 3), selected by a ``postgresql://`` URL.

    A session being recorded is journalled locally first and uploaded in the background
    (:mod:`cmm.journal.store_pg`): an outage of the database delays the upload, it never refuses an event.
    Opening the store does not need the database; listing and reading do (with the local journals of sessions
    still uploading as a fallback)."""

    def __init__(self, url: str, spool: str | Path | None = None) -> None:
        from .store_pg import default_spool, uploader

        self.url = url
        self.location = re.sub(r"//([^:@/]*):[^@/]*@", r"//\1:***@", url)  # never print a password
        self.spool = Path(spool) if spool is not None else default_spool(self.location)
        self.uploader = uploader(url, self.spool)

    def _conn(self) -> Any:
        """A short-lived connection, or StoreError in words."""
        try:
            import psycopg  # noqa: F401
        except ImportError:
            raise StoreError("the PostgreSQL session store needs psycopg: pip install 'cmm[postgres]'") from None
        from .store_pg import connect, pg_schema

        try:
            conn = connect(self.url, 3.0)
        except Exception as exc:  # noqa: BLE001 - psycopg's errors, in words
            raise StoreError(f"cannot connect to the session database: {' '.join(str(exc).split())}") from None
        try:
            with conn.transaction():
                conn.execute("SELECT pg_advisory_xact_lock(%s, %s)", (LOCK_SPACE, 0x53455353))
                conn.execute(pg_schema())
        except Exception as exc:  # noqa: BLE001
            conn.close()
            raise StoreError(f"cannot use the session database: {' '.join(str(exc).split())}") from None
        return conn

    def _spooled(self, name: str) -> Path | None:
        p = self.spool / f"{name}.jsonl"
        return p if p.exists() else None

    def _id(self, conn: Any, name: str) -> int:
        row = conn.execute("SELECT id FROM cmm_sessions WHERE name = %s", (check_name(name),)).fetchone()
        if row is None:
            raise SessionNotFound(f"there is no session {name!r} in {self.location}")
        return int(row[0])

    def list(self) -> list[SessionInfo]:
        """The database's sessions, and those still waiting in the local journal to upload; while the database
        is unreachable, the local ones only."""
        local = {p.stem: p for p in sorted(self.spool.glob("*.jsonl"))}
        out: dict[str, SessionInfo] = {}
        try:
            conn = self._conn()
        except StoreError:
            if not local:
                raise
            conn = None
        if conn is not None:
            with conn:
                rows = conn.execute(
                    "SELECT s.id, s.name, s.created, count(e.seq), "
                    "coalesce(max((e.event::json->>'time')::double precision), s.created) "
                    "FROM cmm_sessions s LEFT JOIN cmm_events e ON e.session_id = s.id "
                    "GROUP BY s.id ORDER BY s.name").fetchall()
                for sid, name, _created, n, modified in rows:
                    busy = not self._try_lock(conn, sid) or (name in local and is_locked(local[name]))
                    events = int(n) + (self.uploader.pending(name) if name in local else 0)
                    out[name] = SessionInfo(name, events, float(modified), busy, f"{self.location}#{name}")
        for name, p in local.items():
            if name not in out:
                st = p.stat()
                out[name] = SessionInfo(name, count_lines(p, st), st.st_mtime, is_locked(p),
                                        f"{self.location}#{name} (waiting to upload: {p})")
        return [out[k] for k in sorted(out)]

    def _try_lock(self, conn: Any, sid: int) -> bool:
        ok = conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, sid)).fetchone()[0]
        if ok:
            conn.execute("SELECT pg_advisory_unlock(%s, %s)", (LOCK_SPACE, sid))
        return bool(ok)

    def exists(self, name: str) -> bool:
        if self._spooled(check_name(name)) is not None:
            return True
        with self._conn() as conn:
            row = conn.execute("SELECT 1 FROM cmm_sessions WHERE name = %s", (check_name(name),)).fetchone()
            return row is not None

    def create(self, name: str, *, append: bool = False) -> Any:
        """A writer for ``name`` (a new session, or with ``append`` an existing one continued); works while the
        database is down (the name is claimed in the database when it is back)."""
        from .store_pg import SpooledWriter

        check_name(name)
        self.spool.mkdir(parents=True, exist_ok=True)
        path = self.spool / f"{name}.jsonl"
        if path.exists() and not append and count_lines(path):
            raise StoreError(f"a session named {name!r} already exists in {self.location}")
        try:
            journal = Journal(path)
        except JournalBusy:
            raise SessionBusy(f"session {name!r} is already open for writing by another station") from None
        try:
            base = self.uploader.register(
                name, append=append,
                exists_error=StoreError(f"a session named {name!r} already exists in {self.location}"),
                busy_error=SessionBusy(f"session {name!r} is already open for writing by another station"))
        except StoreError:
            journal.close()
            if not count_lines(path):
                path.unlink(missing_ok=True)
            raise
        return SpooledWriter(self.uploader, name, journal, base)

    def read(self, name: str) -> JournalContents:
        """The database's events, then those journalled here and not uploaded yet; while the database is
        unreachable, the local journal of a session recorded here."""
        check_name(name)
        local = self._spooled(name)
        try:
            with self._conn() as conn:
                row = conn.execute("SELECT id FROM cmm_sessions WHERE name = %s", (name,)).fetchone()
                rows = [] if row is None else conn.execute(
                    "SELECT event FROM cmm_events WHERE session_id = %s ORDER BY seq", (int(row[0]),)).fetchall()
        except StoreError:
            if local is None:
                raise
            return read_events(local)
        if row is None and local is None:
            raise SessionNotFound(f"there is no session {name!r} in {self.location}")
        lines = [r[0].encode("utf-8") + b"\n" for r in rows]
        if local is not None:
            top = json_seq(lines[-1]) if lines else 0
            with open(local, "rb") as fh:
                lines += [raw for raw in fh if raw.endswith(b"\n") and json_seq(raw) > top]
        return parse_lines(iter(lines), f"{self.location}#{name}")

    def _locked(self, conn: Any, name: str, action: str) -> int:
        local = self._spooled(name)
        if local is not None:
            if is_locked(local):
                raise SessionBusy(f"session {name!r} is being recorded by a station: close it before you {action} it")
            raise SessionBusy(f"session {name!r} still has events waiting to upload to the database: "
                              f"{action} it once they are there")
        sid = self._id(conn, name)
        if not conn.execute("SELECT pg_try_advisory_lock(%s, %s)", (LOCK_SPACE, sid)).fetchone()[0]:
            raise SessionBusy(f"session {name!r} is being recorded by a station: close it before you {action} it")
        return sid

    def rename(self, old: str, new: str) -> None:
        with self._conn() as conn:
            sid = self._locked(conn, old, "rename")
            if conn.execute("SELECT 1 FROM cmm_sessions WHERE name = %s", (check_name(new),)).fetchone():
                raise StoreError(f"a session named {new!r} already exists in {self.location}")
            conn.execute("UPDATE cmm_sessions SET name = %s WHERE id = %s", (new, sid))

    def delete(self, name: str) -> None:
        with self._conn() as conn:
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

