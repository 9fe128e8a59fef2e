"""PIC-SERVO / NMC protocol codec: bytes in, values out, no I/O.

Command packet (host -> module): ``AA | address | cmd | data[0..15] | checksum``
where the command byte's low nibble is the command code and its high nibble
the number of data bytes, and the checksum is the 8-bit sum of address,
command byte and data (the 0xAA header excluded).

Status packet (module -> host): ``status | items... | checksum`` with the
items chosen by DEF_STAT (permanent) or READ_STAT (one reply), always in bit
order; the checksum is the 8-bit sum of the status byte and the items.
Multi-byte fields are little-endian.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

HEADER = 0xAA
MAX_DATA = 15

# Command codes (low nibble of the command byte).
RESET_POS = 0x0
SET_ADDR = 0x1
DEF_STAT = 0x2
READ_STAT = 0x3
LOAD_TRAJ = 0x4
START_MOVE = 0x5
SET_GAIN = 0x6
STOP_MOTOR = 0x7
IO_CTRL = 0x8
SET_HOMING = 0x9
SET_BAUD = 0xA
CLEAR_BITS = 0xB
SAVE_AS_HOME = 0xC
ADD_PATHPOINT = 0xD
NOP = 0xE
HARD_RESET = 0xF

COMMAND_NAMES = {
    RESET_POS: "RESET_POS", SET_ADDR: "SET_ADDR", DEF_STAT: "DEF_STAT", READ_STAT: "READ_STAT",
    LOAD_TRAJ: "LOAD_TRAJ", START_MOVE: "START_MOVE", SET_GAIN: "SET_GAIN", STOP_MOTOR: "STOP_MOTOR",
    IO_CTRL: "IO_CTRL", SET_HOMING: "SET_HOMING", SET_BAUD: "SET_BAUD", CLEAR_BITS: "CLEAR_BITS",
    SAVE_AS_HOME: "SAVE_AS_HOME", ADD_PATHPOINT: "ADD_PATHPOINT", NOP: "NOP", HARD_RESET: "HARD_RESET",
}

# Status byte bits.
MOVE_DONE = 0x01
CKSUM_ERROR = 0x02
OVERCURRENT = 0x04
POWER_ON = 0x08
POS_ERROR = 0x10
LIMIT1 = 0x20
LIMIT2 = 0x40
HOME_IN_PROG = 0x80

STATUS_BIT_NAMES = {
    MOVE_DONE: "move done", CKSUM_ERROR: "checksum error", OVERCURRENT: "overcurrent",
    POWER_ON: "power on", POS_ERROR: "position error", LIMIT1: "limit 1", LIMIT2: "limit 2",
    HOME_IN_PROG: "home in progress",
}

# Auxiliary status byte bits (status item 0x08).
AUX_INDEX = 0x01
AUX_POS_WRAP = 0x02
AUX_SERVO_ON = 0x04
AUX_ACCEL_DONE = 0x08
AUX_SLEW_DONE = 0x10
AUX_SERVO_OVERRUN = 0x20

AUX_BIT_NAMES = {
    AUX_INDEX: "index", AUX_POS_WRAP: "position wrap", AUX_SERVO_ON: "servo on",
    AUX_ACCEL_DONE: "accel done", AUX_SLEW_DONE: "slew done", AUX_SERVO_OVERRUN: "servo overrun",
}

# Status items (DEF_STAT / READ_STAT data byte), in the order they are sent.
SEND_POS = 0x01
SEND_AD = 0x02
SEND_VEL = 0x04
SEND_AUX = 0x08
SEND_HOME = 0x10
SEND_ID = 0x20
SEND_PERROR = 0x40  # later SC firmware
SEND_NPOINTS = 0x80  # later SC firmware

# (mask, attribute, struct format) in wire order.
STATUS_ITEMS: tuple[tuple[int, str, str], ...] = (
    (SEND_POS, "position", "<i"),
    (SEND_AD, "ad", "<B"),
    (SEND_VEL, "velocity", "<h"),
    (SEND_AUX, "aux", "<B"),
    (SEND_HOME, "home", "<i"),
    (SEND_ID, "module_id", "<H"),  # low byte type, high byte version
    (SEND_PERROR, "position_error", "<h"),
    (SEND_NPOINTS, "path_points", "<B"),
)

# LOAD_TRAJ control byte.
LOAD_POS = 0x01
LOAD_VEL = 0x02
LOAD_ACC = 0x04
LOAD_PWM = 0x08
ENABLE_SERVO = 0x10
VEL_MODE = 0x20
REVERSE = 0x40
START_NOW = 0x80

# STOP_MOTOR control byte.
AMP_ENABLE = 0x01
MOTOR_OFF = 0x02
STOP_ABRUPT = 0x04
STOP_SMOOTH = 0x08
STOP_HERE = 0x10

# SET_HOMING control byte.
ON_LIMIT1 = 0x01
ON_LIMIT2 = 0x02
HOME_MOTOR_OFF = 0x04
ON_INDEX = 0x08
HOME_STOP_ABRUPT = 0x10
HOME_STOP_SMOOTH = 0x20
ON_POS_ERR = 0x40
ON_CUR_ERR = 0x80

# IO_CTRL control byte.
IO_LIMIT1_OUT = 0x01  # output value when LIMIT1 is an output
IO_LIMIT2_OUT = 0x02
IO_LIMIT1_IN = 0x04  # 1 = LIMIT1 is an input
IO_LIMIT2_IN = 0x08
# IO_CTRL on SC firmware (Kerr's NMC library header): the LIMIT pins are always inputs and the byte says what
# the module does by itself on an active limit; 0x10..0x80 are drive options (3-phase, antiphase, fast path,
# step & direction) a DC servo leaves clear.
SC_IO_LIMIT_OFF = 0x04  # motor off on a limit
SC_IO_LIMIT_STOP = 0x08  # stop abruptly on a limit

# RESET_POS control byte (later firmware only).
RESET_REL_HOME = 0x01
RESET_SET_POS = 0x02

PIC_SERVO_TYPE = 0
GROUP_ALL = 0xFF

# Servo tick: 0.512 ms x SR (1953.125 Hz at SR = 1).
TICK_SECONDS = 0.000512
SERVO_RATE_HZ = 1953.125

# SET_BAUD divisors by firmware. The thesis (20 MHz PIC-SERVO) and Kerr's 2005
# library (SC part) disagree, so the table is chosen per firmware family.
BAUD_DIVISORS: dict[str, dict[int, int]] = {
    "pic-servo": {9600: 129, 19200: 63, 57600: 20, 115200: 10},
    "pic-servo-sc": {19200: 64, 57600: 21, 115200: 10, 230400: 5},
}
POWER_UP_BAUD = 19200


class CodecError(ValueError):
    """A packet or a command argument that the protocol cannot represent."""


class ChecksumMismatch(CodecError):
    """A received packet whose checksum byte does not match its content."""


def checksum(data: bytes | bytearray) -> int:
    """8-bit sum of the given bytes."""
    return sum(data) & 0xFF


def _check_byte(name: str, value: int, lo: int = 0, hi: int = 0xFF) -> int:
    if not isinstance(value, int) or not lo <= value <= hi:
        raise CodecError(f"{name} must be an integer in {lo:#04x}..{hi:#04x}, got {value!r}")
    return value


def encode(address: int, code: int, data: bytes | bytearray = b"") -> bytes:
    """A complete command packet for ``code`` with ``data`` to ``address``."""
    _check_byte("address", address)
    _check_byte("command code", code, 0, 0xF)
    if len(data) > MAX_DATA:
        raise CodecError(f"a command carries at most {MAX_DATA} data bytes, got {len(data)}")
    body = bytes((address, (len(data) << 4) | code)) + bytes(data)
    return bytes((HEADER,)) + body + bytes((checksum(body),))


@dataclass(frozen=True)
class Command:
    """A decoded command packet."""

    address: int
    code: int
    data: bytes

    @property
    def name(self) -> str:
        return COMMAND_NAMES[self.code]

    def encode(self) -> bytes:
        return encode(self.address, self.code, self.data)


def command_length(command_byte: int) -> int:
    """Total packet length (header through checksum) implied by a command byte."""
    return 4 + (command_byte >> 4)


def decode(packet: bytes | bytearray) -> Command:
    """Decode a complete command packet; raises on bad header, length or checksum."""
    if len(packet) < 4 or packet[0] != HEADER:
        raise CodecError(f"not a command packet: {bytes(packet).hex(' ')}")
    n = packet[2] >> 4
    if len(packet) != 4 + n:
        raise CodecError(f"command byte {packet[2]:#04x} announces {n} data bytes, packet has {len(packet) - 4}")
    if checksum(packet[1:-1]) != packet[-1]:
        raise ChecksumMismatch(
            f"command checksum {packet[-1]:#04x} should be {checksum(packet[1:-1]):#04x}: {bytes(packet).hex(' ')}"
        )
    return Command(packet[1], packet[2] & 0x0F, bytes(packet[3:-1]))


# --- command builders -------------------------------------------------------

def reset_pos(address: int, *, relative_to_home: bool = False, position: int | None = None) -> bytes:
    """RESET_POS: zero the counter (original firmware form, no data).

    Later firmware accepts a control byte: relative to the home position, or
    set the counter to a given int32 position.
    """
    if position is not None:
        return encode(address, RESET_POS, bytes((RESET_SET_POS,)) + struct.pack("<i", position))
    if relative_to_home:
        return encode(address, RESET_POS, bytes((RESET_REL_HOME,)))
    return encode(address, RESET_POS)


def set_addr(address: int, new_address: int, group: int = GROUP_ALL, *, leader: bool = False) -> bytes:
    """SET_ADDR: individual address and group address (0x80..0xFF).

    A group leader is marked by sending the group address with bit 7 cleared.
    """
    _check_byte("new address", new_address)
    _check_byte("group address", group, 0x80, 0xFF)
    return encode(address, SET_ADDR, bytes((new_address, group & 0x7F if leader else group)))


def def_stat(address: int, items: int) -> bytes:
    return encode(address, DEF_STAT, bytes((_check_byte("status items", items),)))


def read_stat(address: int, items: int) -> bytes:
    return encode(address, READ_STAT, bytes((_check_byte("status items", items),)))


def load_traj(
    address: int,
    *,
    position: int | None = None,
    velocity: int | None = None,
    acceleration: int | None = None,
    pwm: int | None = None,
    servo: bool = True,
    velocity_mode: bool = False,
    reverse: bool = False,
    start_now: bool = True,
) -> bytes:
    """LOAD_TRAJ with the optional fields in wire order (position, velocity, acceleration, PWM).

    ``velocity`` and ``acceleration`` are raw 16.16 fixed-point values
    (counts/tick x 65536, counts/tick^2 x 65536), see :func:`velocity_to_fixed`.
    """
    control = (ENABLE_SERVO if servo else 0) | (VEL_MODE if velocity_mode else 0)
    control |= (REVERSE if reverse else 0) | (START_NOW if start_now else 0)
    data = bytearray()
    if position is not None:
        if not -0x7FFFFFFF <= position <= 0x7FFFFFFF:
            raise CodecError(f"position {position} is outside +-0x7FFFFFFF counts")
        control |= LOAD_POS
        data += struct.pack("<i", position)
    for flag, name, value in ((LOAD_VEL, "velocity", velocity), (LOAD_ACC, "acceleration", acceleration)):
        if value is not None:
            if not 0 <= value <= 0x7FFFFFFF:
                raise CodecError(f"{name} {value} is outside 0..0x7FFFFFFF (16.16 counts per tick)")
            control |= flag
            data += struct.pack("<I", value)
    if pwm is not None:
        control |= LOAD_PWM
        data.append(_check_byte("PWM", pwm))
    return encode(address, LOAD_TRAJ, bytes((control,)) + bytes(data))


@dataclass(frozen=True)
class LoadTraj:
    """LOAD_TRAJ data decoded (used by the simulator and the byte trace)."""

    control: int
    position: int | None = None
    velocity: int | None = None
    acceleration: int | None = None
    pwm: int | None = None


def parse_load_traj(data: bytes) -> LoadTraj:
    if not data:
        raise CodecError("LOAD_TRAJ needs a control byte")
    control = data[0]
    expected = 1 + 4 * bool(control & LOAD_POS) + 4 * bool(control & LOAD_VEL) + 4 * bool(control & LOAD_ACC)
    expected += bool(control & LOAD_PWM)
    if len(data) != expected:
        raise CodecError(f"LOAD_TRAJ control {control:#04x} needs {expected} data bytes, got {len(data)}")
    fields: dict[str, int] = {}
    i = 1
    for flag, name, fmt in ((LOAD_POS, "position", "<i"), (LOAD_VEL, "velocity", "<I"), (LOAD_ACC, "acceleration", "<I")):
        if control & flag:
            fields[name] = struct.unpack_from(fmt, data, i)[0]
            i += 4
    if control & LOAD_PWM:
        fields["pwm"] = data[i]
    return LoadTraj(control, **fields)


def start_move(address: int) -> bytes:
    return encode(address, START_MOVE)


@dataclass(frozen=True)
class Gains:
    """SET_GAIN parameters (raw PIC-SERVO units).

    kp, kd, ki: 0..0x7FFF; il: integration limit 0..0x7FFF; ol: output limit
    0..255; cl: current limit 0..255 (odd = CUR_SENSE proportional to current);
    el: position-error limit 0..0x3FFF counts; sr: servo rate divisor 1..255;
    db: amplifier deadband compensation; sm: step multiplier (later SC
    firmware's 15th byte, omitted when None).
    """

    kp: int = 0
    kd: int = 0
    ki: int = 0
    il: int = 0
    ol: int = 0
    cl: int = 0
    el: int = 0
    sr: int = 1
    db: int = 0
    sm: int | None = None

    def to_bytes(self) -> bytes:
        for name, hi in (("kp", 0x7FFF), ("kd", 0x7FFF), ("ki", 0x7FFF), ("il", 0x7FFF), ("el", 0x3FFF)):
            v = getattr(self, name)
            if not isinstance(v, int) or not 0 <= v <= hi:
                raise CodecError(f"gain {name.upper()} must be 0..{hi}, got {v!r}")
        _check_byte("OL", self.ol)
        _check_byte("CL", self.cl)
        _check_byte("SR", self.sr, 1, 255)
        _check_byte("DB", self.db)
        raw = struct.pack("<hhhhBBhBB", self.kp, self.kd, self.ki, self.il, self.ol, self.cl, self.el, self.sr, self.db)
        return raw if self.sm is None else raw + bytes((_check_byte("step multiplier", self.sm),))

    @classmethod
    def from_bytes(cls, data: bytes) -> "Gains":
        if len(data) not in (14, 15):
            raise CodecError(f"SET_GAIN carries 14 data bytes (15 on SC firmware), got {len(data)}")
        kp, kd, ki, il, ol, cl, el, sr, db = struct.unpack_from("<hhhhBBhBB", data)
        return cls(kp, kd, ki, il, ol, cl, el, sr, db, data[14] if len(data) == 15 else None)


def set_gain(address: int, gains: Gains) -> bytes:
    return encode(address, SET_GAIN, gains.to_bytes())


def stop_motor(address: int, control: int, position: int | None = None) -> bytes:
    """STOP_MOTOR with a control byte; STOP_HERE carries an int32 target position."""
    _check_byte("stop control", control)
    if control & STOP_HERE:
        if position is None:
            raise CodecError("STOP_HERE needs a position")
        return encode(address, STOP_MOTOR, bytes((control,)) + struct.pack("<i", position))
    if position is not None:
        raise CodecError("a stop position is only sent with STOP_HERE")
    return encode(address, STOP_MOTOR, bytes((control,)))


def io_ctrl(address: int, control: int) -> bytes:
    return encode(address, IO_CTRL, bytes((_check_byte("I/O control", control),)))


def plain_inputs_io(firmware: str) -> int:
    """The IO_CTRL byte that makes LIMIT1 and LIMIT2 inputs the module reads and captures but never acts on.

    Original firmware: 0x0C (bits 2/3: both pins inputs). SC firmware: 0x00,
    because there the same 0x0C turns the motor off (0x04) and stops it (0x08)
    while a LIMIT input is active: with the probe wired to a LIMIT input every
    trigger, and every retract with the stylus still deflected, would kill the
    axis; home switches would too.
    """
    if firmware not in BAUD_DIVISORS:
        raise CodecError(f"unknown firmware family {firmware!r}; known: {', '.join(BAUD_DIVISORS)}")
    return 0x00 if firmware == "pic-servo-sc" else IO_LIMIT1_IN | IO_LIMIT2_IN


def set_homing(address: int, control: int) -> bytes:
    return encode(address, SET_HOMING, bytes((_check_byte("homing control", control),)))


def set_baud(address: int, divisor: int) -> bytes:
    return encode(address, SET_BAUD, bytes((_check_byte("baud divisor", divisor, 1, 255),)))


def baud_divisor(baud: int, firmware: str = "pic-servo") -> int:
    """SET_BAUD divisor for ``baud`` on a firmware family (see BAUD_DIVISORS)."""
    table = BAUD_DIVISORS.get(firmware)
    if table is None:
        raise CodecError(f"unknown firmware family {firmware!r}; known: {', '.join(BAUD_DIVISORS)}")
    if baud not in table:
        raise CodecError(f"{baud} baud is not available on {firmware}; choose one of {sorted(table)}")
    return table[baud]


def baud_from_divisor(divisor: int, firmware: str = "pic-servo") -> int | None:
    for baud, d in BAUD_DIVISORS[firmware].items():
        if d == divisor:
            return baud
    return None


def clear_bits(address: int) -> bytes:
    return encode(address, CLEAR_BITS)


def save_as_home(address: int) -> bytes:
    return encode(address, SAVE_AS_HOME)


@functools.cache  # the machine's every sample sends one to each axis
def nop(address: int) -> bytes:
    return encode(address, NOP)


def hard_reset(address: int) -> bytes:
    return encode(address, HARD_RESET)


# --- status packets ---------------------------------------------------------

@functools.cache  # every transaction asks, for a handful of item sets
def status_length(items: int) -> int:
    """Bytes in a status packet carrying ``items`` (status byte and checksum included)."""
    return 2 + sum(struct.calcsize(fmt) for mask, _, fmt in STATUS_ITEMS if items & mask)


@functools.cache
def _status_layout(items: int) -> tuple[struct.Struct, tuple[str, ...]]:
    """The items of a status packet as one little-endian struct (after the status byte) and their names."""
    chosen = [(name, fmt) for mask, name, fmt in STATUS_ITEMS if items & mask]
    return struct.Struct("<" + "".join(fmt[1:] for _, fmt in chosen)), tuple(name for name, _ in chosen)


@dataclass(frozen=True)
class Status:
    """A parsed status packet. Items not requested are None."""

    status: int
    position: int | None = None
    ad: int | None = None
    velocity: int | None = None
    aux: int | None = None
    home: int | None = None
    module_id: int | None = None
    position_error: int | None = None
    path_points: int | None = None

    @property
    def module_type(self) -> int | None:
        return None if self.module_id is None else self.module_id & 0xFF

    @property
    def version(self) -> int | None:
        return None if self.module_id is None else self.module_id >> 8

    def flag(self, mask: int) -> bool:
        return bool(self.status & mask)

    @property
    def move_done(self) -> bool:
        return bool(self.status & MOVE_DONE)

    @property
    def cksum_error(self) -> bool:
        return bool(self.status & CKSUM_ERROR)

    @property
    def home_in_progress(self) -> bool:
        return bool(self.status & HOME_IN_PROG)

    @property
    def pos_error(self) -> bool:
        return bool(self.status & POS_ERROR)


def parse_status(packet: bytes | bytearray, items: int) -> Status:
    """Parse a status packet that carries ``items``; verifies length and checksum."""
    need = status_length(items)
    if len(packet) != need:
        raise CodecError(f"status packet with items {items:#04x} has {need} bytes, got {len(packet)}")
    if checksum(packet[:-1]) != packet[-1]:
        raise ChecksumMismatch(
            f"status checksum {packet[-1]:#04x} should be {checksum(packet[:-1]):#04x}: {bytes(packet).hex(' ')}"
        )
    layout, names = _status_layout(items)
    return Status(packet[0], **dict(zip(names, layout.unpack_from(packet, 1))))


def encode_status(status: int, items: int = 0, **values: int) -> bytes:
    """Build a status packet (the simulator's side). Missing requested items are 0."""
    out = bytearray((status & 0xFF,))
    for mask, name, fmt in STATUS_ITEMS:
        if items & mask:
            out += struct.pack(fmt, values.get(name, 0))
    out.append(checksum(out))
    return bytes(out)


def module_id(module_type: int, version: int) -> int:
    return (module_type & 0xFF) | ((version & 0xFF) << 8)


def status_words(status: int, aux: int | None = None) -> list[str]:
    """The set status (and aux) bits in words, for operators."""
    words = [name for mask, name in STATUS_BIT_NAMES.items() if status & mask]
    if aux is not None:
        words += [name for mask, name in AUX_BIT_NAMES.items() if aux & mask]
    return words


# --- units ------------------------------------------------------------------

def tick_seconds(sr: int = 1) -> float:
    return TICK_SECONDS * sr


def velocity_to_fixed(mm_per_s: float, counts_per_mm: float, sr: int = 1) -> int:
    """mm/s -> 16.16 counts per servo tick (the LOAD_TRAJ velocity field)."""
    raw = abs(mm_per_s) * counts_per_mm * tick_seconds(sr) * 65536
    if not raw <= 0x7FFFFFFF:  # also an infinite or not-a-number product: never int(inf)
        raise CodecError(f"{mm_per_s:.4g} mm/s is beyond the largest velocity the module can represent")
    return round(raw)


def fixed_to_velocity(value: int, counts_per_mm: float, sr: int = 1) -> float:
    """16.16 counts per tick -> mm/s."""
    return value / 65536 / tick_seconds(sr) / counts_per_mm


def acceleration_to_fixed(mm_per_s2: float, counts_per_mm: float, sr: int = 1) -> int:
    """mm/s^2 -> 16.16 counts per tick^2 (the LOAD_TRAJ acceleration field)."""
    t = tick_seconds(sr)
    raw = abs(mm_per_s2) * counts_per_mm * t * t * 65536
    if not raw <= 0x7FFFFFFF:  # also an infinite or not-a-number product: never int(inf)
        raise CodecError(f"{mm_per_s2:.4g} mm/s^2 is beyond the largest acceleration the module can represent")
    return round(raw)


def fixed_to_acceleration(value: int, counts_per_mm: float, sr: int = 1) -> float:
    t = tick_seconds(sr)
    return value / 65536 / (t * t) / counts_per_mm


def describe(packet: bytes | bytearray) -> str:
    """One-line human description of a command packet, for byte traces."""
    try:
        cmd = decode(packet)
    except CodecError as exc:
        return f"invalid: {exc}"
    return f"{cmd.name} @ {cmd.address:#04x}" + (f" [{cmd.data.hex(' ')}]" if cmd.data else "")
