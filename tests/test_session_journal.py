"""Journal durability: a killed recording loses no acknowledged hit; damaged journals open with every intact event."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from cmm.journal.writer import Journal, JournalBusy, JournalError, read_events
from cmm.session.replay import Replay
from cmm.journal.store import DirectoryStore, load_session

import session_support as sup

CHILD = textwrap.dedent("""
    import sys
    sys.path.insert(0, {tests!r})
    import numpy as np
    import session_support as sup
    from cmm.measurement.model import Part
    from cmm.measurement.recording import record
    from cmm.journal.store import DirectoryStore
    sim, machine, prober = sup.setup()
    part = Part("sample part", sim.part_mesh, sim.settings.part_pose.copy())
    rec = record(DirectoryStore({root!r}).create("killed"), machine, prober, part)
    print("ready", flush=True)
    k = 0
    while True:
        k += 1
        xy = (10 + (k * 7) % 100, 4 + (k * 3) % 6)
        hit = prober.probe(sup.to_machine(part.pose, [*xy, 40.0]), [0, 0, -1]).wait()
        print(rec.hit_id(hit), flush=True)  # acknowledged: the hit is on disk
""")


def test_killing_the_recording_loses_no_acknowledged_hit(tmp_path):
    tests = str(Path(__file__).parent)
    child = subprocess.Popen([sys.executable, "-c", CHILD.format(tests=tests, root=str(tmp_path))],
                             stdout=subprocess.PIPE, text=True)
    acknowledged = []
    try:
        assert child.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 120
        while len(acknowledged) < 12 and time.monotonic() < deadline:
            line = child.stdout.readline()
            if not line:
                break
            acknowledged.append(int(line))
        os.kill(child.pid, signal.SIGKILL)  # mid-way through the next hit
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(10)
    assert len(acknowledged) >= 12
    store = DirectoryStore(tmp_path)
    session = load_session(store, "killed")
    assert set(acknowledged) <= set(session.hits)
    assert not store.list()[0].open_for_writing  # the lock died with the process
    with Journal(store.path("killed")) as j:  # it can be appended to again
        assert j.seq == len(session.events)


def test_a_truncated_journal_opens_with_every_intact_event(tmp_path):
    path = sup.recorded_copy(tmp_path)
    whole = read_events(path).events
    data = path.read_bytes()
    path.write_bytes(data[:-25])  # a torn last line, as a kill mid-write leaves it
    s = load_session(DirectoryStore(tmp_path), "taught")
    assert len(s.events) == len(whole) - 1
    assert s.damage and f"line {len(whole)} is damaged" in s.damage and "incomplete last line" in s.damage
    assert s.warnings[0] == s.damage
    assert len(Replay(s)) == len(whole) - 1
    # a writer reopening it moves the torn bytes aside and appends after the intact events
    with Journal(path) as j:
        assert j.damage and j.seq == len(whole) - 1
        j.append("note", text="resumed")
    again = read_events(path)
    assert again.damage is None and again.events[-1]["seq"] == len(whole)
    aside = list(tmp_path.glob("taught.jsonl.damaged-*"))
    assert len(aside) == 1 and data[:-25].endswith(aside[0].read_bytes())


def test_a_corrupted_line_ends_the_read_with_a_message(tmp_path):
    path = sup.recorded_copy(tmp_path)
    lines = path.read_bytes().splitlines(keepends=True)
    lines[10] = b'{"seq": 11, "kind": "hit", "id": \x00\xff garbage\n'
    path.write_bytes(b"".join(lines))
    s = load_session(DirectoryStore(tmp_path), "taught")
    assert len(s.events) == 10
    assert "line 11 is damaged" in s.damage and "10 events before it are intact" in s.damage
    path.write_bytes(b"")
    assert load_session(DirectoryStore(tmp_path), "taught").events == []


def test_one_writer_per_journal_and_nan_is_refused(tmp_path):
    with Journal(tmp_path / "a.jsonl") as j:
        with pytest.raises(JournalBusy, match="already open for writing"):
            Journal(tmp_path / "a.jsonl")
        with pytest.raises(ValueError):
            j.append("hit", point=[float("nan"), 0, 0])
        event = j.append("note", text="after")
        assert event["seq"] == 1  # the refused event took no number
    assert [json.loads(line)["text"] for line in (tmp_path / "a.jsonl").read_text().splitlines()] == ["after"]


def test_a_hit_that_could_not_be_written_on_a_full_disk_is_not_in_the_journal(tmp_path):
    """A write the operating system refuses part-way (here: the file size limit, as a full disk does).

    The hit the operator is told was not recorded must not turn up later, under the seq of the
    fault event that follows it; the journal stays readable and numbered 1, 2, 3 ...
    """
    path = tmp_path / "full.jsonl"
    j = Journal(path)
    j.append("start", port="sim://")
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (path.stat().st_size + 20, hard))  # room for 20 bytes more
    try:
        with pytest.raises(OSError) as refused:
            j.append("hit", id="h7", point=[250.0, 190.0, 40.0], probe="Probe1")
        assert path.read_bytes().endswith(b"\n")  # the partly written line is cut off again
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))  # space again: the fault event goes in
    assert isinstance(refused.value, JournalError)
    assert "hit event could not be written" in str(refused.value) and "not recorded" in str(refused.value)
    fault = j.append("error", source="machine:fault", message="the hit could not be recorded")
    j.append("note", text="after")
    j.close()
    events = read_events(path)
    assert events.damage is None
    assert [(e["seq"], e["kind"]) for e in events.events] == [(1, "start"), (2, "error"), (3, "note")]
    assert fault["seq"] == 2
