"""PIC-SERVO status packets: the status byte, the auxiliary byte and the
optional items a DEF_STAT / READ_STAT set asks for, encoded as the firmware
sends them (little-endian, clamped / wrapped like the PIC's registers).

The functions read a :class:`~cmm.sim.picservo.PicServo` (``m``).
"""

from __future__ import annotations

import struct
from typing import Any

from cmm.nmc import codec as c


CLASSIC_ITEMS = 0x3F  # status items of the original firmware
_INT32 = 1 << 32


def _int32(value: int) -> int:
    return (value + 0x80000000) % _INT32 - 0x80000000


def _clamp16(value: int) -> int:
    return -0x8000 if value < -0x8000 else 0x7FFF if value > 0x7FFF else value


def status_byte(m: Any) -> int:
    """The status byte from the module's flags and its LIMIT input levels."""
    levels = m._input_levels()
    return ((c.MOVE_DONE if m.move_done else 0) | (c.CKSUM_ERROR if m.cksum_error else 0)
            | (c.OVERCURRENT if m.overcurrent else 0) | (c.POWER_ON if m.plant.power else 0)
            | (c.POS_ERROR if m.pos_error else 0) | (c.LIMIT1 if levels[0] else 0)
            | (c.LIMIT2 if levels[1] else 0) | (c.HOME_IN_PROG if m.home_in_prog else 0))


def aux_byte(m: Any) -> int:
    """The auxiliary status byte (index, wrap, servo on, profile phases, overrun)."""
    p = m.plant
    return ((c.AUX_INDEX if p.index else 0) | (c.AUX_POS_WRAP if m.pos_wrap else 0)
            | (c.AUX_SERVO_ON if m.servo_on else 0) | (c.AUX_ACCEL_DONE if m.accel_done else 0)
            | (c.AUX_SLEW_DONE if m.slew_done else 0) | (c.AUX_SERVO_OVERRUN if m.servo_overrun else 0))


def status_packet(m: Any, items: int | None = None) -> bytes:
    """The status packet with ``items`` (default: the DEF_STAT set)."""
    if items is None:
        items = m.stat_items
    if not m.sc:
        items &= CLASSIC_ITEMS  # 0x40 / 0x80 do not exist on the original firmware
    out = bytearray((status_byte(m),))
    if items:
        if items & c.SEND_POS:
            out += struct.pack("<i", _int32(m.pos))
        if items & c.SEND_AD:
            out.append(m.ad)
        if items & c.SEND_VEL:
            out += struct.pack("<h", _clamp16(m.velocity))
        if items & c.SEND_AUX:
            out.append(aux_byte(m))
        if items & c.SEND_HOME:
            out += struct.pack("<i", _int32(m.home))
        if items & c.SEND_ID:
            out += bytes((c.PIC_SERVO_TYPE, m.version & 0xFF))
        if items & c.SEND_PERROR:
            out += struct.pack("<h", _clamp16(m.pos_error_value))
        if items & c.SEND_NPOINTS:
            out.append(0)
    out.append(sum(out) & 0xFF)
    return bytes(out)
