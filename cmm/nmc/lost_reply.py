"""After a lost reply, for :class:`~cmm.nmc.bus.Bus`: send the command again when doing it twice is
harmless, else tell from the module (status, position, home register) whether it was carried out; never run a
motion start or a position reset twice."""

from __future__ import annotations

from . import codec
from .bus_types import (
    CAPTURE_BITS, CONTINUITY_FLOOR, CONTINUITY_MARGIN, GOAL_TOLERANCE, RESEND_SAFE, REST_TOLERANCE, LinkError,
)


class LostReplyChecks:
    """Whether a command whose reply was lost was carried out (a part of :class:`~cmm.nmc.bus.Bus`)."""

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
