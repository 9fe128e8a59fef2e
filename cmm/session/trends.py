"""Trends across parts and stations: every run of a routine or program is a part in a series.

A part (:class:`PartResult`) is the series key (the routine or program name), the station that measured it,
its run id (unique per station), its serial, the time, and per characteristic the measured value, nominal,
tolerance limits and unit (:class:`Measured`). :meth:`Trends.record_part` is the one call a runner makes
(:func:`cmm.metrology.measured.feature_values` turns fitted features into characteristics).

Storage, built like the session store (:mod:`cmm.journal.store`):

- **local** (always): ``<dir>/parts.jsonl``, an append-only journal (:class:`cmm.journal.writer.Journal`:
  fsync'ed before ``record_part`` returns) and ``<dir>/index.sqlite``, a query index rebuilt from the journal
  whenever it is behind or missing (it holds nothing the journal does not);
- **shared** (optional): a PostgreSQL database several stations point at (:mod:`cmm.session.trends_pg`).
  Each part is uploaded after it is journalled; a part that cannot be uploaded (the database is down) waits
  in the journal and goes up with the next part or the next :meth:`Trends.sync`. The upload is idempotent,
  keyed by (station, run id): a part uploaded twice (a crash between the commit and the local mark) is
  stored once.

Chart queries (:meth:`Trends.history`) ask the database when one is configured and reachable (every station's
parts) and the local index otherwise (this station's parts, :attr:`Trends.source` says which).
"""

from __future__ import annotations

import math
import os
import socket
import sqlite3
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, NamedTuple, Sequence

import numpy as np

from ..journal.writer import Journal, JournalBusy, _decode
from ..metrology.measured import SEP, Measured, TrendError
from .trends_parts import PartsCache


@dataclass(frozen=True)
class PartResult:
    series: str
    station: str
    run_id: str
    time: float
    serial: str
    values: tuple[Measured, ...]


@dataclass
class History:
    """One characteristic of a series over its parts, in time order (what a chart is drawn from)."""

    series: str
    characteristic: str
    unit: str
    time: np.ndarray
    value: np.ndarray
    nominal: np.ndarray  # NaN: none
    lower: np.ndarray  # NaN: no lower limit
    upper: np.ndarray
    station: list[str]
    run_id: list[str]
    serial: list[str]
    source: str = "local"  # "database" (every station) or "local" (this station)

    def __len__(self) -> int:
        return len(self.value)


DEVIATION_WORDS = ("DIAM", "RAD", "DISTB", "ANGLB")  # DMIS tolerances whose value is a deviation from a nominal


def tolerance_values(evaluations: Iterable[Any]) -> list[Measured]:
    """DMIS tolerance results (:class:`cmm.dmis.tolerances.Evaluation`: ``tolerance`` with ``label``, ``word``,
    ``lower``, ``upper``; ``value``; ``features``) as trend values named ``<features> / <word> T(<label>)``:
    sizes, distances and angles as the deviation from their nominal between the tolerance's limits, form,
    orientation, position, profile and runout as the zone with an upper limit only. A tolerance output twice
    counts once (the last)."""
    out: dict[str, Measured] = {}
    for ev in evaluations:
        t = ev.tolerance
        name = f"{'-'.join(ev.features)}{SEP}{t.word} T({t.label})"
        unit = "deg" if t.word == "ANGLB" else "mm"
        if t.word in DEVIATION_WORDS:
            out[name] = Measured(name, float(ev.value), 0.0, float(t.lower), float(t.upper), unit)
        else:
            out[name] = Measured(name, float(ev.value), 0.0, None, float(t.upper), unit)
    return list(out.values())


def check_values(values: Iterable[Measured | dict | list | tuple]) -> tuple[Measured, ...]:
    out: list[Measured] = []
    seen: set[str] = set()
    for v in values:
        if isinstance(v, dict):
            v = Measured(**v)
        elif isinstance(v, (list, tuple)):
            v = Measured(*v)
        if not isinstance(v.name, str) or not v.name.strip():
            raise TrendError("a characteristic needs a name")
        if v.name in seen:
            raise TrendError(f"the characteristic {v.name!r} is given twice for one part")
        seen.add(v.name)
        nums = [v.value] + [x for x in (v.nominal, v.lower, v.upper) if x is not None]
        if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in nums):
            raise TrendError(f"the characteristic {v.name!r} has a value or limit that is not a number: "
                             f"value {v.value!r}, nominal {v.nominal!r}, limits {v.lower!r} .. {v.upper!r}")
        if v.lower is not None and v.upper is not None and v.lower > v.upper:
            raise TrendError(f"the characteristic {v.name!r} has its lower limit {v.lower} above its upper "
                             f"limit {v.upper}")
        out.append(Measured(v.name, float(v.value), *(None if x is None else float(x)
                                                      for x in (v.nominal, v.lower, v.upper)), str(v.unit)))
    if not out:
        raise TrendError("a part needs at least one measured characteristic")
    return tuple(out)


def default_station() -> str:
    return os.environ.get("CMM_STATION") or socket.gethostname() or "station"


def open_trends(directory: str | Path, *, station: str | None = None, database: str | None = None,
                sessions: str | Path | None = None, background: bool = True) -> "Trends":
    """A station's trends as its front ends open them (``cmm serve``, ``cmm run``): the database is ``database``,
    else CMM_TRENDS_DB, else the session store when that is a ``postgresql://`` URL; connected (and what waited
    uploaded) at once, then kept up to date in the background."""
    from ..journal.store import is_url

    db = database or os.environ.get("CMM_TRENDS_DB") or (str(sessions) if is_url(sessions) else None)
    trends = Trends(directory, station=station, database=db)
    trends.sync()  # connect now (and upload what waited since the last run), so the first status is true
    return trends.start() if background else trends


# --------------------------------------------------------------------------- local index

# the index is a cache of the fsync'ed journal: write-ahead log without a sync per commit (a crash may lose its
# newest commits, never its consistency; the next catch-up reads those parts from the journal again)
INDEX_PRAGMAS = "PRAGMA journal_mode = WAL; PRAGMA synchronous = NORMAL;"
INDEX_VERSION = 3  # PRAGMA user_version of the layout below; an index of another layout is rebuilt
INDEX_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS parts (
    seq INTEGER PRIMARY KEY, station TEXT NOT NULL, run_id TEXT NOT NULL, series TEXT NOT NULL,
    serial TEXT NOT NULL, time REAL NOT NULL, UNIQUE (station, run_id));
CREATE INDEX IF NOT EXISTS parts_series ON parts (series, station);
CREATE TABLE IF NOT EXISTS chars (
    id INTEGER PRIMARY KEY, series TEXT NOT NULL, characteristic TEXT NOT NULL, unit TEXT NOT NULL,
    UNIQUE (series, characteristic));
-- clustered by characteristic and time: one chart is one contiguous range of this table
CREATE TABLE IF NOT EXISTS vals (
    char_id INTEGER NOT NULL, time REAL NOT NULL, seq INTEGER NOT NULL, pos INTEGER NOT NULL,
    value REAL NOT NULL, nominal REAL, lower REAL, upper REAL,
    PRIMARY KEY (char_id, time, seq)) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS vals_seq ON vals (seq);
-- each characteristic's values up to a part, in chart order, as packed float64 / int64 columns: a chart reads one
-- row and the few values journalled since (the values table stays the record; this is rebuilt from it)
CREATE TABLE IF NOT EXISTS packed (
    char_id INTEGER PRIMARY KEY, upto_seq INTEGER NOT NULL, time BLOB NOT NULL, seq BLOB NOT NULL,
    value BLOB NOT NULL, nominal BLOB NOT NULL, lower BLOB NOT NULL, upper BLOB NOT NULL);
"""
PACK_AFTER = 200  # values journalled since a characteristic was packed before a chart query packs it again


class LocalIndex:
    """SQLite index of a parts journal; caught up from the journal's byte offset it last read."""

    def __init__(self, journal_path: Path, path: Path) -> None:
        self.journal_path = journal_path
        self.path = path
        self._lock = threading.RLock()  # one connection for the station's threads: one statement at a time
        self.who = PartsCache()  # seq -> station, run id, serial, as read
        self._parts_seq = 0
        self.db = self._open()

    def _open(self) -> sqlite3.Connection:
        # autocommit; catch_up and the upload mark take their own transactions
        for _attempt in range(2):
            try:
                db = sqlite3.connect(self.path, check_same_thread=False, timeout=30.0, isolation_level=None)
                db.executescript(INDEX_PRAGMAS)
                version = db.execute("PRAGMA user_version").fetchone()[0]
                if version != INDEX_VERSION and db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:
                    raise sqlite3.DatabaseError(f"index layout {version}")
                db.executescript(INDEX_SCHEMA + f"PRAGMA user_version = {INDEX_VERSION};")
                return db
            except sqlite3.DatabaseError:  # damaged or of another layout: it only caches the journal, rebuild it
                try:
                    db.close()
                except Exception:  # noqa: BLE001
                    pass
                for suffix in ("", "-wal", "-shm"):
                    Path(f"{self.path}{suffix}").unlink(missing_ok=True)
        raise TrendError(f"cannot open the trends index {self.path}")

    def _q(self, sql: str, args: Any = ()) -> list[tuple]:
        with self._lock:
            return self.db.execute(sql, args).fetchall()

    def meta(self, key: str) -> int:
        rows = self._q("SELECT value FROM meta WHERE key = ?", (key,))
        return 0 if not rows else int(rows[0][0])

    def set_meta(self, key: str, value: int) -> None:
        self._q("INSERT INTO meta (key, value) VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET value = excluded.value",
                (key, int(value)))

    def catch_up(self) -> int:
        """Index the journal's complete lines past the last offset read; returns how many parts were added."""
        with self._lock:
            try:
                size = self.journal_path.stat().st_size
            except FileNotFoundError:
                return 0
            if size == self.meta("journal_bytes"):
                return 0
            # BEGIN IMMEDIATE: two processes catching up at once index each line once
            self.db.execute("BEGIN IMMEDIATE")
            try:
                offset = self.meta("journal_bytes")
                if size < offset:  # the journal was replaced: index it afresh
                    for table in ("parts", "vals", "chars", "meta", "packed"):
                        self.db.execute(f"DELETE FROM {table}")
                    offset = 0
                    self.who, self._parts_seq = PartsCache(), 0
                with open(self.journal_path, "rb") as fh:
                    fh.seek(offset)
                    data = fh.read(max(size - offset, 0))
                end = data.rfind(b"\n") + 1  # a torn last line waits (the journal's writer cuts it on reopen)
                events = []
                for raw in data[:end].splitlines():
                    try:
                        e = _decode(raw)
                    except ValueError:
                        continue
                    if isinstance(e, dict) and e.get("kind") == "part":
                        events.append(e)
                self.add(events)
                self.set_meta("journal_bytes", offset + end)
                self.db.execute("COMMIT")
            except BaseException:
                self.db.execute("ROLLBACK")
                raise
            if len(events) >= PACK_AFTER:  # many parts at once (a new index, a long way behind): pack them now
                self.pack()
            return len(events)

    def pack(self, char_id: int | None = None) -> None:
        """Write the packed columns of one characteristic (None: every one) from the values table."""
        with self._lock:
            ids = [char_id] if char_id is not None else [r[0] for r in self.db.execute("SELECT id FROM chars")]
            upto = self.db.execute("SELECT coalesce(max(seq), 0) FROM parts").fetchone()[0]
            out = []
            for cid in ids:
                rows = self.db.execute("SELECT time, seq, value, ifnull(nominal, 'NaN'), ifnull(lower, 'NaN'), "
                                       "ifnull(upper, 'NaN') FROM vals WHERE char_id = ? AND seq <= ? "
                                       "ORDER BY char_id, time, seq", (cid, upto)).fetchall()
                cols = list(zip(*rows)) if rows else [()] * 6
                out.append((cid, upto, *(np.asarray(c, dtype=np.int64 if k == 1 else np.float64).tobytes()
                                          for k, c in enumerate(cols))))
            try:
                self.db.execute("BEGIN IMMEDIATE")
                self.db.executemany("INSERT OR REPLACE INTO packed VALUES (?, ?, ?, ?, ?, ?, ?, ?)", out)
                self.db.execute("COMMIT")
            except sqlite3.OperationalError:  # another process holds the index: the next query packs it
                if self.db.in_transaction:
                    self.db.execute("ROLLBACK")

    def _char_ids(self, keys: list[tuple[str, str, str]]) -> dict[tuple[str, str], int]:
        """Ids of (series, characteristic, unit), new ones numbered in the order first seen."""
        self.db.executemany("INSERT OR IGNORE INTO chars (series, characteristic, unit) VALUES (?, ?, ?)", keys)
        return {(a, b): i for i, a, b in self.db.execute("SELECT id, series, characteristic FROM chars")}

    def add(self, events: list[dict]) -> None:
        parts, keys = [], {}
        for e in events:
            parts.append((e["seq"], e["station"], e["run_id"], e["series"], e.get("serial", ""), e["part_time"]))
            for name, _v, _n, _lo, _up, unit in e["values"]:
                keys.setdefault((e["series"], name, unit), None)
        ids = self._char_ids(list(keys)) if keys else {}
        vals = [(ids[(e["series"], row[0])], e["part_time"], e["seq"], k, *row[1:5])
                for e in events for k, row in enumerate(e["values"])]
        self.db.executemany("INSERT OR IGNORE INTO parts VALUES (?, ?, ?, ?, ?, ?)", parts)
        self.db.executemany("INSERT OR IGNORE INTO vals VALUES (?, ?, ?, ?, ?, ?, ?, ?)", vals)

    def series(self) -> list[str]:
        return [r[0] for r in self._q("SELECT DISTINCT series FROM chars ORDER BY series")]

    def characteristics(self, series: str) -> list[tuple[str, str]]:
        return [(r[0], r[1]) for r in self._q(
            "SELECT characteristic, unit FROM chars WHERE series = ? ORDER BY id", (series,))]

    def unit(self, series: str, characteristic: str) -> str:
        rows = self._q("SELECT unit FROM chars WHERE series = ? AND characteristic = ?", (series, characteristic))
        return "mm" if not rows else str(rows[0][0])

    def stations(self, series: str) -> list[str]:
        return [r[0] for r in self._q("SELECT DISTINCT station FROM parts WHERE series = ? ORDER BY station",
                                      (series,))]

    def columns(self, series: str, characteristic: str, station: str | None, *, pack: bool = True) -> "Columns":
        """Every part's time, value, nominal, lower, upper (numbers, NaN: none) and station, run id, serial, in
        time order, as columns: the characteristic's packed columns (one row) and the values journalled since
        they were packed, merged in time order; one station's parts picked by a code per part. Who measured each
        part comes from a cache of the parts table (lines are only ever added to the journal)."""
        with self._lock:
            ids = self._q("SELECT id FROM chars WHERE series = ? AND characteristic = ?", (series, characteristic))
            if not ids:
                return EMPTY_COLUMNS
            cid = ids[0][0]
            packed = self._q("SELECT upto_seq, time, seq, value, nominal, lower, upper FROM packed WHERE char_id = ?",
                             (cid,))
            upto = packed[0][0] if packed else 0
            tail = self._q("SELECT time, seq, value, ifnull(nominal, 'NaN'), ifnull(lower, 'NaN'), "
                           "ifnull(upper, 'NaN') FROM vals INDEXED BY vals_seq WHERE seq > ? AND char_id = ?",
                           (upto, cid))
            if pack and (len(tail) >= PACK_AFTER or (tail and not packed)):
                self.pack(cid)
                return self.columns(series, characteristic, station, pack=False)
            cols = [np.frombuffer(b, dtype=np.int64 if k == 1 else np.float64) for k, b in enumerate(packed[0][1:])] \
                if packed else [np.zeros(0, np.int64 if k == 1 else np.float64) for k in range(6)]
            if tail:
                more = list(zip(*tail))
                cols = [np.concatenate([c, np.asarray(m, dtype=c.dtype)]) for c, m in zip(cols, more)]
                order = np.lexsort((cols[1], cols[0]))  # by time, then part
                cols = [c[order] for c in cols]
            t, seqs, v, n, lo, up = cols
            if not len(seqs):
                return EMPTY_COLUMNS
            self._read_parts(int(seqs.max()))
            if station:
                keep = self.who.station_mask(seqs, station)
                t, seqs, v, n, lo, up = (c[keep] for c in (t, seqs, v, n, lo, up))
            stations, runs, serials = self.who.who(seqs)
        return Columns(t, v, n, lo, up, stations, runs, serials)

    def _read_parts(self, seq: int) -> None:
        """The parts cache up to ``seq`` (the parts journalled since it was last read)."""
        if seq > self._parts_seq:
            rows = self._q("SELECT seq, station, run_id, serial FROM parts WHERE seq > ?", (self._parts_seq,))
            self.who.add(rows)
            self._parts_seq = max([self._parts_seq] + [r[0] for r in rows])

    def rows(self, series: str, characteristic: str, station: str | None) -> list[tuple]:
        """(time, value, nominal, lower, upper, station, run_id, serial) of every part, in time order (None: no
        nominal or limit)."""
        c = self.columns(series, characteristic, station)
        num = [[None if math.isnan(x) else x for x in np.asarray(col, float).tolist()] for col in c[:5]]
        return list(zip(*num, c.station, c.run_id, c.serial))

    def pending(self, after_seq: int, limit: int) -> list[PartSeq]:
        """Parts journalled after ``after_seq`` (in order), with their values, for the upload."""
        parts = self._q("SELECT seq, station, run_id, series, serial, time FROM parts WHERE seq > ? "
                        "ORDER BY seq LIMIT ?", (after_seq, limit))
        if not parts:
            return []
        by_seq: dict[int, list[Measured]] = {p[0]: [] for p in parts}
        for seq, name, value, nominal, lower, upper, unit in self._q(
                "SELECT v.seq, c.characteristic, v.value, v.nominal, v.lower, v.upper, c.unit FROM vals v "
                "JOIN chars c ON c.id = v.char_id WHERE v.seq BETWEEN ? AND ? ORDER BY v.seq, v.pos",
                (parts[0][0], parts[-1][0])):
            if seq in by_seq:
                by_seq[seq].append(Measured(name, value, nominal, lower, upper, unit))
        return [PartSeq(seq, PartResult(series, station, run_id, t, serial, tuple(by_seq[seq])))
                for seq, station, run_id, series, serial, t in parts]

    def close(self) -> None:
        self.db.close()


@dataclass(frozen=True)
class PartSeq:
    seq: int  # the part's line in the local journal
    part: PartResult


class Columns(NamedTuple):
    """A chart's parts as columns (time order): the numbers, then who measured each part."""

    time: Sequence[float]
    value: Sequence[float]
    nominal: Sequence[float | None]
    lower: Sequence[float | None]
    upper: Sequence[float | None]
    station: Sequence[str]
    run_id: Sequence[str]
    serial: Sequence[str]

    def rows(self) -> list[tuple]:
        return list(zip(*self))


EMPTY_COLUMNS = Columns((), (), (), (), (), (), (), ())


def history_from_columns(series: str, characteristic: str, cols: Columns, source: str, unit: str = "mm") -> History:
    """A :class:`History` from :class:`Columns` (None -> NaN)."""
    num = [np.array(c, dtype=np.float64) for c in cols[:5]]
    return History(series, characteristic, unit, *num, list(cols.station), list(cols.run_id), list(cols.serial),
                   source)


def history_from_rows(series: str, characteristic: str, rows: list[tuple], source: str, unit: str = "mm") -> History:
    """A :class:`History` from (time, value, nominal, lower, upper, station, run_id, serial) rows."""
    return history_from_columns(series, characteristic, Columns(*zip(*rows)) if rows else EMPTY_COLUMNS, source, unit)


# --------------------------------------------------------------------------- the station's trends


@dataclass
class SyncState:
    connected: bool = False
    error: str = ""  # the last database error, in words
    since: float = 0.0  # when the database was last lost
    uploaded: int = 0  # parts uploaded by this process
    last_try: float = 0.0


class Trends:
    """One station's trends: the local journal and index, and optionally the shared database.

    ``database``: a ``postgresql://`` URL (several stations point at the same one), or None for local only.
    """

    RETRY_S = 5.0  # after a failed connection, queries use the local index for this long before trying again
    BATCH = 500  # parts per upload transaction
    VACUUM_AFTER = 1000  # parts uploaded in one catch-up after which the database's statistics are refreshed

    def __init__(self, directory: str | Path = "trends", *, station: str | None = None,
                 database: str | None = None, connect_timeout: float = 3.0) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.station = station or default_station()
        if not self.station.strip() or len(self.station) > 128:
            raise TrendError(f"{self.station!r} is not a usable station name (1 to 128 characters)")
        self.journal_path = self.directory / "parts.jsonl"
        self.index = LocalIndex(self.journal_path, self.directory / "index.sqlite")
        self.database_url = database
        self.connect_timeout = connect_timeout
        self.state = SyncState()
        self.version = 0  # counts the parts recorded by this object (a page redraws when it changes)
        self._journal: Journal | None = None
        self._db: Any = None
        self._lock = threading.RLock()  # the journal
        self._db_lock = threading.RLock()  # the database connection and its state
        self._sync_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.index.catch_up()

    # --- recording -------------------------------------------------------------------------------

    def record_part(self, series: str, values: Iterable[Measured | dict | list | tuple], *, run_id: str | None = None,
                    serial: str = "", when: float | None = None, sync: bool = True) -> PartResult:
        """Journal one part (fsync'ed before this returns), index it, and upload what is waiting when a
        database is configured (a database that is down only delays the upload)."""
        if not isinstance(series, str) or not series.strip():
            raise TrendError("a part needs the name of its series (the routine or program)")
        part = PartResult(series.strip(), self.station, run_id or uuid.uuid4().hex, time.time() if when is None else
                          float(when), str(serial or ""), check_values(values))
        self.index.catch_up()
        if self.index._q("SELECT 1 FROM parts WHERE station = ? AND run_id = ?", (part.station, part.run_id)):
            raise TrendError(f"run {part.run_id!r} of station {part.station!r} is already recorded")
        with self._lock:
            if self._journal is None:
                try:
                    self._journal = Journal(self.journal_path)
                except JournalBusy:
                    raise TrendError(f"the trends journal {self.journal_path} is open for writing by another "
                                     "station: give each station its own trends folder") from None
            self._journal.append("part", series=part.series, station=part.station, run_id=part.run_id,
                                 serial=part.serial, part_time=part.time, values=[v.row() for v in part.values])
            self.version += 1
        self.index.catch_up()
        if sync and self.database_url:
            self.sync()
        return part

    # --- the shared database ---------------------------------------------------------------------

    def _database(self, connect: bool = True) -> Any:
        """The open database connection, or None while it is unreachable (a new connection is tried at most
        every RETRY_S, and only when ``connect``)."""
        from .trends_pg import TrendDatabase, TrendDatabaseError

        if not self.database_url:
            return None
        with self._db_lock:
            if self._db is not None and not self._db.closed:
                return self._db
            now = time.monotonic()
            if not connect or (not self.state.connected and self.state.last_try
                               and now - self.state.last_try < self.RETRY_S):
                return None
            self.state.last_try = now
            try:
                self._db = TrendDatabase(self.database_url, self.connect_timeout)
            except TrendDatabaseError as exc:
                self._lost(exc)
                return None
            self.state.connected, self.state.error = True, ""
            return self._db

    def _lost(self, exc: BaseException) -> None:
        with self._db_lock:
            if self.state.connected or not self.state.since:
                self.state.since = time.time()
            self.state.connected, self.state.error = False, str(exc)
            self.state.last_try = time.monotonic()
            if self._db is not None:
                self._db.close()
            self._db = None

    def pending(self) -> int:
        """Parts journalled here and not yet uploaded."""
        self.index.catch_up()
        up = self.index.meta("uploaded_seq")
        return int(self.index._q("SELECT count(*) FROM parts WHERE seq > ?", (up,))[0][0])

    def sync(self, *, force: bool = False) -> int:
        """Upload every part not yet in the database; returns how many were sent (0 when it is down)."""
        from .trends_pg import TrendDatabaseError

        if not self.database_url:
            return 0
        if force:
            self.state.last_try = 0.0
        with self._sync_lock:
            self.index.catch_up()
            sent = 0
            # (re)connect even with nothing to send: the charts come from the database again. Once it was lost,
            # only the sync thread (or a forced sync) waits for a connection attempt, never a run recording a part
            thread = self._thread
            connect = force or not self.state.since or thread is None or threading.current_thread() is thread
            if self._database(connect) is None:
                return 0
            while True:
                batch = self.index.pending(self.index.meta("uploaded_seq"), self.BATCH)
                if not batch:
                    if sent >= self.VACUUM_AFTER and self._db is not None:  # a big catch-up: see vacuum()
                        try:
                            self._db.vacuum()
                        except TrendDatabaseError as exc:
                            self._lost(exc)
                    return sent
                for _attempt in range(2):  # as in _ask: a stale connection is replaced once
                    fresh = self._db is None
                    db = self._database(connect)
                    if db is None:
                        return sent
                    try:
                        db.upload([b.part for b in batch])
                        break
                    except TrendDatabaseError as exc:
                        self._lost(exc)
                        if fresh:
                            return sent
                        self.state.last_try = 0.0
                self.index.set_meta("uploaded_seq", batch[-1].seq)
                sent += len(batch)
                self.state.uploaded += len(batch)


    def start(self, every: float = 10.0) -> "Trends":
        """Catch up in the background while a database is configured: every ``every`` seconds reconnect when it
        was lost and upload what waits. With this thread running, chart queries never wait for a connection
        attempt (they use the local index until the thread has the database back)."""
        if self.database_url and self._thread is None:
            def loop() -> None:
                while not self._stop.wait(every):
                    try:
                        self.sync()
                    except Exception:  # noqa: BLE001 - the next round tries again; the journal holds the parts
                        pass

            self._thread = threading.Thread(target=loop, name="trends-sync", daemon=True)
            self._thread.start()
        return self

    # --- queries ---------------------------------------------------------------------------------

    def _ask(self, fn_db: Any, fn_local: Any) -> tuple[Any, str]:
        from .trends_pg import TrendDatabaseError

        # a station's page never waits for a connection attempt once the database was lost: the sync thread
        # reconnects (without the thread, e.g. the CLI, the query tries, at most every RETRY_S)
        connect = not self.state.since or self._thread is None
        for _attempt in range(2):  # a connection that died since its last use is replaced once at once
            fresh = self._db is None
            db = self._database(connect)
            if db is None:
                break
            try:
                return fn_db(db), "database"
            except TrendDatabaseError as exc:
                self._lost(exc)
                if fresh:
                    break
                self.state.last_try = 0.0
        self.index.catch_up()
        return fn_local(self.index), "local"

    @property
    def source(self) -> str:
        return "database" if self.database_url and self.state.connected else "local"

    def series(self) -> list[str]:
        return self._ask(lambda d: d.series(), lambda i: i.series())[0]

    def characteristics(self, series: str) -> list[tuple[str, str]]:
        return self._ask(lambda d: d.characteristics(series), lambda i: i.characteristics(series))[0]

    def stations(self, series: str) -> list[str]:
        return self._ask(lambda d: d.stations(series), lambda i: i.stations(series))[0]

    def history(self, series: str, characteristic: str, station: str | None = None) -> History:
        (cols, unit), source = self._ask(
            lambda d: (Columns(*d.columns(series, characteristic, station)), d.unit(series, characteristic)),
            lambda i: (i.columns(series, characteristic, station), i.unit(series, characteristic)))
        return history_from_columns(series, characteristic, cols, source, unit)

    def status_text(self) -> str:
        """One line for the page and the CLI: where the charts come from and what waits."""
        if not self.database_url:
            return f"station **{self.station}**, local trends only ({self.directory})"
        waiting = self.pending()
        if self.state.connected:
            tail = f"; {waiting} part{'s' if waiting != 1 else ''} waiting to upload" if waiting else ""
            return f"station **{self.station}**, shared database: connected (every station's parts){tail}"
        lost = time.strftime("%H:%M:%S", time.localtime(self.state.since)) if self.state.since else "start-up"
        return (f"station **{self.station}**: the shared database is unreachable since {lost} "
                f"({self.state.error or 'not tried yet'}); showing this station's parts; {waiting} "
                f"part{'s' if waiting != 1 else ''} journalled here will upload when it is back")

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        with self._lock:
            if self._journal is not None:
                self._journal.close()
        with self._db_lock:
            if self._db is not None:
                self._db.close()
        self.index.close()

    def __enter__(self) -> "Trends":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
