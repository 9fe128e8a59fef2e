"""Queries and subscriptions through the one API: a front end follows the machine without touching the station."""

from __future__ import annotations

import math
import threading
import time

import pytest

from cmm.api import CommandError


@pytest.fixture(scope="module")
def station(module_stations):
    return module_stations.station("subs")


def _until(pred, seconds=120.0):
    end = time.monotonic() + seconds
    while not pred():
        assert time.monotonic() < end, "the subscriber never heard it"
        time.sleep(0.01)


def test_a_subscriber_hears_the_machine_move_at_a_bounded_rate_and_nothing_while_it_stands(station):
    api = station.controller.commands
    op = "subscriber-test"
    assert api.call(op, "take_control").ok
    heard: list[tuple[float, dict]] = []
    lock = threading.Lock()

    def on_change(changed):
        with lock:
            heard.append((time.monotonic(), changed))

    start = api.invoke(op, "position", frame="machine")
    rate = 20.0
    sub = api.subscribe(op, {"position": {"frame": "machine"}, "job": None}, on_change, rate=rate)
    try:
        _until(lambda: len(heard) >= 1)
        first = heard[0][1]
        assert set(first) == {"position", "job"}  # the first delivery is the whole snapshot
        assert first["position"] == pytest.approx(list(start), abs=1e-9)
        target = [start[0] + 40.0, start[1], start[2]]
        # the move at the wall clock's pace (about a second), so a 20 Hz subscriber hears it on its way however
        # fast the uncapped simulator would run it
        station.sim.network.set_pace(1.0)
        t0 = time.monotonic()
        try:
            assert api.call(op, "move", {"target": target, "frame": "machine"}, wait=True, timeout=300).ok
        finally:
            station.sim.network.set_pace(None)
        _until(lambda: any(c.get("position") == pytest.approx(target, abs=1e-3) for _, c in heard))
        t1 = time.monotonic()
        with lock:
            moving = [c["position"] for t, c in heard[1:] if "position" in c]
            during = [t for t, _ in heard if t0 <= t <= t1]
        xs = [p[0] for p in moving]
        assert len(set(round(x, 3) for x in xs)) >= 2  # it heard the machine on its way, not only at the end
        assert xs == sorted(xs)  # in order
        assert len(during) <= rate * (t1 - t0) + 2  # never faster than the rate asked for
        # standing still: the queries answer the same, so nothing is sent
        hub = api._subscriptions
        assert hub.poll(sub) == {}
    finally:
        sub.close()
        api.call(op, "release_control")
    assert api._subscriptions.count() == 0


def test_only_queries_may_be_subscribed_and_the_rate_is_bounded(station):
    api = station.controller.commands
    names = {v.name for v in api.queries()}
    assert {"position", "state", "job"} <= names and "move" not in names
    with pytest.raises(CommandError, match="'move' is not a query"):
        api.subscribe(None, {"move": {}}, lambda c: None)
    for rate in (1000.0, 0.0, math.nan):
        with pytest.raises(CommandError, match="updates a second"):
            api.subscribe(None, {"position": {}}, lambda c: None, rate=rate)


def test_a_failing_query_is_told_to_its_subscriber_and_a_broken_subscriber_is_closed(station):
    api = station.controller.commands
    got: list[dict] = []
    sub = api.subscribe(None, {"position": {"frame": "no-such-frame"}}, got.append, rate=10)
    try:
        _until(lambda: got)
        assert "error" in got[0]["position"]
    finally:
        sub.close()

    def broken(_changed):
        raise RuntimeError("a front end's bug")

    bad = api.subscribe(None, {"position": {}}, broken, rate=10)
    _until(lambda: bad.closed)
    assert api._subscriptions.count() == 0


def test_the_documented_front_end_moves_the_machine_and_follows_it(stations):
    """The example as its docstring runs it, the simulator at the machine's own pace: a subscription at 10 a
    second hears the tip on the way (an uncapped virtual clock may finish a 20 mm move in a few wall ms)."""
    station = stations.station("console", port="sim://?cmm=1&pace=1")
    try:
        _follow_the_example(station)
    finally:
        station.close()


def _follow_the_example(station):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "docs" / "examples" / "console_front_end.py"
    spec = importlib.util.spec_from_file_location("console_front_end", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    lines: list[str] = []
    start = station.controller.commands.invoke(None, "position", frame="machine")
    xs = example.console(station.controller.commands, say=lines.append)
    assert lines.count("arrived") == 2, lines
    assert len(set(xs)) >= 2 and all(start[0] - 1e-3 <= x <= start[0] + 20.0 + 1e-3 for x in xs)
    assert station.controller.commands.invoke(None, "position", frame="machine") == pytest.approx(start, abs=1e-3)
    assert len(path.read_text().splitlines()) <= 60


def test_the_model_query_is_a_snapshot_the_page_draws_from(station):
    """The page's panels and 3-D view read the measurement model through the ``model`` query: a copy taken under
    the model's lock inside the measurement package, which a later hit does not change."""
    from cmm.measurement.queries import ModelSnapshot

    api = station.controller.commands
    op = "model-query-test"
    assert "model" in {v.name for v in api.queries()}
    api.invoke(op, "take_control")
    try:
        before = api.invoke(None, "model")  # a query: open to an anonymous observer too
        assert isinstance(before, ModelSnapshot)
        # a hit on the sample part's top face (part frame)
        api.invoke(op, "probe", target=[15.0, 10.0, 40.0], approach=[0.0, 0.0, -1.0], frame="part").wait(300)
        after = api.invoke(op, "model")
        assert len(after.hits) == len(before.hits) + 1  # the new hit is in the new snapshot...
        assert set(after.hits) - set(before.hits) == {after.last_hit.id}
        assert after.hit_or_deleted().keys() >= after.hits.keys()
        assert len(api.invoke(op, "model").hits) == len(after.hits)  # ...and never in the old one
    finally:
        api.invoke(op, "release_control")
