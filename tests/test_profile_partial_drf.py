"""Profile against partial datum reference frames: the free DOF are fitted in the datum
frame, and a combination of them the toleranced surface does not locate (a translation along the face it lies
in) is left alone; before, a datum frame @A|B with the part turned 0.5 deg on the table gave 5.3e6 mm.
Known answers: the part's faces with a known form, the part tilted and shifted off its nominal set-up; the
fully constrained A|B|C gives twice the largest form deviation, the partial frames a value between the points'
flatness and that."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cmm.metrology import gdt
from cmm.metrology.relations import flatness
from cmm.metrology.datums import build_drf, datum_from_feature
from cmm.metrology.transform import apply_points, apply_vectors, make_pose, rotation_about_axis

SPEC = {"A": ((5, 5, 0), (0, 0, -1)), "B": ((0, 5, 5), (-1, 0, 0)), "C": ((5, 0, 5), (0, -1, 0))}


def _datum(label, pose):
    point, normal = SPEC[label]
    return datum_from_feature(label, "plane", {"point": apply_points(pose, np.array(point, float)),
                                               "normal": apply_vectors(pose, np.array(normal, float))})


@pytest.mark.parametrize("tilt_deg,rz_deg", [(0.01, 0.5), (0.1, 0.5), (0.01, 30.0), (1.0, 0.0)])
def test_profile_with_a_b_c_and_partial_frames_on_a_tilted_shifted_part(tilt_deg, rz_deg):
    mesh = trimesh.creation.box(extents=(40, 30, 20), transform=make_pose(None, (20, 15, 10)))
    rng = np.random.default_rng(5)
    e_side = rng.uniform(-0.005, 0.005, 30)
    side = np.c_[40.0 + e_side, rng.uniform(2, 28, 30), rng.uniform(2, 18, 30)]  # the face x = 40, form e_side
    e_top = rng.uniform(-0.005, 0.005, 30)
    top = np.c_[rng.uniform(2, 38, 30), rng.uniform(2, 28, 30), 20.0 + e_top]
    setup = make_pose(rotation_about_axis([0, 0, 1], np.radians(rz_deg)), (190.0, 150.0, 0.0))
    placed = setup @ make_pose(rotation_about_axis([1, 0.3, 0], np.radians(tilt_deg)), (0.2, -0.1, 0.05))
    for pts, e in ((side, e_side), (top, e_top)):
        values = {}
        for labels in ("A", "AB", "ABC"):
            drf = build_drf([_datum(x, placed) for x in labels])
            ndrf = build_drf([_datum(x, setup) for x in labels])
            r = gdt.profile("profile of a surface", apply_points(placed, pts), mesh, setup, 0.05, drf=drf,
                            nominal_drf=ndrf)
            values[labels] = r.value
        assert values["ABC"] == pytest.approx(2 * np.abs(e).max(), abs=1e-7)
        for labels in ("A", "AB"):
            assert flatness(pts) - 1e-7 <= values[labels] <= values["ABC"] + 1e-7, (labels, values)
