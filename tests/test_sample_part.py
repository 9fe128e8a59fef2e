"""The sample part and reference sphere: watertight, features where the mesh is."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.metrology.mesh import signed_deviation
from cmm.sim.sample_part import reference_sphere, sample_part


def _surface_points(feature, n=64):
    """Points on the nominal surface of a feature, inside the exposed region."""
    p = feature.params
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    if feature.kind == "cylinder":
        z = p["point"][2] + p["length"] * np.linspace(0.1, 0.9, n)
        return np.c_[p["point"][0] + p["radius"] * np.cos(t), p["point"][1] + p["radius"] * np.sin(t), z]
    if feature.kind == "sphere":  # a ring 30 deg below the pole
        c, r = p["center"], p["radius"]
        return c + r * np.c_[np.sin(0.5) * np.cos(t), np.sin(0.5) * np.sin(t), np.full(n, np.cos(0.5))]
    if feature.kind == "cone":  # ring at 6 mm from the base (z 46)
        h = p["apex"][2] - 46.0
        rho = h * np.tan(p["half_angle"])
        return np.c_[p["apex"][0] + rho * np.cos(t), p["apex"][1] + rho * np.sin(t), np.full(n, 46.0)]
    raise AssertionError(feature.kind)


def test_sample_part_is_watertight_and_sized():
    mesh, features = sample_part()
    assert mesh.is_watertight and mesh.is_volume
    assert len(mesh.faces) < 200_000
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [120, 80, 55]], atol=1e-12)
    assert {"top_plane", "bore", "boss", "dome", "cone"} <= set(features)
    assert features["bore"].params["bore"] and not features["boss"].params["bore"]


@pytest.mark.parametrize("name", ["bore", "boss", "dome", "cone"])
def test_nominal_surfaces_lie_on_the_mesh(name):
    mesh, features = sample_part()
    dev = signed_deviation(mesh, _surface_points(features[name]))
    # chordal error: the facets are inscribed, so the mesh has less material than a convex
    # nominal surface (true points read +) and more material inside a bore (true points read -)
    assert np.abs(dev.deviations).max() < 5e-3
    if name == "bore":
        assert dev.deviations.max() <= 1e-9
    else:
        assert dev.deviations.min() >= -1e-9


def test_planes_lie_on_the_mesh():
    mesh, features = sample_part()
    for name in ("top_plane", "front", "left", "boss_top", "cone_top"):
        f = features[name]
        dev = signed_deviation(mesh, [f.params["point"]])
        assert abs(dev.deviations[0]) < 1e-12, name
        np.testing.assert_allclose(dev.normals[0], f.params["normal"], atol=1e-12)


def test_cached_calls_return_independent_copies():
    a, fa = sample_part()
    a.apply_translation((5.0, 0.0, 0.0))
    fa["bore"].params["radius"] = 1.0
    b, fb = sample_part()
    assert b.bounds[0, 0] == 0.0 and fb["bore"].params["radius"] == 15.0


def test_reference_sphere():
    mesh, features = reference_sphere()
    s = features["sphere"].params
    assert mesh.is_watertight
    assert s["radius"] == 12.5
    np.testing.assert_allclose(s["center"], [0, 0, 52.5])
    v = mesh.vertices[mesh.vertices[:, 2] > 50.0]
    assert np.abs(np.linalg.norm(v - s["center"], axis=1) - 12.5).max() < 1e-9
