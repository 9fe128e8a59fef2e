"""The station records a complete session: configuration snapshot, part hash, alignment, hits, notes."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.session.model import mesh_sha256
from cmm.session.store import DirectoryStore, SessionBusy, load_session
from cmm.station import Station


@pytest.fixture
def station(tmp_path):
    st = Station(session_dir=tmp_path).start("recorded")
    yield st
    st.close()


def test_the_station_journals_config_part_hash_alignment_and_hits(station, tmp_path):
    store = DirectoryStore(tmp_path)
    with pytest.raises(SessionBusy, match="being recorded"):
        store.delete("recorded")  # refused while the station writes it
    assert store.list()[0].open_for_writing
    pose = station.part.pose.copy()
    pose[:3, 3] += [0.35, -0.2, 0.0]
    station.set_alignment(pose, "manual", note="test")
    top = (pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]
    hit = station.probe(top, [0, 0, -1], clearance_z=70.0).wait(30)
    station.note("one hit")
    station.journal.close()  # end of the session (the fixture closes the machine)

    s = load_session(store, "recorded")
    start = s.start
    assert start["format"] == 2 and len(start["axes"]) == 3 and start["axes"][0]["counts_per_mm"] == 500.0
    assert start["part_sha256"] == mesh_sha256(station.part.mesh) and s.part.sha256 == start["part_sha256"]
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
    from cmm.session.store import StoreError

    with pytest.raises(StoreError, match="not a usable session name"):
        station.new_session(bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recorded.jsonl"]  # nothing written elsewhere
    assert not (tmp_path.parent.parent / "escape.jsonl").exists()
    station.note("still recording")  # the session that was open goes on
    assert station.journal is not None and station.journal.path.name == "recorded.jsonl"
