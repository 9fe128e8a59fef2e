"""Profiles, control law, stops and protections of the simulated modules (bytes only)."""

from __future__ import annotations

import math

import pytest

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS
from test_sim_helpers import ITEMS, Host

ALL = ITEMS | c.SEND_VEL | c.SEND_AD | c.SEND_HOME
VEL = c.velocity_to_fixed(40, 500)  # 10.24 counts/tick
ACC = c.acceleration_to_fixed(800, 500)


@pytest.fixture
def host() -> Host:
    h = Host(SimNetwork(3))
    h.init()
    return h


def _expected_ticks(d: int, v: int, a: int) -> float:
    v, a = v / 65536, a / 65536
    return d / v + v / a if d >= v * v / a else 2 * math.sqrt(d / a)


@pytest.mark.parametrize("distance", [20000, -20000, 1000, 7, 1])
def test_trapezoid_reaches_goal_in_profile_time(host: Host, distance: int):
    t0 = host.port.now()
    host.cmd(c.load_traj(1, position=distance, velocity=VEL, acceleration=ACC))
    host.wait_done(1)
    ticks = (host.port.now() - t0) / 0.000512
    assert abs(ticks - _expected_ticks(abs(distance), VEL, ACC)) <= 3
    host.settle(0.02)
    s = host.nop(1)
    assert abs(s.position - distance) <= 1
    assert s.aux & c.AUX_ACCEL_DONE and s.aux & c.AUX_SLEW_DONE and s.aux & c.AUX_SERVO_ON


def test_profile_flags_during_trapezoid(host: Host):
    host.cmd(c.load_traj(1, position=20000, velocity=VEL, acceleration=ACC))
    s = host.nop(1)
    assert not s.move_done and not s.aux & c.AUX_ACCEL_DONE  # accelerating
    host.port.sleep(0.2)  # accel lasts 0.05 s; slewing now
    s = host.nop(1)
    assert s.aux & c.AUX_ACCEL_DONE and not s.aux & c.AUX_SLEW_DONE and not s.move_done


def test_velocity_mode_reaches_and_holds_speed_both_ways(host: Host):
    host.cmd(c.load_traj(2, velocity=VEL, acceleration=ACC, velocity_mode=True))
    s = host.wait_done(2)
    host.port.sleep(0.1)
    s = host.cmd(c.read_stat(2, c.SEND_VEL), c.SEND_VEL)
    assert s.move_done and s.velocity in (9, 10, 11)
    host.cmd(c.load_traj(2, velocity=VEL, acceleration=ACC, velocity_mode=True, reverse=True))
    host.wait_done(2)
    host.port.sleep(0.1)
    assert host.cmd(c.read_stat(2, c.SEND_VEL), c.SEND_VEL).velocity in (-9, -10, -11)


def test_pwm_mode_drives_open_loop(host: Host):
    host.cmd(c.load_traj(1, pwm=100, servo=False))
    host.port.sleep(0.2)
    s = host.cmd(c.read_stat(1, ITEMS | c.SEND_VEL), ITEMS | c.SEND_VEL)
    assert not s.aux & c.AUX_SERVO_ON and s.move_done
    assert 6 <= s.velocity <= 8  # about 28 mm/s at 100/255 of 24 V
    host.cmd(c.load_traj(1, pwm=100, servo=False, reverse=True))
    host.port.sleep(0.2)
    assert host.cmd(c.read_stat(1, c.SEND_VEL), c.SEND_VEL).velocity <= -6


def test_amplifier_disabled_means_no_motion():
    h = Host(SimNetwork(1))
    h.init()
    h.cmd(c.stop_motor(1, c.STOP_ABRUPT))  # AMP_EN low
    h.cmd(c.load_traj(1, position=5000, velocity=VEL, acceleration=ACC))
    h.port.sleep(0.05)
    assert abs(h.nop(1).position) <= 1


def test_group_start_move_starts_all_axes_on_the_same_tick(host: Host):
    for a in (1, 2, 3):
        host.cmd(c.set_addr(a, a, 0x80, leader=a == 1))
        host.cmd(c.load_traj(a, position=30000, velocity=VEL, acceleration=ACC, start_now=False))
    host.port.sleep(0.01)
    assert all(abs(host.nop(a).position) <= 1 for a in (1, 2, 3))  # buffered
    host.cmd(c.start_move(0x80), ITEMS)  # the leader answers with its own items
    host.port.sleep(0.1)
    host.cmd(c.save_as_home(0x80), ITEMS)  # latch all three on one tick
    homes = [host.cmd(c.read_stat(a, c.SEND_HOME), c.SEND_HOME).home for a in (1, 2, 3)]
    assert homes[0] > 1000 and homes[0] == homes[1] == homes[2]


def _moving(host: Host, addr: int = 1) -> int:
    host.cmd(c.load_traj(addr, velocity=VEL, acceleration=ACC, velocity_mode=True))
    host.wait_done(addr)
    return host.nop(addr).position


def test_stop_abrupt(host: Host):
    p0 = _moving(host)
    host.cmd(c.stop_motor(1, c.AMP_ENABLE | c.STOP_ABRUPT))
    host.settle(0.1)
    s = host.cmd(c.read_stat(1, ITEMS | c.SEND_VEL), ITEMS | c.SEND_VEL)
    assert s.move_done and s.velocity == 0 and s.aux & c.AUX_SERVO_ON
    assert 0 <= s.position - p0 - 10 < 40  # command set to where it was; braking overshoot only


def test_stop_smooth_decelerates_at_loaded_acceleration(host: Host):
    p0 = _moving(host)
    host.cmd(c.stop_motor(1, c.AMP_ENABLE | c.STOP_SMOOTH))
    assert not host.nop(1).move_done
    host.wait_done(1)
    host.settle(0.05)
    v, a = VEL / 65536, ACC / 65536
    expected = v * v / (2 * a)  # counts past the stop command
    assert abs(host.nop(1).position - p0 - expected) < 0.05 * expected + 40


def test_motor_off_coasts_with_servo_off(host: Host):
    p0 = _moving(host)
    host.cmd(c.stop_motor(1, c.AMP_ENABLE | c.MOTOR_OFF))
    host.settle(0.3)
    s = host.cmd(c.read_stat(1, ITEMS | c.SEND_VEL), ITEMS | c.SEND_VEL)
    assert s.move_done and not s.aux & c.AUX_SERVO_ON and s.velocity == 0
    assert s.position > p0 + 20  # it coasted to rest against friction


def test_stop_here(host: Host):
    host.cmd(c.stop_motor(1, c.AMP_ENABLE | c.STOP_HERE, 150))
    host.settle(0.1)
    assert abs(host.nop(1).position - 150) <= 1


def test_position_error_limit_disables_servo(host: Host):
    host.net.plants[0].set_blocked(True)  # a collision: the carriage cannot move
    host.cmd(c.load_traj(1, position=20000, velocity=VEL, acceleration=ACC))
    host.port.sleep(0.3)
    s = host.nop(1)
    assert s.pos_error and not s.aux & c.AUX_SERVO_ON and s.move_done
    host.net.plants[0].set_blocked(False)
    assert host.cmd(c.clear_bits(1)).pos_error is False


def test_current_limit_reduces_pwm():
    def stalled_ad(cl: int) -> c.Status:
        h = Host(SimNetwork(1))
        h.init(gains=c.Gains(**{**DEFAULT_GAINS.__dict__, "cl": cl}))
        h.net.plants[0].set_blocked(True)
        h.cmd(c.stop_motor(1, c.AMP_ENABLE))
        h.cmd(c.load_traj(1, pwm=255, servo=False))
        h.port.sleep(0.5)
        return h.cmd(c.read_stat(1, c.SEND_AD), c.SEND_AD)

    free = stalled_ad(0)  # CL 0: no current limiting
    limited = stalled_ad(51)  # odd: proportional sensor, about 2 A
    assert free.ad > 200 and not free.status & c.OVERCURRENT
    assert abs(limited.ad - 51) <= 4 and limited.status & c.OVERCURRENT


def test_reset_pos_and_later_firmware_forms(host: Host):
    host.cmd(c.load_traj(1, position=500, velocity=VEL, acceleration=ACC))
    host.wait_done(1)
    host.settle(0.05)
    assert abs(host.cmd(c.reset_pos(1)).position) <= 1
    assert host.cmd(c.reset_pos(1, position=12345)).position == 12345
    host.cmd(c.save_as_home(1))
    assert host.cmd(c.reset_pos(1, relative_to_home=True)).position == 0
    host.settle(0.05)
    assert abs(host.nop(1).position) <= 1  # the servo holds: no jump


def test_later_firmware_status_items_and_15_byte_gains():
    host = Host(SimNetwork(3, firmware="pic-servo-sc"))
    host.init()
    g = c.Gains(**{**DEFAULT_GAINS.__dict__, "sm": 1})
    assert host.cmd(c.set_gain(1, g)) is not None
    s = host.cmd(c.read_stat(1, 0xFF), 0xFF)
    assert s.position_error is not None and s.path_points == 0
