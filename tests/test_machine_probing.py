"""Probing cycles on the simulated CMM: hits against the true geometry the simulator holds."""

import numpy as np
import pytest

from cmm.machine.probing import SurfaceNotFound
from cmm.metrology.compensation import PretravelModel

COUNT = 0.002  # mm


def matched_pretravel(sim) -> PretravelModel:
    """The station's model of the simulated probe, exact for horizontal and vertical approaches."""
    p = sim.settings.probe
    return PretravelModel({"const": p.pretravel_xy, "s_cos3": p.pretravel_lobe, "z2": p.pretravel_z - p.pretravel_xy})


def part_to_machine(sim, xyz):
    return (sim.settings.part_pose @ np.append(xyz, 1.0))[:3]


def test_hits_on_the_top_face_lie_on_the_true_surface(sim_machine):
    sim, m, prober = sim_machine
    prober.settings.pretravel = matched_pretravel(sim)
    for xy in [(20, 15), (60, 75), (110, 10)]:  # around the bore, boss, dome and cone
        nominal = part_to_machine(sim, [*xy, 40.0])
        hit = prober.probe(nominal, [0, 0, -1], clearance_z=70.0).wait()
        assert abs(hit.point[2] - 40.0) <= 2 * COUNT
        assert hit.mode == "programmed" and hit.speed == m.config.speeds.probing
        assert hit.counts[2] == m.config.axes[2].to_counts(hit.machine[2])
    assert not m.state.probe_triggered  # retracted and re-seated


def test_hits_on_the_reference_sphere_lie_on_it(sim_machine):
    sim, m, prober = sim_machine
    prober.settings.pretravel = matched_pretravel(sim)
    c = np.array(sim.settings.sphere_centre)
    R = sim.settings.sphere_diameter / 2
    dirs = [np.array([np.cos(a), np.sin(a), 0.0]) for a in np.radians([0, 50, 130, 200, 290])] + [np.array([0, 0, 1.0])]
    for n in dirs:
        hit = prober.probe(c + R * n, -n, clearance_z=c[2] + R + 5).wait()
        assert abs(np.linalg.norm(np.array(hit.point) - c) - R) <= 2 * COUNT


def test_ten_hits_at_one_spot_repeat_within_one_count(sim_machine):
    sim, m, prober = sim_machine
    nominal = part_to_machine(sim, [40.0, 70.0, 40.0])
    zs = [prober.probe(nominal, [0, 0, -1]).wait().counts[2] for _ in range(10)]
    assert max(zs) - min(zs) <= 2  # +-1 count about the middle


def test_surface_not_found_in_the_air(sim_machine):
    _, m, prober = sim_machine
    hits = []
    prober.listeners.append(hits.append)
    with pytest.raises(SurfaceNotFound, match="surface not found"):
        prober.probe([450.0, 50.0, 150.0], [0, 0, -1]).wait()
    assert hits == []
    assert not m.busy


def test_manual_hit_while_jogging_takes_the_motion_direction(sim_machine):
    sim, m, prober = sim_machine
    above = part_to_machine(sim, [60.0, 40.0, 43.0])
    m.move_to(above).wait()
    hits = []
    prober.listeners.append(hits.append)
    for _ in range(200):
        prober.jog_probe([0.0, 0.0, -1.0])
        m.run_for(0.05)
        if hits:
            break
    m.run_for(1.5)  # back-off
    assert len(hits) == 1
    hit = hits[0]
    assert hit.mode == "manual" and hit.approach == pytest.approx((0, 0, -1))
    assert abs(hit.point[2] - 40.0) <= 3 * COUNT  # nominal pre-travel model: constant 0
    assert m.position[2] > hit.machine[2] + 0.5
    assert not m.state.probe_triggered


def test_bad_probe_requests_are_refused(sim_machine):
    _, _, prober = sim_machine
    with pytest.raises(Exception, match="approach direction"):
        prober.probe([100, 100, 40], [0, 0, 0])
    with pytest.raises(Exception, match="outside the travel"):
        prober.probe([100, 100, 299.5], [0, 0, 1])
