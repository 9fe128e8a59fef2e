"""Control charts and capability against textbook data sets with published limits, and the constants table
against the distribution of the range of normal samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology import spc

# R qcc `pistonrings` (Montgomery, Introduction to SQC, piston ring inside diameters, mm): the 25 trial
# subgroups of 5. Published by qcc: centre 74.00118, LCL 73.98805, UCL 74.01431; R chart centre 0.02276,
# UCL 0.04812; against 73.95 / 74.05 mm, Cp 1.70, Cpk 1.66.
PISTON_RINGS = [
    (74.030, 74.002, 74.019, 73.992, 74.008), (73.995, 73.992, 74.001, 74.011, 74.004),
    (73.988, 74.024, 74.021, 74.005, 74.002), (74.002, 73.996, 73.993, 74.015, 74.009),
    (73.992, 74.007, 74.015, 73.989, 74.014), (74.009, 73.994, 73.997, 73.985, 73.993),
    (73.995, 74.006, 73.994, 74.000, 74.005), (73.985, 74.003, 73.993, 74.015, 73.988),
    (74.008, 73.995, 74.009, 74.005, 74.004), (73.998, 74.000, 73.990, 74.007, 73.995),
    (73.994, 73.998, 73.994, 73.995, 73.990), (74.004, 74.000, 74.007, 74.000, 73.996),
    (73.983, 74.002, 73.998, 73.997, 74.012), (74.006, 73.967, 73.994, 74.000, 73.984),
    (74.012, 74.014, 73.998, 73.999, 74.007), (74.000, 73.984, 74.005, 73.998, 73.996),
    (73.994, 74.012, 73.986, 74.005, 74.007), (74.006, 74.010, 74.018, 74.003, 74.000),
    (73.984, 74.002, 74.003, 74.005, 73.997), (74.000, 74.010, 74.013, 74.020, 74.003),
    (73.988, 74.001, 74.009, 74.005, 73.996), (74.004, 73.999, 73.990, 74.006, 74.009),
    (74.010, 73.989, 73.990, 74.009, 74.014), (74.015, 74.008, 73.993, 74.000, 74.010),
    (73.982, 73.984, 73.995, 74.017, 74.013),
]
# NIST/SEMATECH e-Handbook 6.3.2.2 (flow rate, individuals): mean 50.81, MR-bar 1.8778, UCL 55.8041,
# LCL 45.8159, MR UCL 6.1349.
FLOW_RATE = [49.6, 47.6, 49.9, 51.3, 47.8, 51.2, 52.6, 52.4, 53.6, 52.1]
# Montgomery, Introduction to SQC, viscosity of aircraft primer paint (individuals): x-bar 33.52, MR-bar 0.48,
# UCL 34.80, LCL 32.24, MR UCL 1.57.
VISCOSITY = [33.75, 33.05, 34.00, 33.81, 33.46, 34.02, 33.68, 33.27, 33.49, 33.20, 33.62, 33.00, 33.54, 33.12,
             33.84]


def test_xbar_r_chart_of_the_piston_rings_has_the_published_limits():
    c = spc.xbar_r_chart(np.ravel(PISTON_RINGS), 5)
    assert c.kind == "X-bar-R" and len(c.points) == 25
    assert c.location.centre == pytest.approx(74.00118, abs=5e-6)
    assert c.location.lower == pytest.approx(73.98805, abs=1e-5)
    assert c.location.upper == pytest.approx(74.01431, abs=1e-5)
    assert c.spread.centre == pytest.approx(0.02276, abs=5e-6)
    assert c.spread.upper == pytest.approx(0.04812, abs=1e-5) and c.spread.lower == 0.0
    assert c.out_of_control == [] and c.spread_out_of_control == []
    cap = spc.capability(np.ravel(PISTON_RINGS), 73.95, 74.05, c.sigma)
    assert round(cap.cp, 2) == 1.70 and round(cap.cpk, 2) == 1.66


def test_an_incomplete_last_subgroup_is_left_out_and_a_shift_is_flagged():
    x = list(np.ravel(PISTON_RINGS)) + [74.02, 74.03, 74.025]  # three parts of a 26th subgroup
    assert len(spc.xbar_r_chart(x, 5).points) == 25
    shifted = list(np.ravel(PISTON_RINGS)) + [74.03] * 5
    c = spc.xbar_r_chart(shifted, 5)
    assert c.out_of_control == [25]


def test_individuals_charts_have_the_published_limits():
    c = spc.individuals_chart(FLOW_RATE)
    assert c.location.centre == pytest.approx(50.81, abs=1e-9)
    assert c.spread.centre == pytest.approx(1.8778, abs=5e-5)
    assert c.location.upper == pytest.approx(55.8041, abs=5e-4)
    assert c.location.lower == pytest.approx(45.8159, abs=5e-4)
    assert c.spread.upper == pytest.approx(6.1349, abs=5e-4)
    v = spc.individuals_chart(VISCOSITY)
    assert (round(v.location.centre, 2), round(v.spread.centre, 2)) == (33.52, 0.48)
    assert (round(v.location.upper, 2), round(v.location.lower, 2), round(v.spread.upper, 2)) == (34.80, 32.24, 1.57)
    assert v.out_of_control == [] and len(v.spread_points) == 14


def test_capability_of_one_sided_and_degenerate_characteristics():
    x = [0.010, 0.012, 0.011, 0.013, 0.009, 0.012]
    one = spc.capability(x, None, 0.02)
    assert one.cp is None and one.pp is None
    assert one.cpk == pytest.approx((0.02 - np.mean(x)) / (3 * one.sigma_within))
    flat = spc.capability([5.0, 5.0, 5.0], 4.9, 5.1)
    assert flat.cp is None and flat.cpk is None  # no spread: no index, not infinity
    assert spc.out_of_tolerance([1.0, 1.2, 0.7, 1.0], 0.8, 1.1) == [1, 2]
    assert spc.out_of_tolerance([0.03, 0.01], None, 0.02) == [0]


def test_bad_input_is_a_sentence():
    with pytest.raises(spc.SpcError, match="at least 2 values, there is 1"):
        spc.individuals_chart([1.0])
    with pytest.raises(spc.SpcError, match="choose 2 to 25"):
        spc.xbar_r_chart(range(100), 30)
    with pytest.raises(spc.SpcError, match="not a number"):
        spc.individuals_chart([1.0, float("nan")])


def test_the_constants_are_the_moments_of_the_range_of_normal_samples():
    # d2 for every n by quadrature; A2, D3 and D4 follow from the rounded d2 and d3 (to 0.002)
    for n, (d2, d3, A2, D3, D4) in spc.CONSTANTS.items():
        assert round(spc.normal_range_mean(n), 3) == d2, n
        assert abs(3 / (d2 * math.sqrt(n)) - A2) <= 0.0011, n
        assert abs(1 + 3 * d3 / d2 - D4) <= 0.002 and abs(max(0.0, 1 - 3 * d3 / d2) - D3) <= 0.002, n
    # d3 of two values in closed form (|X1 - X2| is half-normal with sigma sqrt 2), of five by quadrature
    assert round(math.sqrt(2 * (1 - 2 / math.pi)), 3) == spc.CONSTANTS[2][1]
    d2, d3 = spc.normal_range_moments(5)
    assert (round(d2, 3), round(d3, 3)) == spc.CONSTANTS[5][:2]
