"""Replay (scrubber states) and re-evaluation from raw counts."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import session_support as sup
from cmm.journal.records import FeatureRecord
from cmm.journal.state import SessionState
from cmm.journal.session import Session
from cmm.metrology.fit_hits import fit_hits
from cmm.session.reevaluate import reevaluate
from cmm.session.replay import Replay
from cmm.journal.store import DirectoryStore, load_session, write_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay")
    sup.recorded_copy(root)
    return load_session(DirectoryStore(root), "taught")


def test_replay_yields_the_state_after_each_event(session):
    replay = Replay(session)
    assert len(replay) == len(session.events)
    counts = [len(state.hits) for _, state in replay]
    assert counts[0] == 0 and counts == sorted(counts) and counts[-1] == len(session.hits)
    final = replay.at(-1)
    assert final.features == session.features and final.hits == session.hits
    first_alignment = next(i for i, e in enumerate(session.events) if e["kind"] == "alignment")
    assert replay.at(first_alignment - 1).alignment is None and replay.at(first_alignment).alignment is not None
    assert replay.changes(first_alignment)["pose_changed"]
    hit_index = next(i for i, e in enumerate(session.events) if e["kind"] == "hit")
    assert replay.changes(hit_index)["hits_added"] == [session.events[hit_index]["id"]]
    assert replay.index_at_time(session.events[5]["time"]) == 5
    assert replay.time_fraction(0) == 0.0 and replay.time_fraction(len(replay) - 1) == 1.0
    with pytest.raises(IndexError, match="outside"):
        replay.at(len(replay))


def test_replayed_hits_refit_to_exactly_the_recorded_features(session):
    replay = Replay(session)
    settings = session.probe_settings()
    for i, e in enumerate(session.events):
        if e["kind"] != "feature":
            continue
        state = replay.at(i - 1)  # the hits as they were just before the fit
        hits = [state.hits[h] for h in e["hit_ids"]]
        result = fit_hits(e["feature_kind"], e["method"], [h.machine for h in hits], [h.approach for h in hits],
                          [h.point for h in hits], settings, FeatureRecord.from_event(e).nominal_feature())
        recorded = replay.at(i).features[e["id"]].fit
        for key, value in result.geometry().items():
            assert np.array_equal(np.asarray(value), np.asarray(recorded[key])), (e["name"], key)
        assert result.form == recorded["form"]


def test_checkpointed_positions_match_a_full_rebuild():
    events = [{"seq": 1, "time": 0.0, "kind": "start", "part": "p", "part_pose": np.eye(4).tolist()}]
    for k in range(1, 700):
        if k % 97 == 0:
            events.append({"seq": len(events) + 1, "time": float(k), "kind": "hit_deleted", "id": k - 3})
        events.append({"seq": len(events) + 1, "time": float(k), "kind": "hit", "id": k, "counts": [k, 0, 0],
                       "machine": [k / 500, 0, 0], "approach": [0, 0, -1], "speed": 2.0, "hit_time": float(k),
                       "point": [k / 500, 0, -1.0], "mode": "manual"})
    replay = Replay(Session.from_events(events))
    for i in (0, 1, 254, 255, 256, 257, 511, 512, 600, len(events) - 1):
        state = SessionState()
        for j, e in enumerate(events[: i + 1]):
            state.apply(e, j)
        got = replay.at(i)
        assert got.hits == state.hits and got.deleted_hits == state.deleted_hits and got.index == i


def test_reevaluation_with_the_recorded_settings_reproduces_the_session(session):
    again = reevaluate(session)
    assert again.derived_from["session"] == "taught"
    for hid, h in session.hits.items():
        assert np.allclose(again.hits[hid].machine, h.machine, atol=1e-12, rtol=0)
        assert np.allclose(again.hits[hid].point, h.point, atol=1e-12, rtol=0)
    for fid, f in session.features.items():
        g = again.features[fid].fit
        assert g.get("radius", 0) == pytest.approx(f.fit.get("radius", 0), abs=1e-12)
        assert np.allclose(g.get("point", g.get("center")), f.fit.get("point", f.fit.get("center")), atol=1e-9)


def test_a_larger_tip_radius_changes_the_results_as_the_geometry_says(session, tmp_path):
    settings = session.probe_settings()
    delta = 0.1
    new = reevaluate(session, replace(settings, tip_radius=settings.tip_radius + delta), name="bigger tip")
    by_name = {f.name: f for f in session.features.values()}
    new_by_name = {f.name: f for f in new.features.values()}
    # a boss and a dome (probed from outside): the radius shrinks by exactly the delta
    for name in ("boss", "dome"):
        assert new_by_name[name].fit["radius"] - by_name[name].fit["radius"] == pytest.approx(-delta, abs=1e-9)
    # the top plane, probed from above, moves down its normal by the delta
    old_p, new_p = np.array(by_name["top_plane"].fit["point"]), np.array(new_by_name["top_plane"].fit["point"])
    n = np.array(by_name["top_plane"].fit["normal"])
    assert (new_p - old_p) @ n * np.sign(n[2]) == pytest.approx(-delta, abs=1e-9)
    # every compensated point moved by the delta along its approach direction; raw counts are untouched
    for hid, h in session.hits.items():
        moved = np.array(new.hits[hid].point) - np.array(h.point)
        assert np.allclose(moved, delta * np.array(h.approach), atol=1e-12)
        assert new.hits[hid].counts == h.counts
    # stored as a new session that references the original
    store = DirectoryStore(tmp_path)
    write_session(store, "bigger tip", new.events)
    stored = load_session(store, "bigger tip")
    assert stored.derived_from["session"] == "taught" and stored.start["tip_radius"] == settings.tip_radius + delta
    assert {f.name: f.fit["radius"] for f in stored.features.values() if "radius" in f.fit} == \
        {f.name: f.fit["radius"] for f in new.features.values() if "radius" in f.fit}


def test_reevaluation_with_another_criterion(session):
    new = reevaluate(session, method="minzone")
    assert {f.method for f in new.features.values()} == {"minzone"}
    bad = reevaluate(session, methods={"top_plane": "mic"})
    assert "top_plane" not in {f.name for f in bad.features.values()}
    assert any("could not be refitted" in m for _, m in bad.state.errors)


def test_feature_events_read_and_write_back_unchanged_old_and_new(session):
    """The journal's feature and construction records are its events: read and written back, every recorded event
    gives itself again, keys in order; a feature event from before features named their probe (and without a
    tolerance) too, and re-evaluation keeps each feature's recorded probe and tolerance."""
    from cmm.journal.records import ConstructedRecord

    meta = ("seq", "time", "kind")
    recorded = [e for e in session.events if e["kind"] in ("feature", "constructed")]
    assert recorded and all("probe" in e for e in recorded if e["kind"] == "feature")
    for e in recorded:
        rec = (FeatureRecord if e["kind"] == "feature" else ConstructedRecord).from_event(e)
        assert list(rec.to_event().items()) == [(k, v) for k, v in e.items() if k not in meta]
    old = {"seq": 9, "time": 1.0, "kind": "feature", "id": 3, "name": "bore", "hit_ids": [4, 5, 6],
           "feature_kind": "circle", "method": "ls", "n_points": 3, "form": 0.0, "sigma": None,
           "center": [1.0, 2.0, 3.0], "normal": [0.0, 0.0, 1.0], "radius": 5.0, "diameter": 10.0,
           "nominal": None}
    rec = FeatureRecord.from_event(old)
    assert rec.probe is None and rec.tolerance is None and rec.seq == 9 and rec.kind == "circle"
    assert rec.fit == {"n_points": 3, "form": 0.0, "sigma": None, "center": [1.0, 2.0, 3.0],
                       "normal": [0.0, 0.0, 1.0], "radius": 5.0, "diameter": 10.0}
    assert rec.to_event() == {k: v for k, v in old.items() if k not in meta}
    built = {"seq": 10, "time": 2.0, "kind": "constructed", "id": 7, "name": "d", "operation": "distance",
             "operands": [3, 4], "result": {"kind": "distance", "value": 43.87}, "nominal": None, "tolerance": None}
    assert list(ConstructedRecord.from_event(built).to_event().items()) == [(k, v) for k, v in built.items()
                                                                             if k not in meta]
    again = reevaluate(session)
    refitted = [e for e in again.events if e["kind"] == "feature"]
    recorded = [e for e in recorded if e["kind"] == "feature"]
    assert [e["id"] for e in refitted] == [e["id"] for e in recorded]
    for e, r in zip(recorded, refitted):
        assert r["probe"] == e["probe"] and r.get("tolerance") == e.get("tolerance") and r["seq"] == e["seq"]
        assert list(r) == list(e)  # the same fields in the same order
