import numpy as np
import pytest

from cmm.metrology.compensation import PretravelModel, compensate, pretravel_basis


def test_thesis_single_axis_formula_is_a_special_case():
    # eq. 1.6: probing in -x, M_x = x(t+dt) + ed_x - r
    x_trigger, ed_x, r = 123.456, 0.004, 1.5
    m = compensate([x_trigger, 10.0, 20.0], [-1.0, 0.0, 0.0], r, ed_x)
    assert m[0] == pytest.approx(x_trigger + ed_x - r, abs=1e-12)
    assert m[1:] == pytest.approx([10.0, 20.0], abs=1e-12)


def test_radius_and_pretravel_along_a_supplied_normal():
    # approach 10 degrees off the true normal (-z): offsetting along the true normal is exact
    a = np.radians(10)
    u = np.array([np.sin(a), 0, -np.cos(a)])
    r, delta = 1.0, 0.003
    contact_centre = np.array([5.0, 0.0, 1.0])  # tip centre touching the plane z=0
    trigger = contact_centre + delta * u
    exact = compensate(trigger, u, r, delta, normal=[0, 0, 1])  # sense is corrected to into the material
    assert exact == pytest.approx([5.0, 0.0, 0.0], abs=1e-12)
    naive = compensate(trigger, u, r, delta)
    # along u the error is r(1 - cos a) along the normal (15 um at 10 degrees) and r sin a along the surface
    assert naive[2] == pytest.approx(1.0 - np.cos(a), abs=1e-12)
    assert naive[0] - 5.0 == pytest.approx(np.sin(a), abs=1e-12)


def test_directional_model_fits_and_evaluates_three_lobes():
    phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    dirs = np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
    dirs = np.vstack([dirs, [[0, 0, -1]]])
    truth = 0.002 + 0.0015 * np.cos(3 * np.arctan2(dirs[:, 1], dirs[:, 0])) * np.hypot(dirs[:, 0], dirs[:, 1])
    truth[-1] = 0.005
    model = PretravelModel.fit(dirs, truth)
    assert model(dirs) == pytest.approx(truth, abs=1e-12)
    assert model.is_directional and "s_cos3" in model.describe()
    assert not PretravelModel.constant(0.002).is_directional
    assert pretravel_basis(dirs).shape == (25, 6)


def test_bad_directions_refused():
    with pytest.raises(ValueError, match="finite"):
        compensate([0, 0, 0], [0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="finite"):
        compensate([0, 0, 0], [np.nan, 0, 1], 1.0)
