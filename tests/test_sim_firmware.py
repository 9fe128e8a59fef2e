"""Firmware families as the protocol facts describe them (the PIC-SERVO data sheet; Kerr's NMC library header
for the SC bits), checked through bytes only: packets built here by hand, not by the driver's codec.

Facts: IO_CTRL on the original module: bit2/bit3 = 1 make LIMIT1/LIMIT2 inputs,
else outputs at bit0/bit1. On the SC the LIMIT pins are inputs; IO_CTRL 0x04
turns the motor off and 0x08 stops it abruptly on a limit, 0x10 selects 3-phase
drive. SET_HOMING 0x01 captures on a LIMIT1 change (home position = item 0x10).
Status items 0x40 (position error, 2 bytes) and 0x80 (path points, 1 byte) exist
on the SC only. SET_GAIN carries 13 or 14 bytes (Kp Kd Ki IL int16, OL CL byte,
EL int16, SR byte, then DB). LOAD_TRAJ bit 0x40 in position mode: MOVE_REL on the SC.
HARD_RESET on the SC takes a control byte: 0x01 save to EEPROM, 0x02 restore addresses.
"""

from __future__ import annotations

import struct

import pytest

from cmm.nmc.transport import open_port

SET_ADDR, DEF_STAT, READ_STAT, LOAD_TRAJ, SET_GAIN, STOP_MOTOR, IO_CTRL, SET_HOMING, NOP, HARD_RESET = (
    0x1, 0x2, 0x3, 0x4, 0x6, 0x7, 0x8, 0x9, 0xE, 0xF)
LIMIT1_BIT, HOME_IN_PROG = 0x20, 0x80
MOVE_DONE = 0x01
GAINS_13 = struct.pack("<hhhhBBhB", 4000, 10000, 0, 0, 255, 0, 500, 1)  # the simulator's tuned gains, no DB


def packet(address: int, code: int, data: bytes = b"") -> bytes:
    body = bytes((address, (len(data) << 4) | code)) + data
    return b"\xaa" + body + bytes((sum(body) & 0xFF,))


class Host:
    def __init__(self, firmware: str, modules: int = 1) -> None:
        self.port, self.clock = open_port(f"sim://?modules={modules}&firmware={firmware}", 19200, 0.05)
        self.net = self.port.world.network

    def send(self, address: int, code: int, data: bytes = b"", n: int = 2) -> bytes:
        self.port.reset_input_buffer()
        self.port.write(packet(address, code, data))
        reply = self.port.read(n)
        if reply:
            assert sum(reply[:-1]) & 0xFF == reply[-1], reply.hex(" ")
        return reply

    def ready(self, address: int = 1) -> None:
        """Address, status items position + home, gains, amplifier on and servo holding."""
        assert len(self.send(0, SET_ADDR, bytes((address, 0xFF)))) == 2
        assert len(self.send(address, DEF_STAT, b"\x11", 10)) == 10
        assert len(self.send(address, SET_GAIN, GAINS_13 + b"\x00", 10)) == 10
        self.send(address, STOP_MOTOR, b"\x05", 10)  # amp enable + stop abruptly: servo on, holding

    def status(self, address: int = 1) -> tuple[int, int, int]:
        """(status byte, position, home position) from items 0x01 + 0x10."""
        r = self.send(address, NOP, n=10)
        assert len(r) == 10, r.hex(" ")
        return r[0], struct.unpack_from("<i", r, 1)[0], struct.unpack_from("<i", r, 5)[0]

    def move(self, position: int, control: int = 0x97, address: int = 1) -> None:
        """LOAD_TRAJ: position + velocity + acceleration, servo, start now (0x97)."""
        data = bytes((control,)) + struct.pack("<iII", position, 6 << 16, 1 << 14)
        assert len(self.send(address, LOAD_TRAJ, data, 10)) == 10

    def settle(self, address: int = 1, limit_s: float = 5.0) -> tuple[int, int, int]:
        end = self.clock.now() + limit_s
        while self.clock.now() < end:
            st = self.status(address)
            if st[0] & MOVE_DONE:
                self.clock.sleep(0.05)
                return self.status(address)
            self.clock.sleep(0.002)
        raise AssertionError("the move did not finish")


@pytest.mark.parametrize("io_ctrl", [0x00, 0x10])
def test_sc_io_ctrl_keeps_limit1_an_input_and_capture_fires(io_ctrl):
    host = Host("pic-servo-sc")
    host.ready()
    assert len(host.send(1, IO_CTRL, bytes((io_ctrl,)), 10)) == 10  # what Kerr's library sends SC modules first
    host.move(3000)
    host.clock.sleep(0.2)
    assert host.send(1, SET_HOMING, b"\x01", 10)[0] & HOME_IN_PROG
    host.net.set_inputs(0, limit1=True)  # a switch on LIMIT1 closes
    host.clock.sleep(0.002)
    status, position, home = host.status()
    assert status & LIMIT1_BIT and not status & HOME_IN_PROG
    assert 0 < home <= position


def test_classic_io_ctrl_0x00_makes_limit1_an_output_at_0():
    host = Host("pic-servo")
    host.ready()
    host.send(1, IO_CTRL, b"\x00", 10)
    host.send(1, SET_HOMING, b"\x01", 10)
    host.net.set_inputs(0, limit1=True)
    host.clock.sleep(0.01)
    status, _, _ = host.status()
    assert not status & LIMIT1_BIT and status & HOME_IN_PROG  # the pin drives 0: nothing to capture
    host.send(1, IO_CTRL, b"\x0c", 10)  # both inputs again: the switch is seen
    assert host.status()[0] & LIMIT1_BIT


def test_sc_only_status_items():
    classic, sc = Host("pic-servo"), Host("pic-servo-sc")
    for h in (classic, sc):
        assert len(h.send(0, SET_ADDR, b"\x01\xff")) == 2
    assert len(classic.send(1, READ_STAT, b"\xc0", 5)) == 2  # status byte + checksum only
    assert len(sc.send(1, READ_STAT, b"\xc0", 5)) == 5  # + position error (2) + path points (1)
    assert len(classic.send(1, READ_STAT, b"\xe0", 5)) == 4  # 0x20 (type, version) is on both


def test_shipped_config_needs_sc_firmware_to_read_the_following_error():
    from cmm.machine.config import load
    from cmm.machine.motion import Machine
    from cmm.nmc.bus import NmcError

    config = load()
    assert not config.link.read_following_error or config.link.firmware == "pic-servo-sc"
    wrong = config.with_link(read_following_error=True, firmware="pic-servo")
    machine = Machine(wrong, "sim://?cmm=1&firmware=pic-servo")
    with pytest.raises(NmcError, match="needs SC firmware"):
        machine.connect()  # original modules do not send item 0x40: every reply is 2 bytes short
    machine.close()
    right = config.with_link(read_following_error=True, firmware="pic-servo-sc")
    machine = Machine(right, "sim://?cmm=1&firmware=pic-servo-sc")
    machine.connect()
    assert machine.state.axes[0].following_error is not None
    machine.close()


@pytest.mark.parametrize("firmware", ["pic-servo", "pic-servo-sc"])
def test_13_byte_set_gain_is_applied(firmware):
    host = Host(firmware)
    assert len(host.send(0, SET_ADDR, b"\x01\xff")) == 2
    host.send(1, DEF_STAT, b"\x11", 10)
    host.send(1, SET_GAIN, GAINS_13, 10)  # power-up gains are 0: without these the motor never moves
    host.send(1, STOP_MOTOR, b"\x05", 10)
    host.move(2000)
    _, position, _ = host.settle()
    assert abs(position - 2000) <= 1


def test_move_rel_on_sc_and_absolute_on_the_original():
    for firmware, expected in (("pic-servo-sc", 1500), ("pic-servo", 500)):
        host = Host(firmware)
        host.ready()
        host.move(1000)
        host.settle()
        host.move(500, control=0x97 | 0x40)
        _, position, _ = host.settle()
        assert abs(position - expected) <= 1, firmware


def test_sc_limit_stop_stops_travel_towards_the_limit_only():
    host = Host("pic-servo-sc")
    host.ready()
    host.send(1, IO_CTRL, b"\x08", 10)  # stop abruptly on a limit
    host.move(20000)
    host.clock.sleep(0.3)
    host.net.set_inputs(0, limit1=True)  # forward limit reached
    status, position, _ = host.settle()
    assert position < 15000 and status & LIMIT1_BIT
    host.move(0)  # moving off the limit is allowed
    _, position, _ = host.settle()
    assert abs(position) <= 1


def test_sc_limit_off_turns_the_motor_off():
    host = Host("pic-servo-sc")
    host.ready()
    host.send(1, IO_CTRL, b"\x04", 10)
    host.net.set_inputs(0, limit2=True)  # reverse limit already active
    host.move(-5000)
    host.clock.sleep(0.05)
    r = host.send(1, READ_STAT, b"\x08", 3)  # aux status: servo_on is 0x04
    assert not r[1] & 0x04


def test_sc_hard_reset_saves_gains_and_addresses_through_a_power_cycle():
    host = Host("pic-servo-sc", modules=2)
    host.ready(1)
    host.ready(2)
    host.port.write(packet(0xFF, HARD_RESET, b"\x03"))  # save + restore addresses; no reply
    assert host.port.read(2) == b""
    host.net.power_cycle()
    host.clock.sleep(0.01)
    for a in (1, 2):  # both answer at their saved addresses without the chain being addressed
        assert len(host.send(a, NOP)) == 2
    host.send(1, DEF_STAT, b"\x11", 10)
    host.send(1, STOP_MOTOR, b"\x05", 10)
    host.move(1000)
    _, position, _ = host.settle()  # the saved gains are back
    assert abs(position - 1000) <= 1


def test_classic_hard_reset_forgets_everything():
    host = Host("pic-servo")
    host.ready()
    host.port.write(packet(0xFF, HARD_RESET))
    host.clock.sleep(0.01)
    assert host.send(1, NOP) == b""
    assert len(host.send(0, SET_ADDR, b"\x01\xff")) == 2
