"""The station records a complete session: configuration snapshot, part hash, alignment, hits, notes."""

from __future__ import annotations

import time

import numpy as np
import pytest

from cmm.control.modes import Refused
from cmm.journal.session import mesh_sha256
from cmm.journal.store import DirectoryStore, SessionBusy, load_session


@pytest.fixture
def station(stations):
    return stations.station("recorded")


def test_the_station_journals_config_part_hash_alignment_and_hits(station, tmp_path):
    store = DirectoryStore(tmp_path)
    with pytest.raises(SessionBusy, match="being recorded"):
        store.delete("recorded")  # refused while the station writes it
    assert store.list()[0].open_for_writing
    pose = station.measurement.part.pose.copy()
    pose[:3, 3] += [0.35, -0.2, 0.0]
    station.measurement.set_alignment(pose, "manual", note="test")
    top = (pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]
    hit = station.measurement.probe(top, [0, 0, -1], clearance_z=70.0).wait(30)
    station.measurement.note("one hit")
    station.measurement.journal.close()  # end of the session (the fixture closes the machine)

    s = load_session(store, "recorded")
    start = s.start
    assert start["format"] == 2 and len(start["axes"]) == 3 and start["axes"][0]["counts_per_mm"] == 500.0
    assert start["part_sha256"] == mesh_sha256(station.measurement.part.mesh) and s.part.sha256 == start["part_sha256"]
    assert start["tip_radius"] == station.prober.settings.tip_radius and "correction" in start
    assert s.state.alignment.method == "manual" and np.allclose(s.state.pose_array, pose)
    (h,) = s.hits.values()
    assert h.counts == hit.counts and h.point == pytest.approx(hit.point)
    assert np.allclose(s.counts_to_mm([h.counts])[0], h.machine, atol=1e-12)
    assert s.state.notes[-1][1] == "one hit"
    store.rename("recorded", "renamed")  # closed now: allowed
    assert [i.name for i in store.list()] == ["renamed"]


@pytest.mark.parametrize("bad", ["../../escape", "/tmp/absolute", "a/b", "", ".hidden", "x" * 200])
def test_session_names_are_checked_by_the_station_itself(station, tmp_path, bad):
    from cmm.journal.store import StoreError

    with pytest.raises(StoreError, match="not a usable session name"):
        station.measurement.new_session(bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recorded.jsonl"]  # nothing written elsewhere
    assert not (tmp_path.parent.parent / "escape.jsonl").exists()
    station.measurement.note("still recording")  # the session that was open goes on
    assert station.measurement.journal is not None and station.measurement.journal.path.name == "recorded.jsonl"


def test_report_fields_cad_nominals_tolerances_and_refit(station, tmp_path):
    """Header fields are journaled; a feature fitted without a pick gets the CAD surface its hits lie on;
    tolerances are validated and kept; deleting a hit from a feature refits it in place."""
    from cmm.measurement.model import MeasurementError

    station.measurement.set_info(operator="A. Operator", drawing="DWG-1", temperature="20.5")
    with pytest.raises(MeasurementError, match="degrees Celsius"):
        station.measurement.set_info(temperature="warm")
    with pytest.raises(MeasurementError, match="unknown report field"):
        station.measurement.set_info(colour="blue")
    pose = station.measurement.part.pose  # not aligned: the simulator's part is a few tenths off, within the match distance
    ids = []
    for a in np.radians([10, 100, 190, 280]):
        n = np.array([np.cos(a), np.sin(a), 0.0])
        p = (pose @ np.append(np.array([70.0, 22.0, 47.0]) + 10.0 * n, 1.0))[:3]
        hit = station.measurement.probe(p, -(pose[:3, :3] @ n), clearance_z=70.0).wait(30)
        ids.append(station.measurement.hit_id(hit))
    with pytest.raises(MeasurementError, match="positive"):
        station.measurement.fit_feature("circle", ids, tolerance={"size": -1})
    f = station.measurement.fit_feature("circle", ids, name="boss ring", tolerance={"size": 0.01, "position": 0.05})
    assert f.nominal is not None and f.nominal.kind == "cylinder" and f.nominal.params["radius"] == pytest.approx(10.0)
    g = station.measurement.refit_feature(f.id, ids[:3])
    assert g.id == f.id and g.hit_ids == ids[:3] and g.nominal is f.nominal and g.tolerance == f.tolerance
    station.measurement.set_feature_nominal(f.id, tolerance={"form": 0.005})
    station.measurement.journal.close()
    s = load_session(DirectoryStore(tmp_path), "recorded")
    assert s.state.info == {"operator": "A. Operator", "drawing": "DWG-1", "temperature": 20.5}
    assert s.start["calibration"] == {"probe": None, "machine": None, "problems": []}
    (rec,) = s.features.values()
    assert rec.hit_ids == tuple(ids[:3]) and rec.tolerance == {"size": 0.01, "position": 0.05, "form": 0.005}
    assert rec.nominal["kind"] == "cylinder"


@pytest.fixture
def paced_station(stations):
    # a person's jog refreshes come in wall time: the simulated clock must not race past the dead-man (homed on
    # the uncapped clock, then paced as netutil.SIM_PACED)
    return stations.station("manual", pace=1.0)


def test_manual_hits_are_taken_at_the_qualified_probing_speed(paced_station):
    """An armed jog at the 10 mm/s jog speed probes at the probing speed the probe was qualified at."""
    station = paced_station
    assert station.calibration.qualified_probing_speed == station.config.speeds.probing
    station.calibration.status = {**station.calibration.status, "probe": {"date": "x", "probing_speed": 1.5}}
    assert station.calibration.qualified_probing_speed == 1.5
    pose = station.measurement.part.pose
    above = (pose @ np.array([20.0, 15.0, 41.5, 1.0]))[:3]
    station.controller.move(None, above, frame="machine").wait(30)
    end = time.monotonic() + 30
    while station.controller.state.mode.value != "idle" and time.monotonic() < end:  # the core has seen the end
        time.sleep(0.01)
    before = len(station.measurement.hits)
    end = time.monotonic() + 60
    while len(station.measurement.hits) == before and time.monotonic() < end:
        try:
            station.controller.jogs.hold(None, [0.0, 0.0, -10.0], probe=True)
        except Refused:  # the contact ended the jog and the station backs off: busy until it is recorded
            pass
        time.sleep(0.05)
    station.controller.jog_release(None)
    assert len(station.measurement.hits) == before + 1
    hit = station.measurement.hits[max(station.measurement.hits)]
    assert hit.mode == "manual" and hit.speed == pytest.approx(1.5, rel=1e-6)


def test_best_fit_alignment_is_journaled_and_moves_the_nominals(station, tmp_path):
    """Best fit of hits on three faces finds the simulator's set-up error; applying it journals the
    alignment (with residuals) and carries every feature's CAD nominal along with the part."""
    from cmm.measurement import alignment
    from cmm.sim.cmm_sim import TRUE_PART_POSE
    from session_support import ALIGN_HITS

    pose = station.measurement.part.pose.copy()
    ids = []
    for p, u in ALIGN_HITS:
        target = (pose @ np.append(np.asarray(p, float), 1.0))[:3]
        hit = station.measurement.probe(target, pose[:3, :3] @ np.asarray(u, float), clearance_z=70.0).wait(30)
        ids.append(station.measurement.hit_id(hit))
    top = station.measurement.fit_feature("plane", ids[:4], name="top")
    before = top.nominal.params["point"].copy()
    result = alignment.best_fit_hits(station.measurement, ids)
    assert result.residuals["RMS"] < 0.002 and result.info["converged"]
    assert np.abs(result.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max() < 0.01
    shift, angle = result.shift(pose)
    assert shift > 0.1 and 0.3 < angle < 0.7  # the simulator's part is ~0.5 deg and a few tenths off
    assert "moved" in result.text(pose) and "RMS" in result.text(pose)
    alignment.apply(station.measurement, result)
    assert station.measurement.aligned and np.allclose(station.measurement.part.pose, result.pose)
    moved = result.pose @ np.linalg.inv(pose)
    assert np.allclose(station.measurement.features[top.id].nominal.params["point"], moved[:3, :3] @ before + moved[:3, 3])
    station.measurement.journal.close()
    s = load_session(DirectoryStore(tmp_path), "recorded")
    assert s.state.alignment.method == "best_fit" and s.state.alignment.info["hit_ids"] == ids
    with pytest.raises(ValueError, match="at least 6"):
        alignment.best_fit_hits(station.measurement, ids[:3])
