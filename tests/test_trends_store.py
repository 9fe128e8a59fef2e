"""Trends across parts and stations: the local journal and index, and a real shared PostgreSQL with two
stations and a database outage mid-series."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pg_support import PgServer

from cmm.metrology.characteristics import Characteristic
from cmm.metrology.measured import measured
from cmm.session.trends import Measured, TrendError, Trends

BORE = "bore / diameter"
FLAT = "top / flatness"


def part_values(i: int) -> list[Measured]:
    """Part i: the bore drifts 1 um per part from 30.000 (limits 29.98 .. 30.02), flatness alternates."""
    return [Measured(BORE, 30.0 + 0.001 * i, 30.0, 29.98, 30.02),
            Measured(FLAT, 0.004 + 0.001 * (i % 2), 0.0, None, 0.01)]


def test_parts_are_journalled_indexed_and_charted_locally(tmp_path):
    with Trends(tmp_path / "t", station="cmm-1") as t:
        runs = [t.record_part("bracket", part_values(i), serial=f"S{i}", when=1000.0 + i).run_id for i in range(25)]
        assert t.series() == ["bracket"] and t.characteristics("bracket") == [(BORE, "mm"), (FLAT, "mm")]
        h = t.history("bracket", BORE)
        assert h.source == "local" and len(h) == 25 and h.run_id == runs and h.serial[3] == "S3"
        assert np.allclose(h.value, 30.0 + 0.001 * np.arange(25)) and set(h.station) == {"cmm-1"}
        assert np.all(np.isnan(t.history("bracket", FLAT).lower))  # form: an upper limit only
        with pytest.raises(TrendError, match="already recorded"):
            t.record_part("bracket", part_values(0), run_id=runs[0])
    lines = (tmp_path / "t" / "parts.jsonl").read_text().splitlines()
    assert len(lines) == 25 and json.loads(lines[0])["values"][0] == [BORE, 30.0, 30.0, 29.98, 30.02, "mm"]
    # the index is a cache of the journal: deleted, it is rebuilt; a torn last line is left out
    (tmp_path / "t" / "index.sqlite").unlink()
    with open(tmp_path / "t" / "parts.jsonl", "a") as fh:
        fh.write('{"seq": 26, "kind": "part", "series": "bra')
    with Trends(tmp_path / "t", station="cmm-1") as again:
        assert len(again.history("bracket", BORE)) == 25
        again.record_part("bracket", part_values(25))  # the writer cuts the torn line and goes on
        assert len(again.history("bracket", BORE)) == 26


def test_bad_parts_are_refused_with_a_sentence_and_nothing_is_written(tmp_path):
    with Trends(tmp_path, station="cmm-1") as t:
        with pytest.raises(TrendError, match="not a number"):
            t.record_part("bracket", [Measured(BORE, float("nan"), 30.0, 29.98, 30.02)])
        with pytest.raises(TrendError, match="lower limit 30.02 above its upper limit 29.98"):
            t.record_part("bracket", [Measured(BORE, 30.0, 30.0, 30.02, 29.98)])
        with pytest.raises(TrendError, match="given twice"):
            t.record_part("bracket", part_values(0) + part_values(1))
        with pytest.raises(TrendError, match="name of its series"):
            t.record_part(" ", part_values(0))
        with pytest.raises(TrendError, match="at least one"):
            t.record_part("bracket", [])
        assert t.series() == []
        t.record_part("bracket", part_values(0))
        with pytest.raises(TrendError, match="open for writing by another station"):
            Trends(tmp_path, station="cmm-2").record_part("bracket", part_values(1))


def test_report_characteristics_become_trend_values():
    dia = measured(Characteristic("bore", "diameter", 30.0, 30.004, 0.02, -0.02))
    assert (dia.name, dia.lower, dia.upper, dia.ok) == (BORE, pytest.approx(29.98), pytest.approx(30.02), True)
    pos = measured(Characteristic("bore", "position ⌀", 0.0, 0.05, 0.04, 0.0))
    assert pos.lower is None and pos.upper == pytest.approx(0.04) and pos.ok is False
    assert measured(Characteristic("bore", "position ⌀", None, None, 0.04, 0.0)) is None  # not measured
    free = measured(Characteristic("bore", "diameter", None, 30.004, 0.02, -0.02))
    assert free.ok is None and free.upper is None


@pytest.fixture(scope="module")
def pg():
    server = PgServer()
    if server.skip_reason:
        server.close()
        pytest.skip(server.skip_reason)
    yield server
    server.close()


def _db_runs(url: str) -> list[tuple[str, str]]:
    import psycopg

    with psycopg.connect(url) as c:
        return c.execute("SELECT station, run_id FROM cmm_trend_parts ORDER BY station, run_id").fetchall()


def _db_values(url: str) -> int:
    import psycopg

    with psycopg.connect(url) as c:
        return c.execute("SELECT count(*) FROM cmm_trend_vals").fetchone()[0]


def _eventually(check, timeout=20.0):
    import time

    end = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < end, "the station did not catch up"
        time.sleep(0.1)


def test_two_stations_share_one_database_and_an_outage_loses_nothing(pg, tmp_path, capsys):
    a = Trends(tmp_path / "a", station="cmm-a", database=pg.url, connect_timeout=2)
    b = Trends(tmp_path / "b", station="cmm-b", database=pg.url, connect_timeout=2)
    b.RETRY_S = 0.2
    b.start(every=0.2)  # B catches up by itself, as `cmm serve` runs it; A when told (or with its next part)
    try:
        runs = {"cmm-a": [], "cmm-b": []}
        for i in range(6):  # the stations take turns
            t = a if i % 2 == 0 else b
            runs[t.station].append(t.record_part("bracket", part_values(i), when=2000.0 + i).run_id)
        for t in (a, b):  # each sees every station's parts, in time order, with who measured what
            h = t.history("bracket", BORE)
            assert h.source == "database" and h.station == ["cmm-a", "cmm-b"] * 3
            assert np.allclose(h.value, 30.0 + 0.001 * np.arange(6))
            assert t.stations("bracket") == ["cmm-a", "cmm-b"]
        assert a.history("bracket", BORE, station="cmm-b").run_id == runs["cmm-b"]

        pg.stop()  # the database goes away mid-series: both stations keep measuring
        for i in range(6, 12):
            t = a if i < 10 else b
            runs[t.station].append(t.record_part("bracket", part_values(i), when=2000.0 + i).run_id)
        assert a.pending() == 4 and b.pending() == 2
        h = a.history("bracket", BORE)
        assert h.source == "local" and h.station == ["cmm-a"] * 7  # its own parts, from the journal
        assert "unreachable" in a.status_text() and "4 parts journalled here" in a.status_text()
        assert b.history("bracket", BORE).source == "local"

        assert pg.start() == ""
        assert a.sync(force=True) == 4 and a.pending() == 0
        assert "connected" in a.status_text()
        _eventually(lambda: b.pending() == 0)
        # a crash between the database's commit and the local mark sends everything again: stored once
        a.index.set_meta("uploaded_seq", 0)
        assert a.sync() == 7
        expected = sorted((s, r) for s, rs in runs.items() for r in rs)
        assert _db_runs(pg.url) == expected and _db_values(pg.url) == 2 * 12
        _eventually(lambda: b.source == "database")
        for t in (a, b):
            h = t.history("bracket", BORE)
            assert h.source == "database" and len(h) == 12
            assert h.station == ["cmm-a", "cmm-b"] * 3 + ["cmm-a"] * 4 + ["cmm-b"] * 2
            assert np.allclose(h.value, 30.0 + 0.001 * np.arange(12))
        # the CLI over the shared database: every station's parts
        from cmm.cli import main

        assert main(["trends", "--trends", str(tmp_path / "reader"), "--db", pg.url, "show", "bracket", BORE]) == 0
        assert "parts: 12 from 2 stations (cmm-a, cmm-b)" in capsys.readouterr().out
    finally:
        a.close()
        b.close()
