"""Datum reference frames: one test per constraint-order rule (ISO 5459 / ASME Y14.5), and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology.datums import DatumError, build_drf, datum_from_feature


def plane(label, point, normal, **kw):
    return datum_from_feature(label, "plane", {"point": point, "normal": normal}, **kw)


def cyl(label, point, direction, radius=5.0, **kw):
    return datum_from_feature(label, "cylinder", {"point": point, "direction": direction, "radius": radius}, **kw)


def sphere(label, center, radius=3.0):
    return datum_from_feature(label, "sphere", {"center": center, "radius": radius})


def tilted(v, deg, about):
    """v rotated by deg about the axis ``about``."""
    a = np.asarray(about, float) / np.linalg.norm(about)
    t = math.radians(deg)
    v = np.asarray(v, float)
    return v * math.cos(t) + np.cross(a, v) * math.sin(t) + a * (a @ v) * (1 - math.cos(t))


def test_three_planes_primary_constrains_three_secondary_two_tertiary_one():
    # A slightly out of square with B and C: A keeps its normal; B is squared to A; C to both
    a = plane("A", (0, 0, 10), tilted((0, 0, 1), 0.2, (1, 0, 0)))
    b = plane("B", (-20, 3, 5), tilted((-1, 0, 0), 1.0, (0, 1, 0)))
    c = plane("C", (4, -30, 5), tilted((0, -1, 0), 1.0, (0, 0, 1)))
    drf = build_drf([a, b, c])
    assert set(drf.constrained) == {"Tx", "Ty", "Tz", "Rx", "Ry", "Rz"} and drf.labels == "A|B|C"
    z, x, y = drf.rotation[:, 2], drf.rotation[:, 0], drf.rotation[:, 1]
    assert np.allclose(z, a.direction, atol=1e-12)  # the primary's orientation is kept exactly
    assert abs(x @ z) < 1e-12 and np.linalg.norm(np.cross(x, b.direction - (b.direction @ z) * z)) < 1e-12
    assert abs(np.linalg.det(drf.rotation) - 1) < 1e-12
    # the origin lies on A, on the plane through B's point perpendicular to A, and likewise for C
    o = drf.origin
    assert abs((o - a.origin) @ a.direction) < 1e-9
    assert abs((o - b.origin) @ x) < 1e-9
    assert abs((o - c.origin) @ y) < 1e-9


def test_primary_plane_alone_leaves_in_plane_dof_free():
    drf = build_drf([plane("A", (0, 0, 5), (0, 0, 1))])
    assert drf.constrained == ("Tz", "Rx", "Ry") and set(drf.free) == {"Tx", "Ty", "Rz"}


def test_plane_then_bore_then_hole_clocks_on_the_hole():
    a = plane("A", (0, 0, 0), (0, 0, 1))
    b = cyl("B", (10, 20, -5), tilted((0, 0, 1), 0.5, (1, 0, 0)))  # B a little out of square with A
    c = cyl("C", (10 + 30 * math.cos(0.3), 20 + 30 * math.sin(0.3), -5), (0, 0, 1))
    drf = build_drf([a, b, c])
    assert set(drf.constrained) == {"Tx", "Ty", "Tz", "Rx", "Ry", "Rz"}
    assert np.allclose(drf.rotation[:, 2], (0, 0, 1))
    # the origin is B's point (the simulated datum B is perpendicular to A through B's location point) on A
    assert np.allclose(drf.origin, (10, 20, 0), atol=1e-9)
    assert np.allclose(drf.rotation[:, 0], (math.cos(0.3), math.sin(0.3), 0), atol=1e-12)


def test_axis_primary_constrains_four_then_face_locates_along_it():
    a = cyl("A", (1, 2, 0), (0, 0, 1))
    drf_a = build_drf([a])
    assert set(drf_a.constrained) == {"Tx", "Ty", "Rx", "Ry"}
    b = plane("B", (0, 0, 7), tilted((0, 0, 1), 0.3, (0, 1, 0)))  # a face nearly square to the axis
    drf = build_drf([a, b])
    assert set(drf.constrained) == {"Tx", "Ty", "Tz", "Rx", "Ry"}
    assert np.allclose(drf.origin[:2], (1, 2)) and abs(drf.origin[2] - 7) < 1e-9


def test_axis_primary_then_flat_parallel_to_it_sets_rotation():
    a = cyl("A", (0, 0, 0), (0, 0, 1))
    flat = plane("B", (0, 4, 0), (0, 1, 0))
    drf = build_drf([a, flat])
    assert set(drf.constrained) == {"Tx", "Ty", "Rx", "Ry", "Rz"}
    assert np.allclose(drf.rotation[:, 0], (0, 1, 0))


def test_three_sphere_centres_make_a_full_frame():
    drf = build_drf([sphere("A", (0, 0, 0)), sphere("B", (0, 0, 50)), sphere("C", (30, 0, 10))])
    assert set(drf.constrained) == {"Tx", "Ty", "Tz", "Rx", "Ry", "Rz"}
    assert np.allclose(drf.rotation[:, 2], (0, 0, 1)) and np.allclose(drf.rotation[:, 0], (1, 0, 0))
    assert np.allclose(drf.origin, 0)


def test_secondary_parallel_to_primary_is_refused():
    with pytest.raises(DatumError, match="datum B \\(plane\\) is parallel to datum A"):
        build_drf([plane("A", (0, 0, 0), (0, 0, 1)), plane("B", (0, 0, -10), (0, 0, -1))])


def test_a_secondary_nearly_parallel_to_the_primary_is_refused():
    # 0.3 deg: it would orient and locate the frame through a lever of 1/sin(0.3 deg) = 190
    with pytest.raises(DatumError, match="datum B \\(plane\\) is parallel to datum A"):
        build_drf([plane("A", (0, 0, 0), (0, 0, 1)), plane("B", (0, 0, 5), tilted((0, 0, 1), 0.3, (1, 0, 0)))])
    assert "Rz" in build_drf([plane("A", (0, 0, 0), (0, 0, 1)),
                              plane("B", (0, 0, 5), tilted((0, 0, 1), 5.0, (1, 0, 0)))]).constrained


def test_tertiary_that_adds_nothing_is_refused():
    a, b = plane("A", (0, 0, 0), (0, 0, 1)), plane("B", (0, 0, 0), (1, 0, 0))
    with pytest.raises(DatumError, match="datum C \\(plane\\) is parallel to datum B"):
        build_drf([a, b, plane("C", (40, 0, 0), (-1, 0, 0))])
    # a plane in the direction A and B leave free is accepted
    assert "Ty" in build_drf([a, b, plane("C", (0, 40, 0), (0, 1, 0))]).constrained


def test_coaxial_clocking_feature_is_refused():
    a = plane("A", (0, 0, 0), (0, 0, 1))
    b = cyl("B", (5, 5, 0), (0, 0, 1))
    with pytest.raises(DatumError, match="datum C \\(axis\\) is coaxial"):
        build_drf([a, b, cyl("C", (5, 5, 20), (0, 0, 1))])


def test_bad_datum_definitions_are_explained():
    with pytest.raises(DatumError, match="is not a feature of size"):
        plane("A", (0, 0, 0), (0, 0, 1), modifier="MMB", boundary=5.0, internal=True)
    with pytest.raises(DatumError, match="needs its boundary"):
        cyl("B", (0, 0, 0), (0, 0, 1), modifier="MMB")
    with pytest.raises(DatumError, match="used twice"):
        build_drf([plane("A", (0, 0, 0), (0, 0, 1)), cyl("A", (0, 0, 0), (1, 0, 0))])
    with pytest.raises(DatumError, match="too large"):
        plane("A", (1e308, 0, 0), (0, 0, 1))
    with pytest.raises(DatumError, match="cannot be a datum feature"):
        datum_from_feature("A", "torus", {})


def test_datum_shift_of_a_bore_at_mmb():
    hole = cyl("B", (0, 0, 0), (0, 0, 1), radius=5.03, modifier="MMB", boundary=10.0, internal=True)
    pin = cyl("B", (0, 0, 0), (0, 0, 1), radius=4.98, modifier="MMB", boundary=10.0, internal=False)
    assert hole.shift == pytest.approx(0.06) and pin.shift == pytest.approx(0.04)
    assert cyl("B", (0, 0, 0), (0, 0, 1), radius=5.03).shift == 0.0
