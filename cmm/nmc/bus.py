"""The NMC bus: one command, one reply, over any byte transport.

Rules from the protocol:
- the host sends one command and waits for its status packet before the next;
- read timeout 50 ms + 2 ms per expected byte (Kerr's library);
- a reply with cksum_error set means the module ignored the command: resend once;
- group commands are answered by the group leader only, or not at all.

Replies carry no address, so a late reply could be read as the next
module's. After any time-out or bad reply the bus resynchronises Kerr's way
(nulls complete a torn packet and abort a reply in progress), then makes it
certain: it sends a *marker* (READ_STAT of the module type and version, with
a reply length no normal reply has) to the module that owes the late reply,
and discards every byte up to the marker's reply. Bytes keep their order on
the line, so once the marker's reply is in, nothing older can follow. A
command whose reply was lost is sent again only if doing it twice is
harmless; a motion start is checked on the module instead (see
``_after_lost_reply``). Every port failure surfaces as :class:`LinkError`.

A slow host is not a failed link: a reply's time-out counts from the moment the request left and never
passes over bytes already in the port's buffer; a read that came back well past its deadline (the process
was off the CPU) gives the reply its time again. While every axis stands still (:meth:`Bus.still`) a
missed reply is retried with doubling waits, each retry a link warning (``Bus.warning``), for up to
IDLE_PATIENCE s; during motion the limits stay strict (three lost replies to one command, STORM_LIMIT
commands in a row, a marker that does not come back).
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Any, NamedTuple

import serial

from . import codec
from .link_health import RetryRate
from .trace import ByteTrace
from .transport import open_port


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


class Bus:
    """An NMC network behind one serial port.

    ``port`` is a pyserial URL or device name, or an in-process transport
    (the simulator's) with the same byte interface. Thread-safe: transactions
    are serialised.
    """

    def __init__(self, port: Any, *, firmware: str = "pic-servo", trace: ByteTrace | None = None,
                 expected_modules: int | None = None, local: bool | None = None) -> None:
        self.firmware = firmware
        self.local = local_peer(port) if local is None else local  # modules served on this computer (see above)
        self.baud = codec.POWER_UP_BAUD
        self._url = port
        self.port_name = _port_name(port)
        self.port, self.clock = open_port(port, self.baud, reply_timeout(2))
        self.trace = trace if trace is not None else ByteTrace()
        self.lock = threading.RLock()
        self.expected_modules = expected_modules  # initialize() retries discovery until it finds this many
        self.items: dict[int, int] = {}  # address -> DEF_STAT items the module sends
        self.leaders: dict[int, int] = {}  # group address -> leader's individual address
        self.groups: dict[int, int] = {}  # individual address -> group address
        self.modules: list[ModuleInfo] = []
        self.stats = {"transactions": 0, "retries": 0, "resyncs": 0, "discarded": 0, "verified": 0,
                      "suspect": 0, "late": 0, "window_retries": 0, "window_transactions": 0}
        self._rate = RetryRate()  # the retry rate over the last minute: a warning only above its threshold
        self.link_up = True
        self._marker_turn = 0
        self._trip, self._trip_at = 0.0, 0.0  # the link's recent round trip (s) and when it was last raised
        self._storm = 0  # transactions in a row that needed a resynchronisation
        # address -> the last good reply's reading, its time being when its request was sent: the module samples
        # after the request arrives, so (unlike the time the reply was read) it never follows the sample
        self._last: dict[int, Reading] = {}
        self._sent_at = 0.0  # when the request of the reply being read was sent
        self._vmax: dict[int, float] = {}  # address -> fastest loaded speed, counts/s
        self._buffered: dict[int, int] = {}  # address -> goal of a buffered position move
        self._armed: set[int] = set()  # modules with a home capture armed
        # The home register, for telling whether a command whose reply was lost took effect. It changes only when
        # a capture fires, on SAVE_AS_HOME, RESET_POS and HARD_RESET; the value is read at start-up and dropped
        # when one of these may have changed it (a reply shows a capture fired, or one of those commands is sent).
        self._home: dict[int, int] = {}  # address -> home register value as last read and still valid
        self._capturing: set[int] = set()  # modules with a capture armed that no reply has yet shown fired
        self._before: dict[int, tuple[Reading | None, int | None]] = {}  # address -> (last position
        # reply, home value) when a SET_HOMING, SAVE_AS_HOME or RESET_POS was sent to it
        self._free: set[int] = set()  # modules not under position servo (PWM mode, motor off): any speed
        # address -> the last reply before a motion start was sent, when it showed the axis standing under servo
        # (move done): nothing but that command can have moved it since
        self._held: dict[int, Reading] = {}
        self._command_at = 0.0  # when the command being transacted was first sent (nothing it did is older)
        # address -> replies in a row that showed the module at rest (move done, same position as the one before);
        # 0 after a motion command. A module not in it stands as it powered up. See :meth:`still`.
        self._calm: dict[int, int] = {}
        self.warning: tuple[int, str, float] = (0, "", 0.0)  # link warnings so far, the last one, its clock time
        self._preempts = 0  # stops that asked to cut short a patient retry (see preempt)
        self._urgent = 0  # jog stops that asked to cut short any retry (see preempt)
        self._busy: tuple[int, int] | None = None  # both counts when the outermost transaction in progress began
        self._busy_since = 0.0  # and the time it began
        self._heard: deque[tuple[float, bytes]] = deque(maxlen=HEARD_KEEP)  # (time, bytes) as they came in
        # the operator's STOP / E-STOP (stop_all with a latch): every motion start is refused (Preempted) until the
        # station has carried the stop out and clears it (clear_halt), so nothing started in the same moment as the
        # stop can run after it
        self.halt_latch: str | None = None

    # --- port I/O: every pyserial failure becomes a LinkError ------------------

    def _link_error(self, doing: str, exc: BaseException, address: int | None = None) -> LinkError:
        self.link_up = False
        who = f" (module {address})" if address is not None and address < 0x80 else (
            f" (group {address:#04x})" if address is not None else "")
        return LinkError(f"the serial link {self.port_name} failed while {doing}{who}: {exc or type(exc).__name__}. "
                         "Check the cable, the adapter and the module power, then reconnect", address, self.port_name)

    def close(self, *, release: bool = False) -> None:
        """Close the port; with ``release`` first leave the modules in their power-up state."""
        with self.lock:
            if release and self.link_up:
                try:
                    self.release()
                except LinkError:
                    pass
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.link_up = False

    def _write(self, data: bytes, address: int | None = None) -> None:
        self.trace.tx(self.clock.now(), data)
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("sending", exc, address) from exc

    def _set_timeout(self, timeout: float | None, address: int | None = None) -> None:
        try:
            if self.port.timeout != timeout:
                self.port.timeout = timeout
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._link_error("setting the read time-out", exc, address) from exc

    def _read(self, n: int, address: int | None = None, timeout: float | None = None,
              since: float | None = None) -> bytes:
        """Up to ``n`` bytes of a reply, waiting ``timeout`` (default Kerr's) from ``since`` (the moment the
        request left; default now). A reply torn across the deadline (the host was descheduled between two
        chunks: pyserial then returns what it had) is completed from the bytes already in the port's buffer:
        a reply that has arrived is never declared timed out."""
        wait = reply_timeout(n) if timeout is None else timeout
        start = self.clock.now() if since is None else since
        self._set_timeout(wait, address)  # (the same value every time: a real port is not reconfigured)
        renewed = 0
        try:
            data = self.port.read(n)
            while len(data) < n:
                left = start + wait - self.clock.now()
                if left > 1e-4:  # pyserial gave up early (a chunk came just before its own deadline)
                    self._set_timeout(left, address)
                    more = self.port.read(n - len(data))
                    if more:
                        data += more
                        continue
                waiting = self.port.in_waiting
                more = self.port.read(min(waiting, n - len(data))) if waiting else b""  # already here: no wait
                if more:
                    data += more
                    continue
                if self.clock.now() - (start + wait) > OVERSLEPT and renewed < OVERSLEPT_EXTENSIONS:
                    # this process was off the CPU well past the deadline (the read came back late): the time it
                    # was away is not the module's; it gets its reply time again, counted from now
                    renewed += 1
                    start = self.clock.now()
                    continue
                break
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("waiting for a reply", exc, address) from exc
        if data:
            self._heard.append((self.clock.now(), bytes(data)))
            self.trace.rx(self.clock.now(), data, "" if len(data) == n else f"short reply: {len(data)} of {n} bytes")
        return data

    def heard(self, since: float | None = None) -> str:
        """What came in since ``since`` (bus clock), in words for an error message."""
        chunks = [d for t, d in self._heard if since is None or t >= since]
        data = b"".join(chunks)
        if not data:
            return "nothing was received"
        shown = data[-24:].hex(" ")
        return (f"received {len(data)} byte{'s' if len(data) != 1 else ''} in {len(chunks)} "
                f"piece{'s' if len(chunks) != 1 else ''} ({'... ' if len(data) > 24 else ''}{shown})")

    def _late(self, text: str) -> None:
        """A late reply being retried while all stands still: counted and traced; a link warning only when the
        retry rate passes its threshold (see :mod:`cmm.nmc.link_health`)."""
        self.stats["late"] += 1
        self.trace.record(self.clock.now(), "rx", b"", f"late: {text}")
        alarm = self._rate.alarming(self.clock.now(), self.stats["transactions"], self.stats["retries"])
        if alarm:
            self._warn(f"{alarm}; last: {text}")

    def _count_window(self) -> None:
        n, total, _ = self._rate.window(self.clock.now(), self.stats["transactions"], self.stats["retries"])
        self.stats["window_retries"], self.stats["window_transactions"] = n, total

    def _warn(self, text: str) -> None:
        """A link warning: shown to the operator (the control state), nothing is stopped for it."""
        self.warning = (self.warning[0] + 1, text, self.clock.now())
        self.trace.record(self.clock.now(), "rx", b"", f"warning: {text}")

    def _waiting(self, address: int | None = None) -> int:
        try:
            return int(self.port.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("reading the port", exc, address) from exc

    def _read_some(self, timeout: float, address: int | None = None) -> bytes:
        """Whatever arrives within ``timeout``: waits for one byte, then takes what is there."""
        self._set_timeout(max(timeout, 0.0), address)
        try:
            data = self.port.read(1)
            if data:
                n = self.port.in_waiting
                if n:
                    data += self.port.read(n)
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("waiting for a reply", exc, address) from exc
        if data:
            self._heard.append((self.clock.now(), bytes(data)))
        return data

    def _set_host_baud(self, baud: int) -> None:
        try:
            self.port.baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            raise self._link_error(f"switching the port to {baud} baud", exc) from exc
        self.baud = baud

    def flush_input(self) -> None:
        try:
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise self._link_error("flushing the input", exc) from exc

    def _discard_stale(self, address: int | None) -> None:
        """Bytes waiting before a command are late or noise: never part of the coming reply."""
        n = self._waiting(address)
        if n:
            try:
                data = self.port.read(n)
            except (serial.SerialException, OSError) as exc:
                raise self._link_error("reading the port", exc, address) from exc
            self.stats["discarded"] += len(data)
            self._heard.append((self.clock.now(), bytes(data)))
            self.trace.rx(self.clock.now(), data, "stale bytes discarded")

    # --- one transaction ----------------------------------------------------------

    def _attempt(self, packet: bytes, items: int, wait: float | None = None) -> codec.Status | None:
        """Send once; the parsed reply, or None on time-out, garbage or surplus bytes. ``wait``: how long the
        reply may take (default Kerr's 50 ms + 2 ms per byte), counted from the moment the request left."""
        address = packet[1]
        self._discard_stale(address)
        self._sent_at = self.clock.now()
        self._write(packet, address)
        n = codec.status_length(items)
        data = self._read(n, address, self._reply_wait(items) if wait is None else wait, since=self.clock.now())
        if len(data) != n:
            return None
        self._note_trip(self.clock.now() - self._sent_at)
        try:
            status = codec.parse_status(data, items)
        except codec.CodecError:
            return None
        if self._waiting(address):  # more bytes than a reply: something else got mixed in
            self.stats["suspect"] += 1
            return None
        return status

    def _recent_trip(self) -> float:
        """The link's recent round trip: the largest seen, halved for every TRIP_HALF_LIFE s since."""
        return self._trip * 0.5 ** (max(self.clock.now() - self._trip_at, 0.0) / TRIP_HALF_LIFE)

    def _note_trip(self, seconds: float) -> None:
        """A round trip just seen (request sent to reply read)."""
        if seconds >= self._recent_trip():
            self._trip, self._trip_at = seconds, self.clock.now()

    def _reply_wait(self, items: int) -> float:
        """How long a reply of ``items`` may take now (see REPLY_ROUND_TRIPS)."""
        kerr = reply_timeout(codec.status_length(items))
        if not self.local:
            return kerr
        return min(max(kerr, REPLY_ROUND_TRIPS * self._recent_trip()), MARKER_WAIT)

    def _reply_items(self, address: int) -> int | None:
        """Items in the reply to a command sent to ``address``; None if nobody replies."""
        if address in self.items:
            return self.items[address]
        if address >= 0x80 and address in self.leaders:
            return self.items.get(self.leaders[address], 0)
        if address >= 0x80:
            return None
        return 0

    def _members(self, address: int) -> list[int]:
        if address < 0x80:
            return [address]
        return [a for a in (m.address for m in self.modules) if self.groups.get(a, codec.GROUP_ALL) == address]

    def _responder(self, address: int) -> int | None:
        """The individual address that answers commands sent to ``address``."""
        if address < 0x80:
            return address
        return self.leaders.get(address)

    def _read_home_before(self, packet: bytes) -> None:
        """Before arming a capture or SAVE_AS_HOME, read the home register and position if either is not known
        (after RESET_POS, a capture, a SAVE_AS_HOME; replies without position): should the reply be lost, a changed
        register tells the command took effect, and the position whether the axis stood still. One READ_STAT, only
        then (a group SET_HOMING is not checked after a lost reply, so not read for)."""
        address, code = packet[1], packet[2] & 0x0F
        if code == codec.SAVE_AS_HOME or (code == codec.SET_HOMING and address < 0x80 and len(packet) > 4
                                          and packet[3] & CAPTURE_BITS):
            for a in self._members(address):
                if (a not in self._home or a not in self._last) and a in self.items:
                    items = self.items[a] | codec.SEND_POS | codec.SEND_HOME
                    self.transact(codec.read_stat(a, items), items)

    def _before_send(self, packet: bytes) -> None:
        """Remember what a command sets up that a lost reply would have to be checked against."""
        address, code, data = packet[1], packet[2] & 0x0F, packet[3:-1]
        self._command_at = self.clock.now()
        members = self._members(address)
        if code == codec.START_MOVE or (code == codec.LOAD_TRAJ and data and data[0] & codec.START_NOW) or (
                code == codec.STOP_MOTOR and data and data[0] & codec.STOP_HERE):
            for a in members:
                self._calm[a] = 0  # it may move from now on, until its replies show it at rest
                last = self._last.get(a)
                if last is not None and last.status & codec.MOVE_DONE and a not in self._free:
                    self._held[a] = last
                else:
                    self._held.pop(a, None)
        # (any other STOP_MOTOR starts no motion: an axis standing still stays so, and a stop's missed reply is
        # retried as patiently as any other while all stands; STOP_HERE servos to a position: it may move)
        if code == codec.LOAD_TRAJ:
            try:
                lt = codec.parse_load_traj(data)
            except codec.CodecError:
                return
            for a in members:
                if lt.velocity is not None:
                    # 16.16 counts per tick -> counts per second (SR of 1: the fastest it can be)
                    self._vmax[a] = max(self._vmax.get(a, 0.0), lt.velocity / 65536 / codec.TICK_SECONDS)
                if lt.control & codec.START_NOW:
                    self._buffered.pop(a, None)
                    (self._free.discard if lt.control & codec.ENABLE_SERVO else self._free.add)(a)
                elif lt.position is not None and lt.control & codec.ENABLE_SERVO and not lt.control & codec.VEL_MODE:
                    self._buffered[a] = lt.position
                else:
                    self._buffered.pop(a, None)
        elif code == codec.SET_HOMING and data:
            for a in members:
                (self._armed.add if data[0] & CAPTURE_BITS else self._armed.discard)(a)
                self._before[a] = (self._last.get(a), self._home.get(a))
                if data[0] & CAPTURE_BITS:
                    self._capturing.add(a)
        elif code == codec.SAVE_AS_HOME:
            for a in members:
                self._before[a] = (self._last.get(a), self._home.pop(a, None))
        elif code == codec.STOP_MOTOR and data:
            for a in members:
                (self._free.add if data[0] & codec.MOTOR_OFF else self._free.discard)(a)
        elif code in (codec.RESET_POS, codec.HARD_RESET):
            for a in members:
                self._before[a] = (self._last.pop(a, None), self._home.pop(a, None))
                if code == codec.HARD_RESET:
                    self._free.add(a)

    def _plausible(self, address: int, status: codec.Status, code: int) -> bool:
        """Position continuity: a module under servo cannot have moved faster than it was ever told to.

        (In PWM mode or with the motor off nothing bounds the speed: no check.)"""
        if (status.position is None or address >= 0x80 or address in self._free
                or code in (codec.RESET_POS, codec.HARD_RESET)):
            return True
        last = self._last.get(address)
        if last is None:
            return True
        # the two samples lie between the previous request's send time and now: however late a reply is read
        dt = max(self.clock.now() - last[1], 0.0) + 0.002
        speed = max(self._vmax.get(address, 0.0) * 1.5, CONTINUITY_FLOOR)
        return abs(status.position - last[0]) <= speed * dt + CONTINUITY_MARGIN

    def _accept(self, address: int, status: codec.Status) -> codec.Status:
        responder = self._responder(address)
        if responder is not None:
            self._observe(responder, status)
        self._storm = 0
        return status

    def _observe(self, address: int, status: codec.Status) -> None:
        """Keep what a trusted reply of one module tells: its position, and its home register."""
        if status.position is not None:
            prev = self._last.get(address)
            if prev is None:  # a first reading tells no motion: as the commands sent left it
                pass
            elif abs(status.position - prev.position) <= REST_TOLERANCE and status.move_done:
                self._calm[address] = self._calm.get(address, 0) + 1
            else:
                self._calm[address] = 0
            self._last[address] = Reading(status.position, self._sent_at, status.velocity, status.status)
        if address in self._capturing and not status.home_in_progress:
            self._capturing.discard(address)  # its capture fired (or was disarmed): the home value may be new
            self._home.pop(address, None)
        if status.home is not None:
            self._home[address] = status.home

    def last_reading(self, address: int) -> Reading | None:
        """The last trusted reply that carried a position (None after a reset, until one comes)."""
        return self._last.get(address)

    def still(self) -> bool:
        """Does every axis stand still, as far as the commands sent and the replies read tell? (No motion
        command since, and its last reply showed it done and where the one before saw it.) Then a missed reply
        is retried patiently."""
        return all(self._calm.get(m.address, 1) > 0 for m in self.modules)

    def capture_armed(self, address: int) -> bool:
        """Was a home capture armed on ``address`` (SET_HOMING with a capture condition) and not disarmed?"""
        return address in self._armed

    def servoing(self, address: int) -> bool:
        """Is ``address`` under position servo as far as the commands sent tell (not motor off, not PWM)?"""
        return address not in self._free

    def preempt(self, *, urgent: bool = False) -> None:
        """A stop is waiting (any thread, no lock): a transaction that is patiently retrying a missed reply
        while every axis stands still gives up at its next wait (:class:`Preempted`, within ``PREEMPT_SLICE``),
        so the stop gets the link at once instead of after seconds of retries. Transactions sent after this
        call (the stop's own) are not affected. ``urgent`` (the link process's jog stop: a release or the
        dead-man) also cuts short the retries and resynchronisations of a transaction during motion: the stop
        goes out after the attempt in progress, and resynchronises the line itself if it has to."""
        if urgent:
            self._urgent += 1
        else:
            self._preempts += 1

    def _preempted(self) -> bool:
        """Has a stop asked for the link since the transaction in progress began (while all stands still,
        unless it was urgent)?"""
        busy = self._busy
        return busy is not None and (self._urgent != busy[1] or self._preempts != busy[0] and self.still())

    def _check_preempt(self, packet: bytes) -> None:
        if self._preempted():
            raise Preempted(f"the retry of {self._name(packet)} to {self._who(packet[1])} was cut short by a stop "
                            f"({self.heard(self._busy_since)})", packet[1])

    def clear_halt(self) -> None:
        """The station has carried the operator's stop out: motion starts pass again."""
        with self.lock:
            self.halt_latch = None

    def transact(self, packet: bytes, items: int | None = None) -> codec.Status | None:
        """Send a command packet and return the parsed status reply.

        ``items`` overrides the expected status items (READ_STAT). Group
        commands to a group without a leader return None after a short wait.
        Raises :class:`LinkError` if no trustworthy reply can be had, :class:`Preempted` when a stop cut
        short its patient retries (every axis standing still).
        """
        with self.lock:
            if self.halt_latch is not None and starts_motion(packet):
                raise Preempted(f"{self._name(packet)} to {self._who(packet[1])} was not sent: {self.halt_latch}",
                                packet[1])
            outer = self._busy is None
            if outer:
                self._busy, self._busy_since = (self._preempts, self._urgent), self.clock.now()
            try:
                return self._transact(packet, items)
            except LinkError as exc:
                if outer and self.link_up and self._preempted():  # a resynchronisation a stop cut short
                    raise Preempted(f"{self._name(packet)} to {self._who(packet[1])} was cut short by a stop "
                                    f"({exc})", packet[1]) from exc
                raise
            finally:
                if outer:
                    self._busy = None

    def _transact(self, packet: bytes, items: int | None) -> codec.Status | None:
        address = packet[1]
        code = packet[2] & 0x0F
        expected = self._reply_items(address) if items is None else items
        self._read_home_before(packet)
        self.stats["transactions"] += 1
        self._count_window()
        self._before_send(packet)
        if code == codec.HARD_RESET:  # never answered: the module is back at its power-up state
            expected = None
            for a in self._members(address):
                self.items.pop(a, None)
                self._capturing.discard(a)
        if expected is None:  # leaderless group or HARD_RESET: nobody answers
            self._discard_stale(address)
            self._write(packet, address)
            self.clock.sleep(LEADERLESS_WAIT)
            return None
        responder = self._responder(address)
        checksum_rejects = 0
        lost = 0
        first_sent = self._command_at
        wait = None  # Kerr's reply time-out; longer for each retry while the machine stands still
        while True:
            status = self._attempt(packet, expected, wait)
            if status is not None and responder is not None and not self._plausible(responder, status, code):
                status = self._confirm_jump(responder, status)
            if status is not None and status.cksum_error:  # not carried out: sending again is safe
                self.stats["retries"] += 1
                checksum_rejects += 1
                if checksum_rejects >= 2:
                    raise LinkError(f"{self._who(address)} rejected {self._name(packet)} twice with a checksum "
                                    "error: check the wiring and the baud rate", address, self.port_name)
                continue
            if status is not None:
                return self._accept(address, status)
            # no trustworthy reply: the command may or may not have been carried out
            self.stats["retries"] += 1
            lost += 1
            if self.still() and self.clock.now() - first_sent < IDLE_PATIENCE:
                # nothing moves: a slow answer costs only time. Retry, waiting longer each time, and say so;
                # a stop waiting for the link cuts this short
                self._check_preempt(packet)
                self._late(f"{self._who(address)} did not answer {self._name(packet)} in time ({lost}x, "
                           f"{self.heard(self._sent_at)}); retrying")
                self._resync_patiently(address, first_sent)
                self._check_preempt(packet)
                wait = max(min(reply_timeout(codec.status_length(expected)) * 2 ** lost, MAX_REPLY_WAIT),
                           self._reply_wait(expected))
                done = self._after_lost_reply(packet, expected)
                if done is not None:
                    return self._accept(address, done)
                continue
            self._check_preempt(packet)  # an urgent jog stop waits for the link: it goes first
            self._storm += 1
            if self._storm > STORM_LIMIT:
                raise LinkError(f"{STORM_LIMIT} commands in a row got no clean reply (last: {self._name(packet)} "
                                f"to {self._who(address)}): the link is failing", address, self.port_name)
            self.resync(address)
            if lost >= 3:
                raise LinkError(f"{self._who(address)} did not answer {self._name(packet)} at {self.baud} baud "
                                f"{lost} times in {self.clock.now() - first_sent:.1f} s although the link "
                                f"resynchronised ({self.heard(first_sent)}): check its power, cabling and "
                                "address", address, self.port_name)
            done = self._after_lost_reply(packet, expected)
            if done is not None:
                return self._accept(address, done)

    def _confirm_jump(self, address: int, suspect: codec.Status) -> codec.Status | None:
        """A reply that jumped: resynchronise and read the position again; keep the reply only if it agrees."""
        self.stats["suspect"] += 1
        t0 = sent = self._sent_at
        self.resync(address)
        check = self._attempt(codec.read_stat(address, codec.SEND_POS), codec.SEND_POS)
        if check is None or check.cksum_error or check.position is None or suspect.position is None:
            return None
        speed = max(self._vmax.get(address, 0.0) * 1.5, CONTINUITY_FLOOR)
        if abs(check.position - suspect.position) <= speed * (self.clock.now() - t0 + 0.02) + CONTINUITY_MARGIN:
            self._sent_at = sent  # the suspect reply is kept: its own request's time goes with it
            return suspect  # a real jump (a servo let go, a capture...): both readings agree
        return None

    @staticmethod
    def _who(address: int) -> str:
        return f"module {address}" if address < 0x80 else f"group {address:#04x} leader"

    @staticmethod
    def _name(packet: bytes) -> str:
        return codec.COMMAND_NAMES[packet[2] & 0x0F]

    # --- after a lost reply: resend, or check what the module did --------------

    def _after_lost_reply(self, packet: bytes, items: int) -> codec.Status | None:
        """The line is clean again. None: send the command again. A status: it was carried out.

        Motion starts are never blindly sent twice: START_MOVE and a started
        position move are checked on the modules (moving, or already at the
        goal: done; at rest where they were: not done, send again; anything
        else: a LinkError, the caller stops the machine). SET_HOMING,
        SAVE_AS_HOME and RESET_POS are judged from the status, position and
        home register (``_check_homing``, ``_check_save_as_home``,
        ``_check_reset``); a position reset never runs twice.
        """
        address, code = packet[1], packet[2] & 0x0F
        name, who = self._name(packet), self._who(address)
        if code in RESEND_SAFE:
            return None
        if code == codec.SET_ADDR and address < 0x80 and packet[3] == address:
            return None  # a module keeping its address and joining a group: the same again is harmless
        if code == codec.SET_HOMING and not packet[3] & CAPTURE_BITS:
            return None  # disarming twice is harmless
        if code == codec.SET_HOMING and address < 0x80:
            return self._check_homing(address, name, who, coasting=bool(packet[3] & codec.HOME_MOTOR_OFF))
        if code == codec.SAVE_AS_HOME:
            return self._check_members(address, name, who, self._check_save_as_home)
        if code == codec.RESET_POS:
            return self._check_members(address, name, who, lambda a: self._check_reset(a, packet))
        goals: dict[int, int] = {}
        if code == codec.LOAD_TRAJ:
            try:
                lt = codec.parse_load_traj(packet[3:-1])
            except codec.CodecError:
                return None
            moves = lt.control & codec.START_NOW and lt.control & codec.ENABLE_SERVO and not lt.control & codec.VEL_MODE
            if not moves:
                return None  # a buffered load, a velocity or PWM setting: the same again is harmless
            if lt.position is None or address >= 0x80:
                raise self._unsure(name, who, address)
            goals = {address: lt.position}
        elif code == codec.START_MOVE:
            goals = {a: self._buffered[a] for a in self._members(address) if a in self._buffered}
            if not goals:
                return None  # nothing buffered to start: sending it again starts nothing
        else:
            raise self._unsure(name, who, address)
        started, at_rest = [], []
        for a, goal in goals.items():
            last = self._last.get(a)
            if last is not None and abs(goal - last[0]) <= GOAL_TOLERANCE:
                continue  # this axis does not move: it tells nothing
            st = self._query(a, codec.SEND_POS)
            held = self._held.get(a)
            if not st.move_done or abs((st.position or 0) - goal) <= GOAL_TOLERANCE:
                started.append(a)
            elif held is not None and abs((st.position or 0) - held.position) > REST_TOLERANCE:
                # it stood under servo before the command and now stands elsewhere: nothing else moves it, so
                # the command was carried out and something stopped it short (a probe touch on a loaded host
                # whose reply came late: the capture stopped the axis before the bus asked)
                started.append(a)
            elif (last is not None and abs((st.position or 0) - last[0]) <= REST_TOLERANCE and not st.pos_error
                  and not (a in self._armed and not st.home_in_progress)):
                at_rest.append(a)
            else:
                raise self._unsure(name, who, address)
        self.stats["verified"] += 1
        if started and at_rest:
            raise self._unsure(name, who, address)
        if at_rest:
            return None  # nothing started: sending it again starts it once
        for a in goals:
            self._buffered.pop(a, None)
        responder = self._responder(address)
        if responder is None:
            raise self._unsure(name, who, address)
        return self._query(responder, self.items.get(responder, 0))

    def _home_query(self, address: int) -> codec.Status:
        """The module's usual reply items plus position and home register, read after a lost reply."""
        st = self._query(address, self.items.get(address, 0) | codec.SEND_POS | codec.SEND_HOME)
        self.stats["verified"] += 1
        self._observe(address, st)
        return st

    def _settled(self, address: int, st: codec.Status) -> bool:
        """At rest from the last reply before the command until now (move done, same position)."""
        last = self._before.get(address, (None, None))[0]
        return (last is not None and st.move_done and st.position is not None
                and abs(st.position - last[0]) <= REST_TOLERANCE)

    def _passed(self, address: int, value: int, st: codec.Status, *, coasting: bool = False) -> bool:
        """Could the axis have been at ``value`` at some moment since the command was sent (so a capture or a
        SAVE_AS_HOME there may have latched it)? ``st`` is a status read after the command.

        Under servo an axis moves no faster than the fastest speed it was given (the continuity bound): from
        where the last reply before the command saw it, to ``value``, to where ``st`` sees it. ``coasting``
        (the capture switches the motor off): only the way there bounds it. In PWM mode, with the motor off
        or after a position error (the servo let go, maybe before the command) nothing does.
        """
        if address in self._free or st.position is None or st.pos_error:
            return True
        speed = max(self._vmax.get(address, 0.0) * 1.5, CONTINUITY_FLOOR)
        now = self.clock.now() + 0.002
        last = self._before.get(address, (None, None))[0]
        if coasting:
            return last is None or abs(value - last[0]) <= speed * (now - last[1]) + CONTINUITY_MARGIN
        if abs(value - st.position) > speed * (now - self._command_at) + CONTINUITY_MARGIN:
            return False
        return last is None or (abs(value - last[0]) + abs(value - st.position)
                                <= speed * (now - last[1]) + 2 * CONTINUITY_MARGIN)

    def _check_homing(self, address: int, name: str, who: str, *, coasting: bool = False) -> codec.Status | None:
        """A lost reply to SET_HOMING (arming a capture): armed, armed and fired already, or not carried out.

        Fired: the home register changed since it was last read (it is read
        before arming when unknown; the caller then sees the capture as if the
        reply had come: HOME_IN_PROG clear). Not carried out: not armed and the
        home register holds nothing latched since the command: no position the
        axis can have passed (``_passed``), or at rest all along and not where
        it stands. Re-arming is harmless only then: after a capture it would
        hide the touch.
        """
        st = self._home_query(address)
        if st.home_in_progress:
            return st  # armed, as asked
        home_before = self._before.get(address, (None, None))[1]
        if home_before is not None and st.home != home_before:
            return st  # armed, and it fired already
        if st.home is not None and not self._passed(address, st.home, st, coasting=coasting):
            return None  # not armed and nothing latched since: it was not carried out, send it again
        if self._settled(address, st) and abs((st.home or 0) - (st.position or 0)) > REST_TOLERANCE:
            return None  # not armed and nothing latched: it was not carried out, send it again
        raise self._unsure(name, who, address)

    def _check_save_as_home(self, address: int) -> tuple[str, codec.Status]:
        """SAVE_AS_HOME: at rest it is harmless twice (the same position again); moving, a changed home register
        tells it was done (it is read before the command when unknown), one holding no position the axis can
        have passed since the command that it was not (sent again: once)."""
        st = self._home_query(address)
        home_before = self._before.get(address, (None, None))[1]
        if self._settled(address, st):
            return ("done" if abs((st.home or 0) - (st.position or 0)) <= REST_TOLERANCE else "not done"), st
        if home_before is not None and st.home != home_before:
            return "done", st
        if st.home is not None and not self._passed(address, st.home, st):
            return "not done", st
        return "unsure", st

    def _check_reset(self, address: int, packet: bytes) -> tuple[str, codec.Status]:
        """RESET_POS: at rest, the position reads either the new value (done) or the old one (not done).

        Never sent twice unless the module shows it was not carried out: when
        the old and the new reading are too close to tell apart, it is unsure.
        """
        last, home_before = self._before.get(address, (None, None))
        data = packet[3:-1]
        if len(data) == 5 and data[0] & codec.RESET_SET_POS:
            target: int | None = int.from_bytes(data[1:5], "little", signed=True)
        elif data and data[0] & codec.RESET_REL_HOME:
            target = None if last is None or home_before is None else last[0] - home_before
        else:
            target = 0
        st = self._query(address, self.items.get(address, 0) | codec.SEND_POS)
        self.stats["verified"] += 1
        if last is None or target is None or not st.move_done or st.position is None:
            return "unsure", st
        old, now = last[0], st.position
        if old == target and abs(now - target) <= REST_TOLERANCE:
            return "done", st  # already there: done or not, the counter reads the same
        if abs(old - target) <= 2 * REST_TOLERANCE:
            return "unsure", st
        if abs(now - target) <= REST_TOLERANCE:
            return "done", st
        if abs(now - old) <= REST_TOLERANCE:
            return "not done", st
        return "unsure", st

    def _check_members(self, address: int, name: str, who: str, check) -> codec.Status | None:  # noqa: ANN001
        """Run a per-module check on every module the command went to: all done, all not done, or a LinkError."""
        verdicts = [check(a) for a in self._members(address)]
        kinds = {v for v, _ in verdicts}
        if kinds == {"not done"}:
            return None  # carried out nowhere: sending it again does it once
        if kinds != {"done"}:
            raise self._unsure(name, who, address)
        responder = self._responder(address)
        if responder is None:
            raise self._unsure(name, who, address)
        st = self._query(responder, self.items.get(responder, 0))
        self._observe(responder, st)
        return st

    def _unsure(self, name: str, who: str, address: int) -> LinkError:
        return LinkError(f"the reply of {who} to {name} was lost and whether it was carried out cannot be told, "
                         "so it was not sent again: stop the machine and check its state", address, self.port_name,
                         module_only=True)

    def _query(self, address: int, items: int) -> codec.Status:
        """A read-only READ_STAT, resynchronising once if needed."""
        for _ in range(2):
            st = self._attempt(codec.read_stat(address, items), items)
            if st is not None and not st.cksum_error:
                return st
            self.resync(address)
        raise LinkError(f"module {address} did not answer a status read after a resynchronisation: the link is "
                        "failing", address, self.port_name)

    # --- resynchronisation ------------------------------------------------------------

    def _resync_patiently(self, address: int | None, since: float) -> None:
        """:meth:`resync`, retried (each a warning) while the machine stands still, until IDLE_PATIENCE s after
        ``since``; a port failure is never retried."""
        while True:
            try:
                self.resync(address)
                return
            except LinkError as exc:
                if self._preempted():
                    raise Preempted(f"a resynchronisation was cut short by a stop ({exc})", address) from exc
                if not self.link_up or not self.still() or self.clock.now() - since >= IDLE_PATIENCE:
                    raise
                # the markers went unanswered too: replies are being lost, not merely late
                self._warn(f"the link did not answer for {self.clock.now() - since:.1f} s ({exc}); retrying")

    def resync(self, address: int | None = None) -> None:
        """Regain the link so that no late reply can be taken for the next one.

        Nulls complete a torn packet (its reply fails its checksum) and abort a
        reply in progress; then a marker to the module that may owe a late
        reply; everything up to the marker's reply is discarded. Without a
        known module: Kerr's quiet wait and flush.
        """
        with self.lock:
            self.stats["resyncs"] += 1
            targets = self._marker_targets(address)
            if not targets:
                self._write(bytes(NULLS_RESYNC))
                self.clock.sleep(RESYNC_WAIT)
                self.flush_input()
                return
            first = targets[0]
            began = self.clock.now()
            self._write(bytes(NULLS_RESYNC), first)
            if self._marker(first, MARKER_WAIT):
                return
            for other in targets[1:2]:  # is it the module or the link?
                self._write(bytes(NULLS_RESYNC), other)
                if self._marker(other, MARKER_WAIT):
                    self._write(bytes(NULLS_RESYNC), first)
                    if self._marker(first, SHORT_MARKER_WAIT):  # the line is clean now: no need to wait long
                        return
                    raise LinkError(f"module {first} stopped answering (module {other} still answers): "
                                    "check its power and cabling", first, self.port_name, module_only=True)
            self._write(bytes(NULLS_RESYNC), first)
            if self._marker(first, MARKER_WAIT):
                return
            raise LinkError(f"no module answers on {self.port_name} any more (no reply for "
                            f"{2 * MARKER_WAIT + (MARKER_WAIT if len(targets) > 1 else 0):.1f} s; "
                            f"{self.heard(began)}): the link is down; check the cable, the adapter and the module "
                            "power", first, self.port_name)

    def _marker_targets(self, address: int | None) -> list[int]:
        known = [m.address for m in self.modules]
        first = self._responder(address) if address is not None else None
        out = [first] if first is not None and first in known else []
        return out + [a for a in known if a not in out]

    def _marker(self, address: int, wait: float, info: ModuleInfo | None = None) -> bool:
        """Send a marker to ``address``; True once its reply has come, last on a quiet line."""
        normal = codec.status_length(self.items.get(address, 0))
        for _ in MARKER_ITEMS:
            items = MARKER_ITEMS[self._marker_turn % len(MARKER_ITEMS)]
            self._marker_turn += 1
            if codec.status_length(items) != normal:
                break
        n = codec.status_length(items)
        if info is None:
            info = next((m for m in self.modules if m.address == address), None)
        self._write(codec.read_stat(address, items), address)
        buf = bytearray()
        sent = self.clock.now()
        away = 0.0  # time this process was off the CPU while waiting: not the link's
        deadline = sent + wait
        while True:
            left = deadline - self.clock.now()
            if left <= 1e-4:  # (a clock that counts whole nanoseconds never reaches a float deadline exactly)
                if buf:
                    self.stats["discarded"] += len(buf)
                return False
            if self._preempted():  # a stop waits for the link: its own stops resynchronise as they go
                return False
            asked = self.clock.now()
            step = min(left, PREEMPT_SLICE)
            chunk = self._read_some(step, address)
            late = self.clock.now() - asked - step
            if late > OVERSLEPT:  # this process was off the CPU meanwhile: that time is not the module's
                deadline += late
                away += late
            if not chunk:
                continue
            buf += chunk
            if not self._is_marker(bytes(buf[-n:]), items, info):
                continue
            self._note_trip(self.clock.now() - sent - away)
            extra = self._read_some(QUIET_CONFIRM, address)
            if extra:  # the marker pattern was not the end: keep reading
                buf += extra
                continue
            stale = len(buf) - n
            self.stats["discarded"] += stale
            if stale:
                self.trace.record(self.clock.now(), "rx", bytes(buf[:stale]),
                                  f"resynchronised on module {address}: {stale} stale bytes discarded")
            return True

    @staticmethod
    def _is_marker(data: bytes, items: int, info: ModuleInfo | None) -> bool:
        try:
            st = codec.parse_status(data, items)
        except codec.CodecError:
            return False
        if st.cksum_error:
            return False
        if info is not None:
            return st.module_type == info.module_type and st.version == info.version
        return True  # while addressing the chain: length, checksum and status are all there is

    # --- stopping on a failing link ---------------------------------------------------

    def stop_all(self, mode: str = "abrupt", *, latch: str | None = None) -> StopReport:
        """Stop every axis however bad the link is; never raises. Says which modules acknowledged.

        First a burst that asks for no reply (nulls, STOP_MOTOR to every group
        and every module, back to back: the fastest way to reach a module on a
        noisy line), then an acknowledged STOP_MOTOR to each module.
        ``mode``: "abrupt" (servo holds where it is), "smooth" (decelerate at the loaded acceleration; an axis
        without servo, motor off or PWM, is left as it is: a stop would switch its servo on) or "off" (motor off).
        ``latch``: the operator's stop (why, in words): motion starts are refused until :meth:`clear_halt`, and a
        transaction retrying a lost reply gives the link up to this stop at once (also during motion).
        """
        control = {"off": codec.MOTOR_OFF, "smooth": codec.STOP_SMOOTH | codec.AMP_ENABLE}.get(
            mode, codec.STOP_ABRUPT | codec.AMP_ENABLE)
        if latch is not None:
            self.halt_latch = latch  # before the lock: a start waiting for it is refused, not sent
            self.preempt(urgent=True)
        addresses = [m.address for m in self.modules]
        groups = sorted({codec.GROUP_ALL, *self.groups.values()})
        if mode == "smooth" and not all(self.servoing(a) for a in addresses):
            addresses, groups = [a for a in addresses if self.servoing(a)], []
        reason = ""
        with self.lock:
            if latch is not None:
                self.halt_latch = latch
            burst = bytearray(NULLS_RESYNC)
            for g in groups:
                burst += codec.stop_motor(g, control)
            for a in addresses:
                burst += codec.stop_motor(a, control)
            try:
                self._write(bytes(burst))
                self.clock.sleep(0.01)
                self.flush_input()
            except LinkError as exc:
                reason = str(exc)
            acked, silent = [], []
            self._storm = 0  # a stop deserves its own resynchronisations
            for i, a in enumerate(addresses):
                try:
                    st = self.transact(codec.stop_motor(a, control))
                    (acked if st is not None else silent).append(a)
                except NmcError as exc:
                    silent.append(a)
                    reason = reason or str(exc)
                    if isinstance(exc, LinkError) and not exc.module_only:  # the link is down: do not wait per module
                        silent += addresses[i + 1:]
                        break
            return StopReport(tuple(acked), tuple(silent), reason)

    # --- network set-up ---------------------------------------------------------------

    def _reset_at(self, baud: int) -> None:
        """Nulls and HARD_RESET (no reply) at ``baud`` to every address a module can be reached at.

        A module answers its individual address whatever group it is in, so
        resetting 0..MAX_MODULES and group 0xFF reaches every module this
        driver (or Kerr's library) can have addressed.
        """
        self._set_host_baud(baud)
        burst = bytearray(NULLS_INIT)
        burst += codec.hard_reset(codec.GROUP_ALL) * 2
        for a in range(MAX_MODULES + 1):
            burst += codec.hard_reset(a)
        for g in sorted(set(self.groups.values()) | {0x80}):
            burst += codec.hard_reset(g)
        self._write(bytes(burst))
        self.clock.sleep(0.1)
        self._set_host_baud(codec.POWER_UP_BAUD)
        self.flush_input()

    def _discover(self, expected: int | None = None) -> list[int]:
        """Address the chain one module at a time; each step checked, not assumed. Up to ``expected`` modules
        a missing answer is waited for longer (the chain is known to go on: a slow answer is not its end)."""
        found: list[int] = []
        for addr in range(1, MAX_MODULES + 1):
            waits = DISCOVERY_WAITS if expected is not None and addr <= expected else (DISCOVERY_WAIT, DISCOVERY_WAIT)
            if not self._address_next(addr, found, waits):
                break
            found.append(addr)
            self.items[addr] = 0
        return found

    def _address_next(self, addr: int, found: list[int], waits: tuple[float, ...] = (DISCOVERY_WAIT,) * 2) -> bool:
        """SET_ADDR to the module at 0; a lost reply is told apart from the end of the chain. One try per
        entry of ``waits``: how long the marker waits for a late reply."""
        for wait in waits:
            reply = self._attempt(codec.set_addr(0x00, addr, codec.GROUP_ALL), 0)
            if reply is not None and not reply.cksum_error:
                return True
            if reply is not None:
                continue  # rejected with a checksum error: not carried out
            # no reply: the end of the chain, or a late reply. A marker to the new address tells:
            # a module there took it (and the line is clean once its reply is in).
            self._write(bytes(NULLS_RESYNC))
            if self._marker(addr, wait):
                return True
            self.flush_input()
        return False

    def initialize(
        self,
        baud: int | None = None,
        *,
        expected_modules: int | None = None,
        module_type: int = codec.PIC_SERVO_TYPE,
        versions: tuple[int, ...] | None = None,
    ) -> list[ModuleInfo]:
        """The full NMC start-up: reset, address chain, type check, baud change.

        Works whatever state an earlier run left the modules in (any address,
        group, baud rate, servo on): they are reset at the power-up rate and,
        if the chain is not all there, at every rate the firmware knows.
        Discovery is repeated while it finds fewer modules than expected.
        """
        expected = expected_modules if expected_modules is not None else self.expected_modules
        with self.lock:
            self.link_up = True
            found: list[int] = []
            began = self.clock.now()
            seen: list[int] = []  # modules found by each discovery
            for attempt in range(DISCOVERY_ATTEMPTS):
                self.items.clear()
                self.leaders.clear()
                self._last.clear()
                self._held.clear()
                self._buffered.clear()
                self._armed.clear()
                self._free.clear()
                self._home.clear()
                self._capturing.clear()
                self._before.clear()
                self._calm.clear()
                self.modules = []
                bauds = [codec.POWER_UP_BAUD] if attempt == 0 else [
                    *(b for b in codec.BAUD_DIVISORS[self.firmware] if b != codec.POWER_UP_BAUD), codec.POWER_UP_BAUD]
                for b in bauds:
                    self._reset_at(b)
                self.groups.clear()
                found = self._discover(expected)
                seen.append(len(found))
                self._free.update(found)  # power-up state: PWM mode until a servo command
                if found and (expected is None or len(found) == expected):
                    break
            if not found:
                raise LinkError(f"no PIC-SERVO module answered at address 0 at any baud rate in {len(seen)} "
                                f"attempts over {self.clock.now() - began:.1f} s ({self.heard(began)}): check power, "
                                f"cabling and the port ({self.port_name})", 0, self.port_name)
            if expected is not None and len(found) != expected:
                counts = str(seen[0]) if len(set(seen)) == 1 else f"{', '.join(map(str, seen[:-1]))} and {seen[-1]}"
                raise NmcError(f"expected {expected} modules on the network, found {counts} in {len(seen)} attempts "
                               f"over {self.clock.now() - began:.1f} s: check the address chain (ADDR_IN/ADDR_OUT) "
                               "wiring")
            modules = []
            for addr in found:  # type and version; the home register too (see _check_homing)
                st = self.transact(codec.read_stat(addr, codec.SEND_ID | codec.SEND_HOME),
                                   codec.SEND_ID | codec.SEND_HOME)
                assert st is not None
                if st.module_type != module_type:
                    raise NmcError(f"module {addr} is of type {st.module_type}, expected {module_type} (PIC-SERVO)", addr)
                if versions is not None and st.version not in versions:
                    raise NmcError(f"module {addr} has firmware version {st.version}, expected one of {versions}", addr)
                modules.append(ModuleInfo(addr, st.module_type, st.version))
            self.modules = modules
            if baud is not None and baud != self.baud:
                self.change_baud(baud)
            return list(modules)

    def change_baud(self, baud: int) -> None:
        """SET_BAUD to every module (group 0xFF, no leader), switch the host, verify each module."""
        divisor = codec.baud_divisor(baud, self.firmware)
        with self.lock:
            self._write(codec.set_baud(codec.GROUP_ALL, divisor))
            self.clock.sleep(BAUD_SWITCH_WAIT)
            self._set_host_baud(baud)
            self.flush_input()
            for info in self.modules:
                items = self.items.get(info.address, 0)
                since = self.clock.now()
                wait = None
                for tries in range(1, 100):
                    if self._attempt(codec.nop(info.address), items, wait) is not None:
                        break
                    if tries >= 2 and (not self.still() or self.clock.now() - since >= IDLE_PATIENCE):
                        raise LinkError(f"module {info.address} does not answer at {baud} baud after SET_BAUD "
                                        f"({tries} tries in {self.clock.now() - since:.1f} s; "
                                        f"{self.heard(since)})", info.address, self.port_name)
                    self._resync_patiently(info.address, since)
                    wait = min(reply_timeout(codec.status_length(items)) * 2 ** tries, MAX_REPLY_WAIT)

    def release(self) -> None:
        """Leave every module in its power-up state (motor off, address 0, group 0xFF, 19200 baud).

        HARD_RESET goes to each module's individual address and group, so the
        next start-up (this driver's or Kerr's) finds a fresh chain.
        """
        with self.lock:
            burst = bytearray(NULLS_RESYNC)
            for m in reversed(self.modules):
                burst += codec.hard_reset(m.address)
            for g in sorted({codec.GROUP_ALL, *self.groups.values()}):
                burst += codec.hard_reset(g)
            self._write(bytes(burst))
            self.clock.sleep(0.1)
            self._set_host_baud(codec.POWER_UP_BAUD)
            self.flush_input()
            self.modules = []
            self.items.clear()
            self.leaders.clear()
            self.groups.clear()

    def reopen(self) -> list[ModuleInfo]:
        """After a link error: open the port again if it failed, and check every known module still answers.

        The modules keep their addresses, rate and positions (nothing is
        reset); raises :class:`LinkError` if the port or a module stays away.
        """
        with self.lock:
            if isinstance(self._url, str) and not self.link_up:  # the port failed: open it again
                try:
                    self.port.close()
                except (serial.SerialException, OSError):
                    pass
                self.port, self.clock = open_port(self._url, self.baud, reply_timeout(2))
            self.link_up = True
            self._storm = 0
            self.flush_input()
            for info in self.modules:
                self.resync(info.address)
            self._last.clear()
            self._held.clear()
            return list(self.modules)

    def set_group(self, address: int, group: int, *, leader: bool = False) -> None:
        """Put a module in a group (0x80..0xFF); at most one leader per group."""
        with self.lock:
            self.transact(codec.set_addr(address, address, group, leader=leader))
            self.groups[address] = group
            for g, a in list(self.leaders.items()):
                if a == address:
                    del self.leaders[g]
            if leader:
                self.leaders[group] = address

    def define_status(self, address: int, items: int) -> codec.Status | None:
        """DEF_STAT: the reply to this command already carries the new items."""
        with self.lock:
            status = self.transact(codec.def_stat(address, items), items if address < 0x80 else None)
            targets = [address] if address < 0x80 else [m.address for m in self.modules]
            for a in targets:
                self.items[a] = items
            return status

    def group(self, group: int, packet_builder) -> codec.Status | None:
        """Send ``packet_builder(group)`` to a group; the leader's reply, or None."""
        return self.transact(packet_builder(group))

    def start_move(self, group: int = codec.GROUP_ALL) -> codec.Status | None:
        """START_MOVE to a group: every member starts on the same servo tick."""
        return self.transact(codec.start_move(group))
