"""Home capture: a tick hook drives LIMIT1 at a known plant position (the probe model's way)."""

from __future__ import annotations

import pytest

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork
from test_sim_helpers import ITEMS, Host

VEL = c.velocity_to_fixed(20, 500)  # 5.12 counts per tick
ACC = c.acceleration_to_fixed(800, 500)
TRIGGER_AT = 3000.0  # counts


class Probe:
    """Raises LIMIT1 of modules[0] on the first tick the carriage passes TRIGGER_AT."""

    def __init__(self) -> None:
        self.count_at_trigger: int | None = None
        self.tick: int | None = None

    def __call__(self, net: SimNetwork, tick: int) -> None:
        plant = net.plants[0]
        if self.count_at_trigger is None and plant.x >= TRIGGER_AT:
            plant.set_inputs(limit1=True)
            self.count_at_trigger = plant.count
            self.tick = tick


def _probe_move(action: int) -> tuple[Host, Probe, c.Status]:
    net = SimNetwork(1)
    probe = Probe()
    net.add_tick_hook(probe)
    host = Host(net)
    host.init()
    s = host.cmd(c.set_homing(1, c.ON_LIMIT1 | action))
    assert s.home_in_progress
    host.cmd(c.load_traj(1, position=10000, velocity=VEL, acceleration=ACC))
    host.wait_done(1, limit_s=5)
    host.settle(0.2)
    return host, probe, host.cmd(c.read_stat(1, ITEMS | c.SEND_HOME | c.SEND_VEL), ITEMS | c.SEND_HOME | c.SEND_VEL)


@pytest.mark.parametrize("action", [c.HOME_STOP_ABRUPT, c.HOME_STOP_SMOOTH, c.HOME_MOTOR_OFF])
def test_capture_latches_count_of_the_trigger_tick(action: int):
    host, probe, s = _probe_move(action)
    assert probe.count_at_trigger is not None
    assert s.home == probe.count_at_trigger  # exactly the encoder count on that tick
    assert not s.home_in_progress and s.status & c.LIMIT1
    assert s.velocity == 0
    overtravel = s.position - s.home
    if action == c.HOME_STOP_ABRUPT:
        assert s.aux & c.AUX_SERVO_ON and 0 <= overtravel < 30
    elif action == c.HOME_STOP_SMOOTH:
        v, a = VEL / 65536, ACC / 65536
        assert s.aux & c.AUX_SERVO_ON and abs(overtravel - v * v / (2 * a)) < 25
    else:
        assert not s.aux & c.AUX_SERVO_ON and 0 < overtravel < 200  # coasted


def test_no_capture_without_input_change():
    net = SimNetwork(1)
    host = Host(net)
    host.init()
    host.cmd(c.set_homing(1, c.ON_LIMIT2 | c.HOME_STOP_ABRUPT))
    host.cmd(c.load_traj(1, position=2000, velocity=VEL, acceleration=ACC))
    s = host.wait_done(1)
    assert s.home_in_progress and abs(s.position - 2000) <= 1


def test_capture_on_position_error():
    net = SimNetwork(1)
    host = Host(net)
    host.init()
    host.cmd(c.set_homing(1, c.ON_POS_ERR))
    net.plants[0].set_blocked(True)
    host.cmd(c.load_traj(1, position=5000, velocity=VEL, acceleration=ACC))
    host.port.sleep(0.5)
    s = host.cmd(c.read_stat(1, ITEMS | c.SEND_HOME), ITEMS | c.SEND_HOME)
    assert s.pos_error and not s.home_in_progress and abs(s.home) <= 1


def test_limit_pins_as_outputs_via_io_ctrl():
    host = Host(SimNetwork(1))
    host.init()
    s = host.cmd(c.io_ctrl(1, c.IO_LIMIT1_OUT | c.IO_LIMIT2_IN))  # LIMIT1 output high
    assert s.status & c.LIMIT1 and not s.status & c.LIMIT2
    host.net.set_inputs(0, limit2=True)
    assert host.nop(1).status & c.LIMIT2
