"""The command API's own package: mechanics that know no machine, and the queries and streams the control core
registers into it, which the I++ DME server reads the station through."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.api import AccessRefused, Client, CommandAPI, CommandError
from cmm.control.access import Control, OpenPolicy


class Jammed(RuntimeError):
    pass


class Stuck(Jammed):
    pass


def test_the_api_answers_with_the_codes_each_layer_registers_for_its_errors():
    """A bare API has only its own codes; a layer's error kinds are tried in the order registered (a kind that
    comes first wins over a later, wider one) and a code may depend on the error's words."""
    api = CommandAPI()

    def fail(client, error):
        raise error
    api.register("fail", fail, {"error": api.REQUIRED}, "raise the error given")
    assert api.call(None, "nothing").error["code"] == "unknown_method"
    assert api.call(None, "fail").error == {"code": "bad_params", "message": "fail needs error"}
    assert api.call(None, "fail", {"error": Stuck("stuck")}).error["code"] == "failed"  # not registered yet
    assert api.call(None, "fail", {"error": AccessRefused("take control")}).error["code"] == "refused"
    assert api.call(None, "fail", {"error": TypeError("a number")}).error["code"] == "bad_params"
    api.register_error(Stuck, "fault")
    api.register_error(Jammed, lambda exc: "limit" if "travel" in str(exc) else "motion")
    assert api.call(None, "fail", {"error": Stuck("outside the travel")}).error["code"] == "fault"
    assert api.call(None, "fail", {"error": Jammed("outside the travel")}).error["code"] == "limit"
    assert api.call(None, "fail", {"error": Jammed("servo")}).error == {"code": "motion", "message": "servo"}
    cancelled = Jammed("ended")
    cancelled.cancelled = True  # a job that ended itself for the cancel verb
    assert api.call(None, "fail", {"error": cancelled}).error["code"] == "cancelled"


def test_a_stream_is_heard_until_its_listener_ends_it():
    api = CommandAPI()
    listeners = []

    def subscribe(fn):
        listeners.append(fn)
        return lambda: listeners.remove(fn)
    api.register_stream("ticks", subscribe, "fn(n) on every tick")
    heard = []
    end = api.listen(Client("page"), "ticks", heard.append)
    for fn in list(listeners):
        fn(1)
    end()
    for fn in list(listeners):
        fn(2)
    assert heard == [1] and [s.name for s in api.streams()] == ["ticks"]
    with pytest.raises(CommandError, match="'tocks' is not a stream; the streams are ticks"):
        api.listen(None, "tocks", heard.append)


@pytest.fixture(scope="module")
def station(module_stations):
    return module_stations.station()


def test_the_machine_queries_a_front_end_reads_the_station_through(station):
    """Who holds control, the configuration, a target checked against the travel and the tip radius, read as any
    client may (queries are open to observers), and the events stream hears an E-stop."""
    api = station.controller.commands
    control = Control()
    station.controller.use_policy_of(control)
    try:
        assert api.invoke(Client("lan-tab"), "control") == {"holder": None, "yours": False}
        assert api.call(Client("pendant", local=True), "take_control").ok
        control.set_name("pendant", "Maria")
        assert api.invoke(Client("pendant", local=True), "control") == {"holder": "Maria", "yours": True}
        assert api.invoke("lan-tab", "control") == {"holder": "Maria", "yours": False}
        config = api.invoke("lan-tab", "machine_config")
        assert config is station.config
        inside = [(a.min + a.max) / 2 for a in config.axes]
        assert np.allclose(api.invoke("lan-tab", "check_target", target=inside), inside)
        outside = api.call("lan-tab", "check_target", {"target": [config.axis("x").max + 5.0] + inside[1:]})
        assert outside.error["code"] == "limit" and "target X=" in outside.error["message"], outside
        assert api.invoke("lan-tab", "tip_radius") == pytest.approx(station.prober.settings.tip_radius)
        heard = []
        end = api.listen("lan-tab", "events", lambda kind, info: heard.append(kind))
        try:
            assert api.invoke(None, "estop")["ok"]
            station.controller.dispatcher.flush()
            assert "estop" in heard
        finally:
            end()
            api.invoke(None, "reset")
        assert api.invoke("pendant", "release_control")["released"]
    finally:
        station.controller.policy = OpenPolicy()
