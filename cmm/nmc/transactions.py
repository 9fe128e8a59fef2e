"""One command, one reply for :class:`~cmm.nmc.bus.Bus`: what a command sets up that a lost reply would be
checked against, position continuity, what a trusted reply tells (positions, home register, rest), stops
that cut a patient retry short, and the retry loop of a transaction."""

from __future__ import annotations

from . import codec
from .bus_types import (
    CAPTURE_BITS, CONTINUITY_FLOOR, CONTINUITY_MARGIN, IDLE_PATIENCE, LEADERLESS_WAIT, MAX_REPLY_WAIT,
    REST_TOLERANCE, STORM_LIMIT, LinkError, Preempted, Reading, reply_timeout, starts_motion,
)


class Transactions:
    """Transactions of the bus and the state they keep per module (a part of :class:`~cmm.nmc.bus.Bus`)."""

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
