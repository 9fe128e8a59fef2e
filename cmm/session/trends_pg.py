"""The shared trends database: PostgreSQL tables several stations upload their parts to (psycopg 3).

Tables (created when missing, under an advisory lock so stations starting together do not race):

- ``cmm_trend_parts`` (id, station, run_id, series, serial, time), UNIQUE (station, run_id): the upload is
  idempotent, a part sent twice is stored once;
- ``cmm_trend_chars`` (id, series, characteristic, unit): the characteristics, numbered in the order first
  uploaded (the list the page offers: a DISTINCT over every value would read them all);
- ``cmm_trend_vals`` (char_id, part_id, time, value, nominal, lower, upper), keyed by (characteristic, time,
  part) with the charted columns included, so a chart is one range of that index.

Every failure (server down, connection lost) is a :class:`TrendDatabaseError` with the reason; the caller
keeps the parts in its local journal and tries again.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .trends_parts import PartsCache

SCHEMA = """
CREATE TABLE IF NOT EXISTS cmm_trend_parts (
    id      bigserial PRIMARY KEY,
    station text NOT NULL,
    run_id  text NOT NULL,
    series  text NOT NULL,
    serial  text NOT NULL,
    time    double precision NOT NULL,
    UNIQUE (station, run_id)
);
CREATE INDEX IF NOT EXISTS cmm_trend_parts_series ON cmm_trend_parts (series, station);
CREATE TABLE IF NOT EXISTS cmm_trend_chars (
    id             bigserial PRIMARY KEY,
    series         text NOT NULL,
    characteristic text NOT NULL,
    unit           text NOT NULL,
    UNIQUE (series, characteristic)
);
CREATE TABLE IF NOT EXISTS cmm_trend_vals (
    char_id bigint NOT NULL REFERENCES cmm_trend_chars(id) ON DELETE CASCADE,
    part_id bigint NOT NULL REFERENCES cmm_trend_parts(id) ON DELETE CASCADE,
    time    double precision NOT NULL,
    pos     integer NOT NULL,
    value   double precision NOT NULL,
    nominal double precision,
    lower   double precision,
    upper   double precision,
    PRIMARY KEY (char_id, time, part_id) INCLUDE (value, nominal, lower, upper)
);
CREATE INDEX IF NOT EXISTS cmm_trend_vals_part ON cmm_trend_vals (part_id);
"""
SCHEMA_LOCK = (0x434D4D, 0x54524E44)  # "CMM", "TRND"


class TrendDatabaseError(RuntimeError):
    """The shared trends database cannot be reached or refused a statement, in words."""


def _psycopg() -> Any:
    try:
        import psycopg
    except ImportError:
        raise TrendDatabaseError("the shared trends database needs psycopg: pip install 'cmm[postgres]'") from None
    return psycopg


class TrendDatabase:
    """One connection to the shared database."""

    def __init__(self, url: str, connect_timeout: float = 3.0) -> None:
        psycopg = _psycopg()
        self._error = psycopg.Error
        self._ids: dict[tuple[str, str], int] = {}  # (series, characteristic) -> id, as uploaded
        self.who = PartsCache()  # part id -> station, run id, serial, as read
        self._units: dict[tuple[str, str], str] = {}
        try:
            # TCP keepalives and a user timeout: a server that vanished without closing is noticed in seconds
            self.conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, round(connect_timeout)),
                                        keepalives=1, keepalives_idle=5, keepalives_interval=2, keepalives_count=2,
                                        tcp_user_timeout=int(connect_timeout * 2000))
            with self.conn.transaction():
                self.conn.execute("SELECT pg_advisory_xact_lock(%s, %s)", SCHEMA_LOCK)
                self.conn.execute(SCHEMA)
        except psycopg.Error as exc:
            self.close()
            raise TrendDatabaseError(self._words(exc)) from None

    @staticmethod
    def _words(exc: BaseException) -> str:
        text = " ".join(str(exc).split())
        return f"cannot use the shared trends database: {text or type(exc).__name__}"

    @property
    def closed(self) -> bool:
        return getattr(self, "conn", None) is None or self.conn.closed

    def close(self) -> None:
        conn = getattr(self, "conn", None)
        if conn is not None and not conn.closed:
            try:
                conn.close()
            except Exception:  # noqa: BLE001 - a connection to a dead server closes anyway
                pass

    def _run(self, fn: Any) -> Any:
        try:
            return fn(self.conn)
        except self._error as exc:
            self.close()
            raise TrendDatabaseError(self._words(exc)) from None

    # --- upload --------------------------------------------------------------------------------

    def upload(self, parts: list[Any]) -> int:
        """Store ``parts`` (:class:`~cmm.session.trends.PartResult`) in one transaction; a part whose (station,
        run id) is already there is skipped. Returns how many were new."""

        def go(conn: Any) -> int:
            new = 0
            with conn.transaction():
                with conn.cursor() as cur:
                    rows = []
                    for p in parts:
                        cur.execute("INSERT INTO cmm_trend_parts (station, run_id, series, serial, time) "
                                    "VALUES (%s, %s, %s, %s, %s) ON CONFLICT (station, run_id) DO NOTHING RETURNING id",
                                    (p.station, p.run_id, p.series, p.serial, p.time))
                        got = cur.fetchone()
                        if got is None:
                            continue  # uploaded before
                        new += 1
                        for k, v in enumerate(p.values):
                            rows.append(((p.series, v.name, v.unit), got[0], p.time, k, v.value, v.nominal, v.lower,
                                         v.upper))
                    ids = self._char_ids(cur, list(dict.fromkeys(r[0] for r in rows)))
                    if rows:
                        with cur.copy("COPY cmm_trend_vals (char_id, part_id, time, pos, value, nominal, lower, upper) "
                                      "FROM STDIN") as copy:
                            for r in rows:
                                copy.write_row((ids[r[0][:2]], *r[1:]))
            return new

        return self._run(go)

    def _char_ids(self, cur: Any, keys: list[tuple[str, str, str]]) -> dict[tuple[str, str], int]:
        """Ids of (series, characteristic, unit), new ones numbered in the order given."""
        missing = [k for k in keys if k[:2] not in self._ids]
        if missing:
            cur.executemany("INSERT INTO cmm_trend_chars (series, characteristic, unit) VALUES (%s, %s, %s) "
                            "ON CONFLICT DO NOTHING", missing)
            cur.execute("SELECT id, series, characteristic FROM cmm_trend_chars")
            self._ids = {(a, b): i for i, a, b in cur.fetchall()}
        return self._ids

    # --- queries -------------------------------------------------------------------------------

    def series(self) -> list[str]:
        return self._run(lambda c: [r[0] for r in c.execute(
            "SELECT DISTINCT series FROM cmm_trend_chars ORDER BY series")])

    def characteristics(self, series: str) -> list[tuple[str, str]]:
        return self._run(lambda c: [(r[0], r[1]) for r in c.execute(
            "SELECT characteristic, unit FROM cmm_trend_chars WHERE series = %s ORDER BY id", (series,))])

    def unit(self, series: str, characteristic: str) -> str:
        """A characteristic's unit (kept once read: a characteristic is stored once, with its unit, and never
        changed, so a chart costs one round trip to the database, not two)."""
        key = (series, characteristic)
        if key not in self._units:
            row = self._run(lambda c: c.execute("SELECT unit FROM cmm_trend_chars WHERE series = %s AND "
                                                "characteristic = %s", key).fetchone())
            if row is None:
                return "mm"
            self._units[key] = str(row[0])
        return self._units[key]

    def stations(self, series: str) -> list[str]:
        return self._run(lambda c: [r[0] for r in c.execute(
            "SELECT DISTINCT station FROM cmm_trend_parts WHERE series = %s ORDER BY station", (series,))])

    def columns(self, series: str, characteristic: str, station: str | None) -> tuple:
        """Every part's time, value, nominal, lower, upper (NaN: none), station, run_id, serial, in time order, as
        8 columns.

        The values come as binary numbers in the order of the (characteristic, time, part) key (one index range,
        no sort) and are split into numpy columns at once; who measured each part comes from a cache of the
        parts table (filled for the parts not yet in it), which also picks one station's parts. (Sending each
        column as one array, array_agg ... ORDER BY, made the database sort six times: slower.)"""
        sql = ("SELECT v.time, v.part_id, v.value, v.nominal, v.lower, v.upper FROM cmm_trend_vals v "
               "WHERE v.char_id = (SELECT id FROM cmm_trend_chars WHERE series = %s AND characteristic = %s) "
               "ORDER BY v.char_id, v.time, v.part_id")

        def go(conn: Any) -> tuple:
            with conn.cursor(binary=True) as cur:
                rows = cur.execute(sql, (series, characteristic)).fetchall()
                if not rows:
                    return ((),) * 8
                t, pids, v, n, lo, up = (np.array(c, dtype=np.int64 if k == 1 else np.float64)  # None -> NaN
                                         for k, c in enumerate(zip(*rows)))
                missing = self.who.missing(pids)
                if missing:
                    self.who.add(cur.execute("SELECT id, station, run_id, serial FROM cmm_trend_parts "
                                             "WHERE id = ANY(%s)", (missing,)).fetchall())
            if station:
                keep = self.who.station_mask(pids, station)
                t, pids, v, n, lo, up = (c[keep] for c in (t, pids, v, n, lo, up))
            return (t, v, n, lo, up, *self.who.who(pids))

        return self._run(go)

    def rows(self, series: str, characteristic: str, station: str | None) -> list[tuple]:
        """(time, value, nominal, lower, upper, station, run_id, serial) of every part, in time order."""
        return list(zip(*self.columns(series, characteristic, station)))

    def vacuum(self) -> None:
        """Refresh the visibility map and statistics after a big upload: chart queries are index-only again."""
        self._run(lambda c: c.execute("VACUUM ANALYZE cmm_trend_vals"))

    def count_parts(self, series: str | None = None) -> int:
        if series is None:
            return self._run(lambda c: int(c.execute("SELECT count(*) FROM cmm_trend_parts").fetchone()[0]))
        return self._run(lambda c: int(c.execute("SELECT count(*) FROM cmm_trend_parts WHERE series = %s",
                                                 (series,)).fetchone()[0]))
