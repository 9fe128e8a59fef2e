"""The shared trends database: PostgreSQL tables several stations upload their parts to (psycopg 3).

Tables (created when missing, under an advisory lock so stations starting together do not race):

- ``cmm_trend_parts`` (id, station, run_id, series, serial, time), UNIQUE (station, run_id): the upload is
  idempotent, a part sent twice is stored once;
- ``cmm_trend_values`` (part_id, series, characteristic, time, value, nominal, lower, upper, unit), indexed
  by (series, characteristic, time) with the charted columns included, so a chart is an index-only range scan;
- ``cmm_trend_characteristics`` (series, characteristic, unit): the list the page offers, kept on upload
  (a DISTINCT over every value would read them all).

Every failure (server down, connection lost) is a :class:`TrendDatabaseError` with the reason; the caller
keeps the parts in its local journal and tries again.
"""

from __future__ import annotations

from typing import Any

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
CREATE TABLE IF NOT EXISTS cmm_trend_values (
    part_id        bigint NOT NULL REFERENCES cmm_trend_parts(id) ON DELETE CASCADE,
    series         text NOT NULL,
    characteristic text NOT NULL,
    time           double precision NOT NULL,
    value          double precision NOT NULL,
    nominal        double precision,
    lower          double precision,
    upper          double precision,
    unit           text NOT NULL,
    PRIMARY KEY (part_id, characteristic)
);
CREATE INDEX IF NOT EXISTS cmm_trend_values_chart ON cmm_trend_values (series, characteristic, time, part_id)
    INCLUDE (value, nominal, lower, upper);
CREATE TABLE IF NOT EXISTS cmm_trend_characteristics (
    series         text NOT NULL,
    characteristic text NOT NULL,
    unit           text NOT NULL,
    first          double precision NOT NULL,
    PRIMARY KEY (series, characteristic)
);
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
        try:
            self.conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, round(connect_timeout)))
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
                chars: dict[tuple[str, str], tuple[str, float]] = {}
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
                        for v in p.values:
                            rows.append((got[0], p.series, v.name, p.time, v.value, v.nominal, v.lower, v.upper, v.unit))
                            chars.setdefault((p.series, v.name), (v.unit, p.time))
                    if rows:
                        with cur.copy("COPY cmm_trend_values (part_id, series, characteristic, time, value, nominal, "
                                      "lower, upper, unit) FROM STDIN") as copy:
                            for r in rows:
                                copy.write_row(r)
                    if chars:
                        cur.executemany("INSERT INTO cmm_trend_characteristics (series, characteristic, unit, first) "
                                        "VALUES (%s, %s, %s, %s) ON CONFLICT DO NOTHING",
                                        [(s, c, u, t) for (s, c), (u, t) in chars.items()])
            return new

        return self._run(go)

    # --- queries -------------------------------------------------------------------------------

    def series(self) -> list[str]:
        return self._run(lambda c: [r[0] for r in c.execute(
            "SELECT DISTINCT series FROM cmm_trend_characteristics ORDER BY series")])

    def characteristics(self, series: str) -> list[tuple[str, str]]:
        return self._run(lambda c: [(r[0], r[1]) for r in c.execute(
            "SELECT characteristic, unit FROM cmm_trend_characteristics WHERE series = %s ORDER BY first, "
            "characteristic", (series,))])

    def stations(self, series: str) -> list[str]:
        return self._run(lambda c: [r[0] for r in c.execute(
            "SELECT DISTINCT station FROM cmm_trend_parts WHERE series = %s ORDER BY station", (series,))])

    def rows(self, series: str, characteristic: str, station: str | None) -> list[tuple]:
        sql = ("SELECT v.time, v.value, v.nominal, v.lower, v.upper, p.station, p.run_id, p.serial, v.unit "
               "FROM cmm_trend_values v JOIN cmm_trend_parts p ON p.id = v.part_id "
               "WHERE v.series = %s AND v.characteristic = %s")
        args: list[Any] = [series, characteristic]
        if station:
            sql += " AND p.station = %s"
            args.append(station)
        return self._run(lambda c: c.execute(sql + " ORDER BY v.time, v.part_id", args).fetchall())

    def count_parts(self, series: str | None = None) -> int:
        if series is None:
            return self._run(lambda c: int(c.execute("SELECT count(*) FROM cmm_trend_parts").fetchone()[0]))
        return self._run(lambda c: int(c.execute("SELECT count(*) FROM cmm_trend_parts WHERE series = %s",
                                                 (series,)).fetchone()[0]))
