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
:mod:`cmm.nmc.lost_reply`). Every port failure surfaces as :class:`LinkError`.

A slow host is not a failed link: a reply's time-out counts from the moment the request left and never
passes over bytes already in the port's buffer; a read that came back well past its deadline (the process
was off the CPU) gives the reply its time again. While every axis stands still (:meth:`Bus.still`) a
missed reply is retried with doubling waits, each retry a link warning (``Bus.warning``), for up to
IDLE_PATIENCE s; during motion the limits stay strict (three lost replies to one command, STORM_LIMIT
commands in a row, a marker that does not come back).

The bus is one class assembled from one module per job: :mod:`~cmm.nmc.framing` (bytes on the port),
:mod:`~cmm.nmc.transactions` (one command, one reply), :mod:`~cmm.nmc.lost_reply` (was a command whose reply
was lost carried out?), :mod:`~cmm.nmc.resync` (a clean line again) and :mod:`~cmm.nmc.startup` (the network
set up and left); its vocabulary (errors, readings, times and limits) is :mod:`~cmm.nmc.bus_types`.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

from . import codec
from .bus_types import (
    HEARD_KEEP, IDLE_PATIENCE, NULLS_RESYNC, LinkError, ModuleInfo, NmcError, Preempted, Reading, StopReport,
    _port_name, local_peer, reply_timeout, starts_motion,
)
from .framing import Framing
from .link_health import RetryRate
from .lost_reply import LostReplyChecks
from .resync import Resynchronisation
from .startup import StartUp
from .trace import ByteTrace
from .transactions import Transactions
from .transport import open_port

# the bus's public names: its errors and readings live in bus_types, imported from here by its users
__all__ = ["Bus", "IDLE_PATIENCE", "LinkError", "ModuleInfo", "NmcError", "Preempted", "Reading", "StopReport",
           "local_peer", "reply_timeout", "starts_motion"]


class Bus(Framing, Transactions, LostReplyChecks, Resynchronisation, StartUp):
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
    def group(self, group: int, packet_builder) -> codec.Status | None:
        """Send ``packet_builder(group)`` to a group; the leader's reply, or None."""
        return self.transact(packet_builder(group))

    def start_move(self, group: int = codec.GROUP_ALL) -> codec.Status | None:
        """START_MOVE to a group: every member starts on the same servo tick."""
        return self.transact(codec.start_move(group))
