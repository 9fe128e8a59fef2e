"""Step heights and distances between measured features: plane to plane from the centroid of
the second to the first with the angle shown and a warning past STEP_ANGLE_WARN_DEG, axis to plane, and DMIS
TOL/DISTB between two measured faces on the simulated station (it stopped the program before: planes that are
not parallel within 1e-9 rad were refused)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import session_support as sup
from cmm.dmis.features import Actual
from cmm.dmis.runner import run_text
from cmm.dmis.tolerances import Tolerance, evaluate
from cmm.metrology.construct import STEP_ANGLE_WARN_DEG, construct
from cmm.metrology.fit_ls import fit_plane


def _plane(points):
    p = fit_plane(np.asarray(points, float))
    return "plane", {"point": p.point.tolist(), "normal": p.normal.tolist()}


def test_step_height_from_the_centroid_with_the_angle_and_a_warning():
    base = _plane([[x, y, 0.0] for x in (0, 40) for y in (0, 30)])
    # a face 15 mm up, tilted 0.05 deg about Y, centroid at (60, 10): its height there is 15 exactly
    t = math.radians(0.05)
    top = _plane([[60 + x, 10 + y, 15.0 + math.tan(t) * x] for x in (-8, 8) for y in (-5, 5)])
    c = construct("distance", base, top)
    assert c.value == pytest.approx(15.0, abs=1e-12)
    assert "0.0500 deg" in c.projection and c.warning == ""
    # the other way round: from the base's centroid (20, 15) perpendicular to the tilted face
    back = construct("distance", top, base).value
    assert back == pytest.approx((15.0 + math.tan(t) * (20 - 60)) * math.cos(t), abs=1e-9)
    # past the stated limit: the value still, with a warning naming the angle
    t2 = math.radians(2 * STEP_ANGLE_WARN_DEG)
    steep = _plane([[60 + x, 10 + y, 15.0 + math.tan(t2) * x] for x in (-8, 8) for y in (-5, 5)])
    c2 = construct("distance", base, steep)
    assert c2.value == pytest.approx(15.0, abs=1e-12)
    assert c2.warning.startswith("the planes are 1.000 deg from parallel") and "warning" in c2.summary()


def test_axis_to_plane_and_line_to_line():
    base = _plane([[x, y, 0.0] for x in (0, 40) for y in (0, 30)])
    line = ("line", {"point": [5.0, 2.0, 7.5], "direction": [1.0, 0.0, 0.0]})
    c = construct("distance", line, base)
    assert c.value == pytest.approx(7.5) and c.warning == ""
    bore = ("cylinder", {"point": [30.0, 40.0, 20.0], "direction": [0, 0, 1.0], "radius": 15.0})
    c = construct("distance", base, bore)
    assert c.value == pytest.approx(20.0) and "90.0000 deg" in c.projection and c.warning
    skew = construct("distance", line, ("line", {"point": [0, 0, 0.0], "direction": [0, 1.0, 0]}))
    assert skew.value == pytest.approx(7.5)


def test_dmis_distb_between_two_measured_planes_on_the_true_part(tmp_path):
    """The sample part's top face (Z40) and the boss's top (Z55): a 15 mm step, measured with the simulator's
    noise; TOL/DISTB and TOL/ANGLB between them are evaluated (the program ran to its end)."""
    gen = sup.sim_station(tmp_path, "step")
    station = next(gen)
    try:
        text = """FILNAM/'step height'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
GOTO/10, 10, 80
F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1
MEAS/PLANE, F(TOP), 4
  PTMEAS/CART, 10, 10, 40, 0, 0, 1
  PTMEAS/CART, 115, 5, 40, 0, 0, 1
  PTMEAS/CART, 115, 75, 40, 0, 0, 1
  PTMEAS/CART, 10, 70, 40, 0, 0, 1
ENDMES
GOTO/70, 22, 80
F(BTOP) = FEAT/PLANE, CART, 70, 22, 55, 0, 0, 1
MEAS/PLANE, F(BTOP), 3
  PTMEAS/CART, 76, 22, 55, 0, 0, 1
  PTMEAS/CART, 67, 27.2, 55, 0, 0, 1
  PTMEAS/CART, 67, 16.8, 55, 0, 0, 1
ENDMES
GOTO/70, 22, 80
T(STEP) = TOL/DISTB, NOMINL, 15, -0.02, 0.02
T(TILT) = TOL/ANGLB, NOMINL, 0, -0.5, 0.5
OUTPUT/FA(TOP), FA(BTOP), TA(STEP)
OUTPUT/FA(TOP), FA(BTOP), TA(TILT)
ENDFIL
"""
        result = run_text(text, station.controller.commands, name="step.dmi")
        evs = {ev.tolerance.label: ev for ev in result.evaluations}
        assert set(evs) == {"STEP", "TILT"}
        assert abs(evs["STEP"].value) < 0.02 and evs["STEP"].intol
        assert evs["TILT"].intol
    finally:
        gen.close()


def test_distb_between_two_planes_off_parallel_evaluates_with_a_note():
    z = np.array([0, 0, 1.0])
    a = Actual("A", "plane", {"point": [0, 0, 0], "normal": z.tolist(), "form": 0.0})
    n = np.array([math.sin(1e-5), 0.0, math.cos(1e-5)])
    b = Actual("B", "plane", {"point": [10, 0, 15.0], "normal": n.tolist(), "form": 0.0})
    ev = evaluate(Tolerance("S", "DISTB", lower=-0.01, upper=0.01, nominal=15.0), [a, b], {}, np.eye(4))
    assert ev.value == pytest.approx(0.0, abs=1e-12) and ev.intol and ev.note == ""
    steep = np.array([math.sin(0.05), 0.0, math.cos(0.05)])  # 2.9 deg
    b2 = Actual("B", "plane", {"point": [10, 0, 15.0], "normal": steep.tolist(), "form": 0.0})
    ev2 = evaluate(Tolerance("S", "DISTB", lower=-0.01, upper=0.01, nominal=15.0), [a, b2], {}, np.eye(4))
    assert ev2.value == pytest.approx(0.0, abs=1e-12) and "from parallel" in ev2.note
