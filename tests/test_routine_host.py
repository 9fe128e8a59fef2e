"""A routine's run gets the narrow RoutineHost (cmm/measurement/routine_host.py), never the measurement model or the
control core: its one adapter, StationRoutineHost, has every operation of the protocol with the protocol's
parameters, and a run on it over a simulated station (virtual clock) measures, constructs, journals and ends at the
clearance plane; the routine verbs hand a run the host acting for the client that sends them."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
import session_support as sup

from cmm.control.access import Client
from cmm.journal.writer import read_events
from cmm.measurement.routine import Routine
from cmm.measurement.routine_host import RoutineHost, StationRoutineHost
from cmm.measurement.routine_run import RoutineRun
from cmm.sim.cmm_sim import TRUE_PART_POSE

# two faces of the block (part mm): hits on the top and the front, approach into them
@pytest.fixture
def station(stations):
    st = stations.station("routine host")
    st.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's set-up")
    return st


def _routine(part) -> Routine:
    routine = sup.planes_routine(part, "two faces", ("TOP", "FRONT"))
    routine.steps.append({"kind": "construct", "name": "square", "operation": "angle", "of": ["TOP", "FRONT"]})
    return routine


def _operations(cls: type) -> dict[str, list[str]]:
    return {name: list(inspect.signature(fn).parameters) for name, fn in vars(cls).items()
            if callable(fn) and not name.startswith("_")}


def test_the_adapter_has_every_operation_of_the_protocol_and_no_other():
    protocol, adapter = _operations(RoutineHost), _operations(StationRoutineHost)
    assert protocol and protocol == {name: adapter.get(name) for name in protocol}
    assert set(adapter) == set(protocol)  # no other operation a run could reach for
    host = StationRoutineHost.__init__
    assert list(inspect.signature(host).parameters) == ["self", "model", "controller", "client", "select_probes"]


def test_a_run_on_the_stations_host_measures_constructs_journals_and_ends_clear(station):
    model, api = station.measurement, station.controller.commands
    me = Client("page", local=True)
    host = StationRoutineHost(model, station.controller, me)
    assert host.mode() == "idle" and np.allclose(host.position(), api.invoke(me, "position"))
    assert host.part() is model.part and host.clearance_z() == model.clearance_z()
    run = RoutineRun(_routine(model.part), host, part_name="H-1")
    progress = run.run()
    assert progress.state == "done" and progress.hits == 6, progress.message
    top, front, square = (progress.results[n] for n in ("TOP", "FRONT", "square"))
    assert top.id in model.features and front.id in model.features and square.id in model.constructed
    assert abs(square.result.value - 90.0) < 0.05  # the block's top and front are square
    assert sorted(host.hits()) == sorted(model.hits) and len(model.hits) == 6
    events = read_events(model.journal.path).events  # the part's own session, started by the run
    assert [e["name"] for e in events if e["kind"] == "routine"] == ["two faces"]
    assert "routine 'two faces' finished" in [e.get("text", "") for e in events if e["kind"] == "note"]
    # the run ended at the clearance plane: no climb is left to do
    assert api.invoke(me, "clearance_target") is None and host.mode() == "idle"


def test_the_routine_verbs_hand_a_run_the_host_acting_for_their_client(station):
    api = station.controller.commands
    me = Client("page", local=True)
    run = api.invoke(me, "new_routine_run", routine=_routine(station.measurement.part), part_name="H-2")
    assert isinstance(run.host, StationRoutineHost) and run.host.client is me
    assert run.progress.state == "ready" and not station.measurement.hits  # built, nothing changed
