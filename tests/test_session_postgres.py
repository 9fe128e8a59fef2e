"""The PostgreSQL session store against a real server the fixture starts on loopback, and through outages of a
server a test stops and starts again (every event journalled locally first, uploaded once, in order).

Needs Debian's postgresql (initdb, pg_ctl under /usr/lib/postgresql/*/bin) and
psycopg; without them the tests are skipped with the reason shown (-ra).
"""

from __future__ import annotations

import pytest
from netutil import free_port
from pg_support import PgServer

import session_support as sup
from cmm.journal.writer import read_events
from cmm.journal.session import Session
from cmm.session.replay import Replay
from cmm.journal.store import PostgresStore, SessionBusy, SessionNotFound, StoreError, load_session, open_store, write_session



@pytest.fixture(autouse=True)
def _spool(tmp_path, monkeypatch):
    """The store's local journals (its spool folder) in the test's folder, not the user's home."""
    monkeypatch.setenv("CMM_SESSION_SPOOL", str(tmp_path / "spool"))


@pytest.fixture(scope="module")
def pg_url():
    """A PostgreSQL server of this module's on loopback (pg_support.PgServer: initdb, pg_ctl), its URL."""
    server = PgServer()
    if server.skip_reason:
        server.close()
        pytest.skip(f"{server.skip_reason}: PostgreSQL store not tested")
    yield server.url
    server.close()


def test_postgres_store_round_trips_a_recorded_session(pg_url):
    store = open_store(pg_url)
    assert isinstance(store, PostgresStore)
    original = read_events(sup._recorded()).events
    write_session(store, "taught", original)
    s = load_session(store, "taught")
    assert s.damage is None and len(s.events) == len(original)
    ref = Session.from_events(original, "taught")
    assert {f.name: f.fit for f in s.features.values()} == {f.name: f.fit for f in ref.features.values()}
    assert {h: r.counts for h, r in s.hits.items()} == {h: r.counts for h, r in ref.hits.items()}
    assert len(Replay(s)) == len(original)
    info = {i.name: i for i in store.list()}
    assert info["taught"].events == len(original) and not info["taught"].open_for_writing


def test_postgres_store_refuses_while_recording_and_renames_and_deletes(pg_url):
    store = open_store(pg_url)
    writer = store.create("live")
    try:
        writer.append("start", note="x")
        writer.append("hit", id=1, counts=[1, 2, 3], machine=[0, 0, 0], approach=[0, 0, -1], speed=2.0,
                      hit_time=0.0, point=[0, 0, -1])
        assert load_session(store, "live").hits[1].counts == (1, 2, 3)  # committed before append returned
        with pytest.raises(SessionBusy, match="being recorded"):
            store.delete("live")
        with pytest.raises(SessionBusy):
            store.create("live", append=True)
        assert {i.name: i.open_for_writing for i in store.list()}["live"]
    finally:
        writer.close()
    store.rename("live", "done")
    with pytest.raises(StoreError, match="already exists"):
        store.create("done")
    with pytest.raises(SessionNotFound):
        load_session(store, "live")
    store.delete("done")
    assert not store.exists("done")


def test_cli_works_against_postgres(pg_url, capsys, tmp_path):
    from cmm.cli import main

    store = open_store(pg_url)
    if not store.exists("taught"):
        write_session(store, "taught", read_events(sup._recorded()).events)
    assert main(["sessions", "--store", pg_url, "list"]) == 0
    assert "taught" in capsys.readouterr().out
    assert main(["sessions", "--store", pg_url, "export", "taught", "--csv", str(tmp_path / "h.csv")]) == 0
    assert len((tmp_path / "h.csv").read_text().splitlines()) == 27
    assert main(["report", "taught", "--store", pg_url, "-o", str(tmp_path / "r.html")]) == 0


def test_a_bad_url_is_an_operator_message():
    pytest.importorskip("psycopg", reason="psycopg is not installed")
    with pytest.raises(StoreError, match="cannot connect to the session database"):
        open_store(f"postgresql://nobody@127.0.0.1:{free_port()}/x?connect_timeout=2").list()


# --------------------------------------------------------------------------- outages


@pytest.fixture
def pg_server():
    """A PostgreSQL server of this test's own, which the test stops and starts again (an outage)."""
    server = PgServer()
    if server.skip_reason:
        server.close()
        pytest.skip(server.skip_reason)
    yield server
    server.close()


def _db_events(url: str, name: str) -> list[tuple[int, str]]:
    import psycopg

    with psycopg.connect(url) as conn:
        return conn.execute("SELECT e.seq, e.event FROM cmm_events e JOIN cmm_sessions s ON s.id = e.session_id "
                            "WHERE s.name = %s ORDER BY e.seq", (name,)).fetchall()


def _hit(st, dx: float, dy: float):
    """A probe hit on the part's top face, where a click at part (dx, dy) lands."""
    import numpy as np

    b = st.measurement.part.mesh.bounds
    pose = st.measurement.part.pose
    local = np.array([dx, dy, b[1][2] + 30.0])
    hit, _ = st.measurement.pick(pose[:3, :3] @ local + pose[:3, 3], [0.0, 0.0, -1.0])
    return st.measurement.probe_here(hit.point, hit.normal).wait(40)


def test_a_station_records_through_a_database_restart_and_every_event_arrives_once(pg_server, tmp_path,
                                                                                    monkeypatch, stations):
    """The station records into the PostgreSQL store; the database is killed mid-session: hits go on (none refused,
    no FAULT), the status bar says "database offline, N events waiting", a note and a new part's session are
    journalled too; the database comes back and every event arrives once, in order, byte for byte."""
    import re
    import time

    from cmm.ui.panel_status import status_html

    monkeypatch.setenv("CMM_SESSION_SPOOL", str(tmp_path / "spool"))
    st = stations.station("through outage", session_dir=pg_server.url)
    try:
        journal = st.measurement.journal
        for x in (15.0, 45.0, 85.0):
            _hit(st, x, 5.0)
        store = open_store(pg_server.url)
        assert store.uploader.wait_uploaded("through outage", 30.0), store.uploader.status_text()
        assert "database offline" not in status_html(st.controller.commands, "")

        pg_server.stop("immediate")  # the shop's database dies (no clean shutdown)
        for x in (10.0, 40.0, 85.0, 110.0):
            _hit(st, x, 75.0)  # never refused
        st.measurement.note("measured while the database was down")
        assert st.controller.state.machine is not None and st.measurement.journal is journal
        end = time.monotonic() + 30.0
        while "database offline" not in journal.upload_status() and time.monotonic() < end:
            time.sleep(0.05)  # the uploader has to try and fail first
        text = status_html(st.controller.commands, "")
        m = re.search(r"database offline, (\d+) events waiting", text)
        assert m and int(m.group(1)) >= 5, text  # 4 hits and the note at least
        assert "psycopg" not in text and "Traceback" not in text
        # a new part while the database is down: its session is created locally and claimed later
        st.measurement.new_part("next part")
        _hit(st, 110.0, 10.0)
        st.measurement.new_part("third part")  # closes "next part" while the database is still down
        local = (tmp_path / "spool" / "through outage.jsonl").read_text().splitlines()  # closed, not uploaded

        assert pg_server.start() == ""  # back, same port and data
        assert store.uploader.wait_uploaded(None, 60.0), store.uploader.status_text()
        assert "database offline" not in status_html(st.controller.commands, "")
    finally:
        st.close()
    rows = _db_events(pg_server.url, "through outage")
    assert [seq for seq, _ in rows] == list(range(1, len(rows) + 1))  # in order, none missing, none twice
    assert [line for _, line in rows] == local  # the database's rows are the station's journal, byte for byte
    import json

    events = [json.loads(line) for _, line in rows]
    hits = [e["id"] for e in events if e["kind"] == "hit"]
    assert len(hits) == 7 == len(set(hits))
    assert any(e["kind"] == "note" and "database was down" in e["text"] for e in events)
    nxt = [json.loads(line) for _, line in _db_events(pg_server.url, "next part")]
    assert nxt[0]["kind"] == "start" and sum(e["kind"] == "hit" for e in nxt) == 1
    # the closed sessions' local journals go once the database has them
    assert not (tmp_path / "spool" / "next part.jsonl").exists()
    assert not (tmp_path / "spool" / "through outage.jsonl").exists()
    s = load_session(open_store(pg_server.url), "through outage")
    assert len(s.hits) == 7


def test_a_session_closed_while_the_database_is_down_is_uploaded_when_it_is_back(pg_server, tmp_path):
    """A station stopped during the outage leaves its journal in the spool folder: the next store opened on it
    (another process: here a fresh uploader) uploads it, once; the local journal then goes."""
    from cmm.journal import store_pg

    spool = tmp_path / "spool"
    store = PostgresStore(pg_server.url, spool=spool)
    pg_server.stop("immediate")
    w = store.create("offline")
    for k in range(10):
        w.append("note", text=f"n{k}")
    assert w.pending() == 10 and "database offline, 10 events waiting" in w.upload_status()
    w.close()  # no wait: the database is down
    assert [i.name for i in store.list()] == ["offline"]  # listed from the local journal meanwhile
    assert len(load_session(store, "offline").events) == 10
    store.uploader.close()  # this "process" ends
    store_pg._uploaders.clear()
    assert pg_server.start() == ""
    again = PostgresStore(pg_server.url, spool=spool)
    assert again.uploader.wait_uploaded(None, 60.0), again.uploader.status_text()
    rows = _db_events(pg_server.url, "offline")
    assert [seq for seq, _ in rows] == list(range(1, 11))
    end = __import__("time").monotonic() + 30
    while (spool / "offline.jsonl").exists() and __import__("time").monotonic() < end:
        again.uploader._wake.set()
        __import__("time").sleep(0.05)
    assert not (spool / "offline.jsonl").exists()
