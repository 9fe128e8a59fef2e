"""Heavy session work in the worker process (cmm.session.worker), the fast journal parser, the cached line
counts and the replay's bounded checkpoints: the pieces that keep a 200,000-hit session off the machine loop."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

import session_support as sup
from cmm.session import worker
from cmm.journal.writer import encode_event, read_events
from cmm.journal.session import Session
from cmm.session.replay import MAX_CHECKPOINTS, Replay
from cmm.session.report import render
from cmm.journal.store import DirectoryStore, SessionNotFound, count_lines, load_session


@pytest.fixture(scope="module")
def store_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("worker")
    sup.recorded_copy(root)
    return root


@pytest.fixture(scope="module")
def pool():
    w = worker.SessionWorker(1)
    yield w
    w.close()


def test_tasks_run_in_another_process_and_match_the_in_process_results(store_dir, pool, tmp_path):
    assert pool.call(os.getpid) != os.getpid()
    assert pool.call(os.getpriority, os.PRIO_PROCESS, 0) >= worker.WORKER_NICE  # behind the station for the CPU
    session = load_session(DirectoryStore(store_dir), "taught")
    assert pool.call(worker.summary, str(store_dir), "taught") == session.summary()
    html, table = pool.call(worker.report, str(store_dir), "taught", tmp_path)
    assert html == tmp_path / "taught-report.html" and table == tmp_path / "taught-features.csv"
    assert html.read_text().count("<tr") == render(session).count("<tr") > 1
    csv_file, json_file = pool.call(worker.export, str(store_dir), "taught", tmp_path)
    assert csv_file.read_text().count("\n") == len(session.hits) + 1
    assert json.loads(json_file.read_text())["session"]["hits"] == len(session.hits)
    result = pool.call(worker.reevaluate, str(store_dir), "taught", "taught-r", 1.2, "ls")
    derived = load_session(DirectoryStore(store_dir), "taught-r")
    assert result == {"hits": len(derived.hits), "features": len(derived.features), "errors": [], "left_out": ""}
    assert derived.start["tip_radius"] == pytest.approx(1.2)


def test_a_job_error_comes_back_as_the_operator_reads_it(store_dir, pool):
    with pytest.raises(SessionNotFound, match="there is no session 'nope'"):
        pool.call(worker.summary, str(store_dir), "nope")


def test_a_dead_worker_fails_its_job_and_the_next_job_gets_a_new_one(store_dir, pool):
    first = pool.call(os.getpid)
    with pytest.raises(worker.WorkerError, match="stopped unexpectedly"):
        pool.call(worker.crash)
    assert pool.call(os.getpid) not in (first, os.getpid())
    assert pool.call(worker.summary, str(store_dir), "taught")["hits"] > 0


def test_summaries_are_read_once_per_journal_version_and_shared(store_dir, pool):
    sums = worker.Summaries(pool)
    key = (10, 1.0)
    first = sums.get(store_dir, "taught", key, wait=True)
    assert first["hits"] > 0
    assert sums.get(str(store_dir), "taught", key) is first  # the same object: not read again
    pending = sums.get(store_dir, "taught", (11, 2.0))  # a new version: read again, the caller does not wait
    again = sums.get(store_dir, "taught", (11, 2.0), wait=True)
    assert pending in (None, again) and again == first and again is not first
    with pytest.raises(SessionNotFound):
        sums.get(store_dir, "gone", key, wait=True)
    with pytest.raises(SessionNotFound):  # the error is kept for that version, not re-read on every list
        sums.get(store_dir, "gone", key)


def test_fast_parser_keeps_the_damage_rules(tmp_path):
    good = [{"seq": i, "time": 1.0, "kind": "note", "text": f"n{i}"} for i in (1, 2)]
    p = tmp_path / "j.jsonl"
    p.write_bytes(b"".join(encode_event(e).encode() + b"\n" for e in good)
                  + b'{"seq": 3, "time": NaN, "kind": "note"}\n'  # the json module's reading is kept
                  + b'{"seq": 4, "kind": "note", "text": "\xff"}\n')  # not UTF-8: damaged
    contents = read_events(p)
    assert [e["seq"] for e in contents.events] == [1, 2, 3] and contents.events[:2] == good
    assert "line 4 is damaged" in contents.damage
    p.write_bytes(b"".join(encode_event(e).encode() + b"\n" for e in good) + b'{"seq": 3, "ki')
    torn = read_events(p)
    assert len(torn.events) == 2 and "incomplete last line" in torn.damage
    assert count_lines(p) == 3  # the torn line counts as a line, as it always did


def test_line_counts_follow_the_journal(tmp_path):
    p = tmp_path / "s.jsonl"
    p.write_text("".join(json.dumps({"seq": i, "kind": "note"}) + "\n" for i in range(5)))
    assert count_lines(p) == 5 and [i.events for i in DirectoryStore(tmp_path).list()] == [5]
    with open(p, "a") as f:
        f.write(json.dumps({"seq": 6, "kind": "note", "text": "a longer line"}) + "\n")
    assert count_lines(p) == 6


def test_replay_of_a_big_session_keeps_a_bounded_number_of_checkpoints():
    events = []
    for e in _hit_events(20_000):
        events.append(e)
        if e["kind"] == "hit" and e["id"] % 5000 == 0:
            events.append({"seq": e["seq"], "time": e["time"], "kind": "hit_deleted", "id": e["id"] - 1})
    replay = Replay.from_events(events, "big")
    assert len(replay._checkpoints) <= MAX_CHECKPOINTS + 1
    session = Session.from_events(events, "big")
    assert replay.session.hits == session.hits and replay.session.summary() == session.summary()
    for i in (0, 1, 4999, 5001, 12_345, len(events) - 1):
        expected = Session.from_events(events[: i + 1]).state
        state = replay.at(i)
        assert state.hits == expected.hits and state.deleted_hits == expected.deleted_hits, i


def test_workers_end_when_the_station_process_is_killed(tmp_path):
    script = ("import os, sys, time\n"
              "from cmm.session.worker import SessionWorker\n"
              "w = SessionWorker(1)\n"
              "print(w.call(os.getpid), flush=True)\n"
              "time.sleep(60)\n")
    station = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        worker_pid = int(station.stdout.readline())
        assert _alive(worker_pid)
    finally:
        station.kill()  # SIGKILL: no exit hooks run
        station.wait(10)
    end = time.monotonic() + 30
    while _alive(worker_pid) and time.monotonic() < end:
        time.sleep(0.1)
    assert not _alive(worker_pid), "the worker outlived the killed station"


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_dispose_empties_a_replay_piece_by_piece_in_the_background():
    from cmm.journal.bulk import dispose

    events = _hit_events(6000)
    replay = Replay.from_events(events, "big")
    state = replay.at(len(replay) - 1)
    session = replay.session
    assert len(session.hits) == 6000 and len(state.hits) == 6000
    thread = dispose(session, replay, state)
    assert thread is not None and thread.name == "session-dispose"
    thread.join(30)
    assert not thread.is_alive()
    assert replay._checkpoints == [] and replay.events == [] and session.events == []
    assert len(session.hits) == 0 and len(state.hits) == 0 and len(state.hit_pose) == 0
    assert dispose(None) is None


def _hit_events(n: int) -> list[dict]:
    events = [{"seq": 1, "time": 0.0, "kind": "start"}]
    for k in range(1, n + 1):
        events.append({"seq": k + 1, "time": float(k), "kind": "hit", "id": k, "counts": [k, 0, 0],
                       "machine": [k / 500, 0.0, 0.0], "approach": [0.0, 0.0, -1.0], "point": [k / 500, 0.0, -1.0]})
    return events
