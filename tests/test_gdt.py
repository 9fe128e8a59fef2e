"""Geometric tolerances: a known-answer test per characteristic (constructed data with a known value)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from cmm.metrology import gdt
from cmm.metrology.datums import build_drf, datum_from_feature
from cmm.metrology.transform import apply_points, apply_vectors, make_pose, rotation_about_axis

RNG = np.random.default_rng(23)


def planes_drf(pose=np.eye(4)):
    """A|B|C: the three faces of a corner at the origin (bottom z=0, left x=0, front y=0), moved by pose."""
    def p(label, point, normal):
        return datum_from_feature(label, "plane", {"point": apply_points(pose, np.array(point, float)),
                                                   "normal": apply_vectors(pose, np.array(normal, float))})
    return build_drf([p("A", (5, 5, 0), (0, 0, -1)), p("B", (0, 5, 5), (-1, 0, 0)), p("C", (5, 0, 5), (0, -1, 0))])


def ring(center, axis, radius, z_values, n=24, lobes=0, amp=0.0):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    f = np.linalg.svd(np.c_[axis, np.eye(3)].T[:, :3])[2]  # any frame: axes ⊥ axis below
    e1 = np.cross(axis, [1, 0, 0] if abs(axis[0]) < 0.9 else [0, 1, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    del f
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = radius + amp * np.cos(lobes * t)
    return np.array([np.asarray(center) + z * axis + ri * (math.cos(a) * e1 + math.sin(a) * e2)
                     for z in z_values for a, ri in zip(t, r)])


def test_flatness_two_levels():
    xy = RNG.uniform(0, 50, (200, 2))
    z = np.where(np.arange(200) % 2 == 0, 0.0, 0.03)
    r = gdt.form("flatness", np.c_[xy, z], 0.02)
    assert r.value == pytest.approx(0.03, abs=1e-9) and not r.ok and r.drf == ""


def test_circularity_and_cylindricity_of_three_lobes():
    c = gdt.form("circularity", ring((1, 2, 3), (0, 0, 1), 10.0, [0.0], n=90, lobes=3, amp=0.005), 0.02)
    assert c.value == pytest.approx(0.01, abs=1e-6) and c.ok
    cyl = gdt.form("cylindricity", ring((0, 0, 0), (0, 1, 1), 5.0, [0, 10, 20], n=60, lobes=3, amp=0.004), 0.005)
    assert cyl.value == pytest.approx(0.008, abs=1e-5) and not cyl.ok


def test_parallelism_of_a_tilted_face():
    drf = planes_drf()
    L, t = 40.0, math.radians(0.05)
    xy = RNG.uniform(0, L, (100, 2))
    xy[:2, 0] = (0, L)
    pts = np.c_[xy, 10 + xy[:, 0] * math.tan(t)]
    r = gdt.orientation("parallelism", "plane", {}, pts, drf, 0.05)
    assert r.value == pytest.approx(L * math.tan(t), rel=1e-9) and r.drf == "A|B|C"


def test_perpendicularity_of_a_face_and_of_an_axis():
    drf = build_drf([datum_from_feature("A", "plane", {"point": (0, 0, 0), "normal": (0, 0, 1)})])
    H, t = 25.0, math.radians(0.1)
    yz = np.array([(a, b) for a in np.linspace(0, H, 6) for b in np.linspace(0, H, 6)])
    # a face x = z tan t (rotation about A free: the zone turns to fit it)
    pts = np.c_[30 + yz[:, 1] * math.tan(t), yz[:, 0], yz[:, 1]]
    r = gdt.orientation("perpendicularity", "plane", {}, pts, drf, 0.05)
    assert r.value == pytest.approx(H * math.tan(t), rel=1e-6)
    # a bore tilted 0.1 deg from A's normal over 20 mm: the axis leans 20 sin(0.1 deg)
    u = np.array([math.sin(t), 0, math.cos(t)])
    bore = {"point": [5, 5, 0], "direction": u.tolist(), "radius": 4.0}
    pts = ring((5, 5, 0), u, 4.0, [0.0, 20.0])
    r = gdt.orientation("perpendicularity", "cylinder", bore, pts, drf, 0.05)
    assert r.value == pytest.approx(20 * math.sin(t), rel=1e-9) and r.ok


def test_angularity_of_a_face_at_30_degrees():
    drf = build_drf([datum_from_feature("A", "plane", {"point": (0, 0, 0), "normal": (0, 0, 1)})])
    a = math.radians(30.1)  # the face is 0.1 deg off its basic 30 deg to A, and turned about A
    e1 = np.array([math.cos(a), 0, -math.sin(a)])
    turn = rotation_about_axis((0, 0, 1), 0.7)
    L = 30.0
    s = np.array([(a, b) for a in np.linspace(0, L, 7) for b in np.linspace(0, L, 7)])
    pts = (s[:, :1] * e1 + s[:, 1:] * np.array([0, 1.0, 0])) @ turn.T + (3, 4, 5)
    r = gdt.orientation("angularity", "plane", {}, pts, drf, 0.1, angle_deg=30.0)
    assert r.value == pytest.approx(L * math.sin(math.radians(0.1)), rel=1e-6)


def test_position_with_mmc_bonus_in_a_moved_part():
    pose = make_pose(rotation_about_axis((1, 2, 3), 0.4), (100, -50, 20))  # where the part sits on the table
    drf_actual, drf_nominal = planes_drf(pose), planes_drf()
    # the hole: nominal at (20, 15) perpendicular to A; actual 0.03, 0.04 off, diameter 10.06 (limits 10.00-10.10)
    nominal = {"point": [20, 15, 0], "direction": [0, 0, 1], "radius": 5.0}
    axis = apply_vectors(pose, np.array([0, 0, 1.0]))
    actual = {"point": apply_points(pose, np.array([20.03, 15.04, 0])).tolist(), "direction": axis.tolist(),
              "radius": 5.03}
    pts = ring(apply_points(pose, np.array([20.03, 15.04, 0])), axis, 5.03, [-10.0, 0.0])
    rfs = gdt.position("cylinder", actual, nominal, 0.05, drf=drf_actual, nominal_drf=drf_nominal, points=pts)
    assert rfs.value == pytest.approx(0.1, abs=1e-9) and not rfs.ok
    mmc = gdt.position("cylinder", actual, nominal, 0.05, drf=drf_actual, nominal_drf=drf_nominal, points=pts,
                       material="MMC", size_limits=(10.0, 10.1), internal=True)
    assert mmc.bonus == pytest.approx(0.06) and mmc.allowed == pytest.approx(0.11) and mmc.ok
    lmc = gdt.position("cylinder", actual, nominal, 0.05, drf=drf_actual, nominal_drf=drf_nominal, points=pts,
                       material="LMC", size_limits=(10.0, 10.1), internal=True)
    assert lmc.bonus == pytest.approx(0.04) and not lmc.ok
    assert mmc.drf == "A|B|C" and mmc.material == "MMC"


def test_position_of_a_tilted_axis_counts_its_far_end():
    drf = planes_drf()
    t = 0.002  # rad: over 10 mm the axis leans 0.02 mm
    actual = {"point": [20, 15, 0], "direction": [t, 0, 1], "radius": 5.0}
    pts = ring((20, 15, 0), (t, 0, 1), 5.0, [0.0, 10.0])
    r = gdt.position("cylinder", actual, {"point": [20, 15, 0], "direction": [0, 0, 1]}, 0.05, drf=drf,
                     nominal_drf=drf, points=pts)
    assert r.value == pytest.approx(2 * 10 * t / math.sqrt(1 + t * t), rel=1e-6)


def test_position_datum_shift_and_free_rotation():
    a = datum_from_feature("A", "plane", {"point": (0, 0, 0), "normal": (0, 0, 1)})
    # B a bore of 20.04 at MMB 20.00: it may shift the frame by up to 0.02 across it
    b = datum_from_feature("B", "cylinder", {"point": (0, 0, 0), "direction": (0, 0, 1), "radius": 10.02},
                           modifier="MMB", boundary=20.0, internal=True)
    drf = build_drf([a, b])
    assert "Rz" not in drf.constrained
    nominal = {"center": [30, 0, 0], "normal": [0, 0, 1]}
    # 0.05 off radially: 0.02 of it taken by the shift
    r = gdt.position("circle", {"center": [30.05, 0, 0], "normal": [0, 0, 1], "radius": 3}, nominal, 0.1, drf=drf,
                     nominal_drf=drf)
    assert r.value == pytest.approx(2 * 0.03, abs=1e-9) and "datum shift" in r.note
    # turned about B by any angle: the rotation is free (no datum C), only the radial error counts
    p = apply_points(make_pose(rotation_about_axis((0, 0, 1), 0.3)), np.array([30.0, 0, 0]))
    r = gdt.position("circle", {"center": p.tolist(), "normal": [0, 0, 1], "radius": 3}, nominal, 0.1, drf=drf,
                     nominal_drf=drf)
    assert r.value == pytest.approx(0.0, abs=1e-9)
    # a sphere: spherical zone
    s = gdt.position("sphere", {"center": [30.01, 0.02, 0.02], "radius": 3}, {"center": [30, 0, 0]}, 0.1)
    assert s.value == pytest.approx(2 * 0.03, abs=1e-9) and "spherical" in s.note


def test_coaxiality_and_concentricity():
    drf = build_drf([datum_from_feature("A", "cylinder", {"point": (0, 0, 0), "direction": (0, 0, 1), "radius": 5})])
    # the toleranced axis from (0.01, 0, 30) to (0.03, 0, 50): its far end is 0.03 off the datum axis
    g = {"point": [0.01, 0, 30], "direction": [0.001, 0, 1], "radius": 8}
    pts = ring((0.01, 0, 30), (0.001, 0, 1), 8.0, [0.0, 20.0])
    r = gdt.coaxiality("coaxiality", "cylinder", g, drf, 0.05, points=pts)
    assert r.value == pytest.approx(2 * (0.01 + 20 * 0.001 / math.sqrt(1 + 1e-6)), rel=1e-6)
    c = gdt.coaxiality("concentricity", "circle", {"center": [0.0, 0.004, 12], "normal": [0, 0, 1], "radius": 8},
                       drf, 0.01)
    assert c.value == pytest.approx(0.008) and c.ok
    with pytest.raises(gdt.GdtError, match="needs a datum axis"):
        gdt.coaxiality("coaxiality", "cylinder", g,
                       build_drf([datum_from_feature("A", "plane", {"point": (0, 0, 0), "normal": (0, 0, 1)})]), 0.05)


def test_runout_of_an_eccentric_diameter():
    drf = build_drf([datum_from_feature("A", "cylinder", {"point": (0, 0, 0), "direction": (0, 0, 1), "radius": 5})])
    e = 0.02
    sec1 = ring((e, 0, 0), (0, 0, 1), 10.0, [10.0], n=360)
    sec2 = ring((e, 0, 0), (0, 0, 1), 10.005, [20.0], n=360)  # the diameter is 0.01 larger further up
    circ = gdt.runout("circular runout", np.r_[sec1, sec2], drf, 0.05)
    assert circ.value == pytest.approx(2 * e, abs=1e-9)  # the radius ranges over 2e in each section
    total = gdt.runout("total runout", np.r_[sec1, sec2], drf, 0.05)
    assert total.value == pytest.approx(2 * e + 0.005, abs=1e-9)
    # axial runout of a face tilted 0.001 rad across 2 x 15 mm
    face = np.array([[15 * math.cos(a), 15 * math.sin(a), 40 + 0.001 * 15 * math.cos(a)]
                     for a in np.linspace(0, 2 * np.pi, 72, endpoint=False)])
    ax = gdt.runout("circular runout", face, drf, 0.05, direction="axial")
    assert ax.value == pytest.approx(2 * 0.015, abs=1e-9)


def box_mesh():
    return trimesh.creation.box(extents=(40, 30, 20), transform=make_pose(None, (20, 15, 10)))  # corner at 0


def test_profile_of_a_surface_with_and_without_datums():
    mesh = box_mesh()
    xy = np.repeat(np.c_[RNG.uniform(2, 38, 20), RNG.uniform(2, 28, 20)], 2, axis=0)
    z = 20 + np.where(np.arange(40) % 2 == 0, 0.01, -0.02)  # top face: each spot once +0.01, once -0.02
    pts = np.c_[xy, z]
    drf = planes_drf()
    with_datums = gdt.profile("profile of a surface", pts, mesh, np.eye(4), 0.05, drf=drf, nominal_drf=drf)
    assert with_datums.value == pytest.approx(0.04, abs=1e-9) and with_datums.drf == "A|B|C"
    form_only = gdt.profile("profile of a surface", pts, mesh, np.eye(4), 0.05)
    assert form_only.value == pytest.approx(0.03, abs=1e-6)
    # one point 0.03 high among many on the mesh: the minimum zone is 0.03 (least squares would leave more)
    bump = np.c_[xy, np.full(len(xy), 20.0)]
    bump[7, 2] += 0.03
    assert gdt.profile("profile of a surface", bump, mesh, np.eye(4), 0.05).value == pytest.approx(0.03, abs=1e-7)
    # a datum A alone: the top's height above A is fixed, its in-plane position free
    only_a = build_drf([datum_from_feature("A", "plane", {"point": (5, 5, 0), "normal": (0, 0, -1)})])
    assert gdt.profile("profile of a surface", pts + (0.3, -0.2, 0), mesh, np.eye(4), 0.05, drf=only_a,
                       nominal_drf=only_a).value == pytest.approx(0.04, abs=1e-6)
    # the actual datum A is its hits' centroid, the nominal's point elsewhere on the face: the frames agree
    # along what A leaves free, so the free fit starts where the part is
    a_nominal = build_drf([datum_from_feature("A", "plane", {"point": (35, 25, 0), "normal": (0, 0, -1)})])
    assert np.allclose(a_nominal.origin, only_a.origin)
    assert gdt.profile("profile of a surface", pts, mesh, np.eye(4), 0.05, drf=only_a,
                       nominal_drf=a_nominal).value == pytest.approx(0.04, abs=1e-6)
    with pytest.raises(gdt.GdtError, match="profile tolerance needs the part mesh"):
        gdt.profile("profile of a surface", pts, None, np.eye(4), 0.05)


def test_profile_of_a_line_in_a_section():
    mesh = box_mesh()
    # a section y = 10 across the top and the right face; the right face is 0.015 out
    top = np.c_[np.linspace(2, 38, 10), np.full(10, 10.0), np.full(10, 20.0)]
    side = np.c_[np.full(6, 40.015), np.full(6, 10.0), np.linspace(2, 18, 6)]
    drf = planes_drf()
    r = gdt.profile("profile of a line", np.r_[top, side], mesh, np.eye(4), 0.02, drf=drf, nominal_drf=drf)
    assert r.value == pytest.approx(0.03, abs=1e-9) and not r.ok
    # without datums the section best-fits in its plane: the step is taken up by a shift along x
    free = gdt.profile("profile of a line", np.r_[top, side], mesh, np.eye(4), 0.02)
    assert free.value == pytest.approx(0.0, abs=1e-6)


def test_bad_input_is_explained():
    with pytest.raises(gdt.GdtError, match="coordinates too large"):
        gdt.form("flatness", [[1e308, 0, 0], [0, 1, 0], [0, 0, 1]], 0.01)
    with pytest.raises(gdt.GdtError, match="tolerance must be a positive"):
        gdt.form("flatness", [[1, 0, 0], [0, 1, 0], [0, 0, 1]], -1)
    with pytest.raises(gdt.GdtError, match="needs a datum that sets a direction"):
        gdt.orientation("parallelism", "plane", {}, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], None, 0.01)
    with pytest.raises(gdt.GdtError, match="needs a feature of size"):
        gdt.position("point", {"point": [0, 0, 0]}, {"point": [0, 0, 0]}, 0.1, material="MMC")


def test_profile_with_an_unequally_disposed_zone():
    """ISO 1101 UZ: the zone's middle offset o from the nominal surface (+ outside the material); the value is
    twice the largest |d - o|. Top-face points at +0.01 and -0.02 (located by A|B|C): 0.04 equally disposed,
    0.03 about -0.005 (the zone -0.025 .. +0.005 of 0.04 holds them), 0.06 about +0.01. A section whose side is
    0.015 out: 0.015 about +0.0075."""
    mesh = box_mesh()
    xy = np.repeat(np.c_[RNG.uniform(2, 38, 20), RNG.uniform(2, 28, 20)], 2, axis=0)
    pts = np.c_[xy, 20 + np.where(np.arange(40) % 2 == 0, 0.01, -0.02)]
    drf = planes_drf()
    def value(offset, tol=0.04, points=pts, ch="profile of a surface"):
        return gdt.profile(ch, points, mesh, np.eye(4), tol, drf=drf, nominal_drf=drf, offset=offset)
    assert value(0.0).value == pytest.approx(0.04, abs=1e-9)
    inside = value(-0.005)
    assert inside.value == pytest.approx(0.03, abs=1e-9) and inside.ok and "UZ" in inside.note
    assert "-0.0250 .. +0.0150" in inside.note and "deviations -0.0200 .. +0.0100" in inside.note
    assert value(0.01, tol=0.06).value == pytest.approx(0.06, abs=1e-9)
    top = np.c_[np.linspace(2, 38, 10), np.full(10, 10.0), np.full(10, 20.0)]
    side = np.c_[np.full(6, 40.015), np.full(6, 10.0), np.linspace(2, 18, 6)]
    assert value(0.0075, 0.02, np.r_[top, side], "profile of a line").value == pytest.approx(0.015, abs=1e-9)
    # without datums the fit minimises the largest |d - o|: a plane's points take up any offset by moving
    flat = np.c_[xy, np.full(len(xy), 20.0)]
    assert gdt.profile("profile of a surface", flat, mesh, np.eye(4), 0.04, offset=0.01).value == pytest.approx(
        0.0, abs=1e-6)
    with pytest.raises(gdt.GdtError, match="moves the profile zone of 0.04 off the nominal surface"):
        value(0.03)


def test_unequal_profile_zone_definitions_and_frame_text():
    from cmm.metrology.gdt_eval import MeasuredFeature, check_definition, evaluate, tolerance_text

    d = check_definition({"characteristic": "profile of a surface", "feature": 1, "tolerance": 0.04,
                          "datums": [], "offset": -0.005})
    assert d["offset"] == -0.005 and tolerance_text(d) == "⌓ 0.0400 UZ-0.0050"
    assert "offset" not in check_definition({**d, "offset": 0})
    with pytest.raises(gdt.GdtError, match="applies to a profile tolerance only"):
        check_definition({"characteristic": "flatness", "feature": 1, "tolerance": 0.04, "offset": 0.01})
    with pytest.raises(gdt.GdtError, match="is a number in mm"):
        check_definition({**d, "offset": "high"})
    xy = np.repeat(np.c_[RNG.uniform(2, 38, 20), RNG.uniform(2, 28, 20)], 2, axis=0)
    top = np.c_[xy, 20 + np.where(np.arange(40) % 2 == 0, 0.01, -0.02)]
    corner = {1: MeasuredFeature("top", "plane", {"point": [20, 15, 20], "normal": [0, 0, 1]}, None, top)}
    for label, (point, normal) in zip("ABC", (((5, 5, 0), (0, 0, -1)), ((0, 5, 5), (-1, 0, 0)),
                                             ((5, 0, 5), (0, -1, 0)))):
        nominal = {"kind": "plane", "point": list(point), "normal": list(normal)}
        corner[ord(label)] = MeasuredFeature(label, "plane", nominal, nominal,
                                             np.array([point], float))
    datums = {x: {"label": x, "feature": ord(x)} for x in "ABC"}
    ((_, c),) = evaluate([{**d, "datums": ["A", "B", "C"]}], datums, corner, box_mesh(), np.eye(4))
    assert c.actual == pytest.approx(0.03, abs=1e-9) and c.ok and "UZ" in c.note
