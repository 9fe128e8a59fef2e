"""The PostgreSQL session store against a real server the fixture starts on loopback.

Needs Debian's postgresql (initdb, pg_ctl under /usr/lib/postgresql/*/bin) and
psycopg; without them the tests are skipped with the reason shown (-ra).
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest
from netutil import free_port

import session_support as sup
from cmm.session.journal import read_events
from cmm.session.model import Session
from cmm.session.replay import Replay
from cmm.session.store import PostgresStore, SessionBusy, SessionNotFound, StoreError, load_session, open_store, write_session



@pytest.fixture(scope="module")
def pg_url():
    try:
        import psycopg  # noqa: F401
    except ImportError:
        pytest.skip("psycopg is not installed (pip install 'cmm[postgres]'): PostgreSQL store not tested")
    bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not bins:
        pytest.skip("PostgreSQL server binaries not found (apt-get install postgresql): PostgreSQL store not tested")
    bindir = Path(bins[-1]).parent
    root = Path(tempfile.mkdtemp(prefix="cmm-pg-"))
    prefix: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root: run the server as the postgres user
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL as another user")
        try:
            import pwd

            pw = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run the server")
        os.chown(root, pw.pw_uid, pw.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    data, port = root / "data", free_port()
    run = lambda *cmd: subprocess.run(prefix + list(cmd), capture_output=True, text=True, timeout=120)  # noqa: E731
    r = run(str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "cmm", "--no-sync")
    if r.returncode != 0:
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"initdb failed: {r.stderr.strip()[-300:]}")
    r = run(str(bindir / "pg_ctl"), "-D", str(data), "-l", str(root / "log"), "-w", "-t", "60", "start",
            "-o", f"-k {root} -p {port} -c listen_addresses=127.0.0.1 -c fsync=on")
    if r.returncode != 0:
        log = (root / "log").read_text() if (root / "log").exists() else ""
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"the PostgreSQL server did not start: {(r.stderr + log).strip()[-300:]}")
    try:
        yield f"postgresql://cmm@127.0.0.1:{port}/postgres"
    finally:
        run(str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop")
        shutil.rmtree(root, ignore_errors=True)


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
        open_store(f"postgresql://nobody@127.0.0.1:{free_port()}/x?connect_timeout=2")
