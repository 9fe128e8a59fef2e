"""One hit per touch: a still-held armed jog takes its hit, backs off and stays stopped until the operator lets go.

The operator's defect: holding the armed jog took hit after hit: each touch backed off 1 mm and the
still-held button drove back in (8 s of holding gave 7 identical hits, 0.7 s gave 2), and all went into the fit.
Every front end (page button, key, pendant, gamepad stick) feeds the same jog-hold pipeline with holds while the
input is held and a release when it is let go; here the holds are fed as a front end feeds them (one every 40 ms),
on the simulator's virtual clock, onto the sample part (its face at Z 40 mm there).
"""

from __future__ import annotations

import numpy as np
import pytest

from cmm.control import Refused
from cmm.control.jog import TOUCHED
from control_support import make_controller

DOWN = [0.0, 0.0, -2.0]  # mm/s: the armed jog runs at the probing speed


@pytest.fixture
def ctl():
    _, c, _ = make_controller(start_at=[150.0, 100.0, 250.0])
    c.home(None)
    c.move(None, [250.0, 190.0, 43.0], frame="machine").wait(120)
    yield c
    c.close()


def _hold(c, seconds: float, hits: list) -> list:
    """Hold the armed jog down for ``seconds`` of machine time (a hold every 40 ms); the notes the holds returned."""
    notes = []
    end = c.clock.now() + seconds
    while c.clock.now() < end:
        try:
            notes.append(c.jogs.hold(None, DOWN, probe=True))
        except Refused as exc:  # what a front end shows (throttled), and goes on holding
            notes.append(str(exc))
        c.run_for(0.04)
    return notes


def test_a_held_armed_jog_takes_one_hit_until_let_go(ctl):
    hits: list = []
    ctl.prober.listeners.append(hits.append)
    notes = _hold(ctl, 6.0, hits)  # contact after ~1.5 s; the retract; then 4 s more of holding
    assert len(hits) == 1, [h.machine for h in hits]
    assert TOUCHED in notes  # the front end is told why the held jog does not move
    assert not [n for n in notes if n and "busy" in n], notes  # no error while it backs off
    z = ctl.state.machine.position[2]
    ctl.run_for(0.5)
    assert abs(ctl.state.machine.position[2] - z) < 1e-3  # stays stopped, backed off
    ctl.jogs.release(None)
    _hold(ctl, 2.0, hits)  # a new press takes the next hit
    assert len(hits) == 2
    assert np.allclose(hits[0].machine, hits[1].machine, atol=0.01)


def test_a_short_hold_takes_one_hit(ctl):
    hits: list = []
    ctl.prober.listeners.append(hits.append)
    _hold(ctl, 1.6, hits)
    while not hits:  # until the touch
        _hold(ctl, 0.1, hits)
    _hold(ctl, 0.7, hits)  # held 0.7 s past the touch (the operator's case: it gave 2 hits)
    ctl.jogs.release(None)
    ctl.run_for(0.3)
    assert len(hits) == 1
