"""The NMC bus's vocabulary: its errors, what a reply tells, and the protocol's times and limits (see
:mod:`cmm.nmc.bus` for the rules they serve)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from . import codec


class NmcError(Exception):
    """A failure on the NMC network, naming the module address when there is one."""

    def __init__(self, message: str, address: int | None = None) -> None:
        super().__init__(message)
        self.address = address


class Preempted(NmcError):
    """A stop cut short the patient retry of a command while every axis stood still (see :meth:`Bus.preempt`):
    the command was not confirmed, nothing failed; the caller lets the stop go first and may try again."""


class LinkError(NmcError):
    """The link failed (port error, disconnect, modules silent, time-out storm).

    The only exception a port failure raises from the bus: whoever drives the
    machine must treat it as "the machine state is unknown" and stop.
    """

    def __init__(self, message: str, address: int | None = None, port: str = "", *,
                 module_only: bool = False) -> None:
        super().__init__(message, address)
        self.port = port
        self.module_only = module_only  # this module is silent or unsure; the others may still answer


class Reading(NamedTuple):
    """What the last trusted reply of one module said (see :meth:`Bus.last_reading`)."""

    position: int  # counts
    time: float  # when its request was sent: the module sampled after it, never before
    velocity: int | None  # counts per servo tick (None when the reply does not carry it)
    status: int  # the status byte


@dataclass(frozen=True)
class ModuleInfo:
    address: int
    module_type: int
    version: int


@dataclass(frozen=True)
class StopReport:
    """What :meth:`Bus.stop_all` achieved: which modules acknowledged the stop."""

    acknowledged: tuple[int, ...]
    silent: tuple[int, ...]
    reason: str = ""  # the first link error met, if any

    @property
    def ok(self) -> bool:
        return not self.silent

    def sentence(self) -> str:
        if self.ok:
            return f"stop acknowledged by every module ({', '.join(map(str, self.acknowledged)) or 'none known'})"
        return (f"STOP NOT CONFIRMED by module(s) {', '.join(map(str, self.silent))}"
                f"{': ' + self.reason if self.reason else ''}. Cut the motor power")


NULLS_INIT = 20  # the thesis sends 16, Kerr's library 20
NULLS_RESYNC = 30
RESYNC_WAIT = 0.1  # Kerr's quiet wait, used when there is no module to send a marker to
BAUD_SWITCH_WAIT = 0.1
LEADERLESS_WAIT = 0.002  # at least one servo tick before the next command (several at SR > 1)
MAX_MODULES = 32
MARKER_WAIT = 0.75  # longest late reply the marker waits through (stalls of up to 0.5 s seen under load)
DISCOVERY_WAIT = 0.3  # the same while addressing the chain
SHORT_MARKER_WAIT = 0.25  # a marker on a line known to be clean (a busy host can still be slow)
QUIET_CONFIRM = 0.02  # no byte may follow the marker's reply for this long
RESYNC_ATTEMPTS = 3
DISCOVERY_ATTEMPTS = 3
# While every axis stands still a missed reply costs nothing but time: it is retried, each time waiting twice as
# long (up to MAX_REPLY_WAIT), and counted (a link warning only above the retry-rate threshold of link_health.py);
# only after IDLE_PATIENCE s without an answer is
# the link declared failed. A host descheduled for seconds under load (seen: 0.5 s and more at load 6 to 22) is
# not a failed link. During motion the limits below stay as they are.
IDLE_PATIENCE = 6.0
PREEMPT_SLICE = 0.05  # s: a resynchronisation's wait looks this often whether a stop wants the link
MAX_REPLY_WAIT = 1.0
DISCOVERY_WAITS = (DISCOVERY_WAIT, 0.6, 1.2)  # the marker's waits for a module the chain is known to have
OVERSLEPT = 0.02  # s a read may return past its deadline before the host counts as descheduled meanwhile
OVERSLEPT_EXTENSIONS = 3  # a reply's wait is renewed at most this often for a descheduled host
# Modules served by a process on this computer (the built-in simulator over TCP on loopback) share its CPU: on a
# loaded computer they answer, but late (on a 2-core machine at load 8.5, three retries in a row missed Kerr's 60 ms
# during motion while every marker between them was answered in 0.1-0.2 s: a false fault). For such a peer a reply
# may take REPLY_ROUND_TRIPS times the link's recent round trip (the largest that replies and markers took, halved
# every TRIP_HALF_LIFE s), never less than Kerr's time and never more than MARKER_WAIT. Hardware (a serial port, a
# serial server on another computer) keeps Kerr's time and the strict rules during motion: a late module there is
# a failing module. The count of lost replies that faults the machine is the same for both.
REPLY_ROUND_TRIPS = 2.0
TRIP_HALF_LIFE = 5.0
LOCAL_HOSTS = ("127.", "localhost", "[::1]")
HEARD_KEEP = 64  # received chunks kept for the error messages ("what was seen")
STORM_LIMIT = 6  # transactions in a row that needed a resynchronisation: the link is down
GOAL_TOLERANCE = 3  # counts: a started move that already arrived
REST_TOLERANCE = 3  # counts: a move that did not start has not moved
CONTINUITY_MARGIN = 64  # counts a module may move beyond its fastest loaded speed between two replies
CONTINUITY_FLOOR = 2000.0  # counts/s always allowed (a servo pushed off, an axis moved by hand slowly)

# Resending these is harmless if the first one was carried out (the second does the same again).
RESEND_SAFE = {codec.NOP, codec.READ_STAT, codec.DEF_STAT, codec.SET_GAIN, codec.IO_CTRL, codec.STOP_MOTOR,
               codec.CLEAR_BITS}
# Marker item sets, in turn; each carries the module id so its content is known.
MARKER_ITEMS = (codec.SEND_ID, codec.SEND_ID | codec.SEND_AUX, codec.SEND_ID | codec.SEND_AD | codec.SEND_AUX,
                codec.SEND_ID | codec.SEND_VEL | codec.SEND_AUX)
CAPTURE_BITS = codec.ON_LIMIT1 | codec.ON_LIMIT2 | codec.ON_INDEX | codec.ON_POS_ERR | codec.ON_CUR_ERR


def starts_motion(packet: bytes) -> bool:
    """Does this command packet start a motion (START_MOVE, or LOAD_TRAJ with start now that is not a stop)?"""
    if len(packet) < 3:
        return False
    code = packet[2] & 0x0F
    if code == codec.START_MOVE:
        return True
    if code != codec.LOAD_TRAJ or len(packet) < 4 or not packet[3] & codec.START_NOW:
        return False
    try:
        lt = codec.parse_load_traj(bytes(packet[3:-1]))
    except codec.CodecError:
        return True
    return not (lt.control & codec.VEL_MODE and not lt.velocity)


def local_peer(port: Any) -> bool:
    """Is ``port`` a URL of modules served by a process on this computer (TCP or RFC 2217 on loopback, or a
    pseudo-terminal: ``cmm sim --pty``)?"""
    if not isinstance(port, str):
        return False
    if port.startswith("/dev/pts/"):
        return True
    if "://" not in port:
        return False
    scheme, rest = port.split("://", 1)
    return scheme.lower() in ("socket", "rfc2217") and rest.lower().startswith(LOCAL_HOSTS)


def reply_timeout(n_bytes: int) -> float:
    return 0.050 + 0.002 * n_bytes


def _port_name(port: Any) -> str:
    if isinstance(port, str):
        return port
    return str(getattr(port, "port", None) or type(port).__name__)
