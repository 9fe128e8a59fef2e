"""One fold of the journal's events: the live measurement model's state is the fold replay and re-evaluation make
of the journal it wrote, record by record, so an event means one thing to the station and to the session files."""

from __future__ import annotations

import time

import numpy as np
import pytest

from cmm.machine.probing import Hit
from cmm.measurement.model import MeasurementError, MeasurementModel
from cmm.journal.state import SessionState
from cmm.journal.writer import read_events
from cmm.journal.session import Session

TOP = ((20.0, 15.0, 40.0), (50.0, 5.0, 40.0), (110.0, 70.0, 40.0), (95.0, 10.0, 40.0))  # part mm, on the top face


@pytest.fixture
def station(stations):
    return stations.station("first part")


def file_fold(path) -> SessionState:
    """The final state of the journal file as replay, re-evaluation and the report read it."""
    contents = read_events(path)
    assert contents.damage is None and contents.events[0]["kind"] == "start"
    return Session.from_events(contents.events).state


def assert_same(live: SessionState, fold: SessionState) -> None:
    """Record by record (readable failures), then every field of the state."""
    assert list(live.hits) == list(fold.hits)
    for hid, rec in fold.hits.items():
        assert live.hits[hid] == rec, f"hit {hid}"
    assert list(live.deleted_hits) == list(fold.deleted_hits)
    for hid, rec in fold.deleted_hits.items():
        assert live.deleted_hits[hid] == rec, f"deleted hit {hid}"
    assert live.hit_pose == fold.hit_pose and live.unaligned == fold.unaligned and live.aligned == fold.aligned
    assert live.features.keys() == fold.features.keys()
    for fid, rec in fold.features.items():
        assert live.features[fid] == rec, f"feature {fid}"
    assert live.constructed == fold.constructed
    assert live.datums == fold.datums and live.gdt == fold.gdt and live.info == fold.info
    assert live.part == fold.part and live.part_pose == fold.part_pose and live.alignments == fold.alignments
    assert live.notes == fold.notes and live.errors == fold.errors
    assert live == fold  # the rest too: index, seq, time and the last event


def probe(model, pose, p, approach) -> int:
    """A programmed hit at part point ``p`` (the simulator probes the part), its session id."""
    point = (pose @ np.append(np.asarray(p, float), 1.0))[:3]
    hit = model.probe(point, pose[:3, :3] @ np.asarray(approach, float), clearance_z=70.0).wait(30)
    return model.hit_id(hit)


def test_the_live_state_is_the_fold_of_its_journal(station):
    model = station.measurement
    pose = model.part.pose.copy()
    model.set_info(operator="A. Operator", drawing="DWG-7", temperature="20.5")
    top = [probe(model, pose, p, (0, 0, -1)) for p in TOP]
    stray = probe(model, pose, (10.0, 60.0, 40.0), (0, 0, -1))
    assert model.undo() == f"removed hit {stray}"  # the hit just taken, undone
    boss = []
    for a in np.radians([10, 100, 190, 280, 330]):
        n = np.array([np.cos(a), np.sin(a), 0.0])
        boss.append(probe(model, pose, np.array([70.0, 22.0, 47.0]) + 10.0 * n, -n))
    model.delete_hit(boss[4])  # stays deleted
    model.delete_hit(top[1])
    assert model.undo() == f"restored hit {top[1]}"
    aligned = pose.copy()
    aligned[:3, 3] += [0.05, -0.03, 0.0]
    model.set_alignment(aligned, "manual", note="shifted by hand")  # the hits before it get its pose
    plane = model.fit_feature("plane", top, name="top")
    ring = model.fit_feature("circle", boss[:4], name="boss ring", tolerance={"size": 0.02})
    model.set_feature_nominal(ring.id, tolerance={"form": 0.01})
    model.construct_feature("distance", ring.id, plane.id, name="ring above top")
    model.define_datum("A", plane.id)
    model.define_gdt("flatness", plane.id, 0.05)
    spare, _ = model.define_gdt("flatness", plane.id, 0.1, name="spare")
    model.delete_gdt(spare["id"])
    with pytest.raises(MeasurementError, match="no hit"):
        model.delete_hit(999)  # refused: journals nothing, changes nothing
    model.note("first part done")

    first = model.journal.path
    live = model.state.copy()
    assert list(live.hits) == top + boss[:4] and list(live.deleted_hits) == [stray, boss[4]]
    assert live.hit_pose[top[0]] == live.part_pose == tuple(tuple(r) for r in aligned.tolist())
    assert set(live.features) == {plane.id, ring.id} and len(live.constructed) == 1
    assert set(live.datums) == {"A"} and [d["name"] for d in live.gdt.values()] == [f"flatness {plane.name}"]
    assert live.info == {"operator": "A. Operator", "drawing": "DWG-7", "temperature": 20.5}
    assert [t for _, t in live.notes] == ["first part done"]
    # the model reads its hits, datums, tolerances and header from the fold
    assert model.hits is model.state.hits and model.deleted is model.state.deleted_hits
    assert model.datums is model.state.datums and model.gdt is model.state.gdt and model.info is model.state.info
    assert model.last_hit == model.deleted[boss[4]]  # the last hit taken, as the fold keeps it
    assert_same(live, file_fold(first))

    second = model.new_part("second part")  # the next part of the series: the fold starts again with its journal
    assert not model.hits and not model.deleted and not model.datums and not model.gdt and model.info == live.info
    again = [probe(model, aligned, p, (0, 0, -1)) for p in TOP[:3]]
    assert min(again) > max(boss)  # ids go on counting
    model.fit_feature("plane", again, name="top")
    model.note("second part done")
    assert_same(model.state, file_fold(second))
    assert_same(live, file_fold(first))  # the first part's journal is as it was


def test_without_a_journal_the_model_still_folds_what_it_records(tmp_path):
    """A model with no journal open (a script before its session): hits, undo and the header go through the same
    fold, and a journal opened later starts with what is measured."""
    from session_support import setup

    _, machine, prober = setup()
    try:
        model = MeasurementModel(machine, prober, lambda *a, **k: None, session_dir=tmp_path)
        for k in range(3):
            p = (100.0 + k, 50.0, 40.0)
            model.add_hit(Hit(counts=(k, 0, 0), machine=(p[0], p[1], p[2] + 1.0), approach=(0.0, 0.0, -1.0),
                              speed=2.0, time=time.time(), point=p))
        model.delete_hit(2)
        model.undo()
        model.set_info(operator="B")
        assert list(model.hits) == [1, 2, 3] and model.state.seq == 6 and model.info == {"operator": "B"}
        assert model.hits[1].point == (100.0, 50.0, 40.0) and model.hits[1].seq == 1
        path = model.new_session("later")
        events = read_events(path).events
        assert [e["kind"] for e in events] == ["start", "info"] and events[1]["operator"] == "B"
        assert list(model.hits) == [1, 2, 3] and model.state.seq == 2  # measured stays; seq is the journal's
    finally:
        machine.close()
