"""Per-module operations on one PIC-SERVO, in raw units (counts, ticks, 16.16)."""

from __future__ import annotations

from . import codec
from .bus import Bus, NmcError

STOP_MODES = {
    "abrupt": codec.STOP_ABRUPT | codec.AMP_ENABLE,
    "smooth": codec.STOP_SMOOTH | codec.AMP_ENABLE,
    "off": codec.MOTOR_OFF,  # servo and PWM off, amplifier disabled
    "here": codec.STOP_HERE | codec.AMP_ENABLE,
}

HOME_TRIGGERS = {
    "limit1": codec.ON_LIMIT1,
    "limit2": codec.ON_LIMIT2,
    "index": codec.ON_INDEX,
    "pos_error": codec.ON_POS_ERR,
    "overcurrent": codec.ON_CUR_ERR,
}
HOME_ACTIONS = {"none": 0, "abrupt": codec.HOME_STOP_ABRUPT, "smooth": codec.HOME_STOP_SMOOTH, "off": codec.HOME_MOTOR_OFF}

DEFAULT_ITEMS = codec.SEND_POS | codec.SEND_AUX


class Module:
    """One PIC-SERVO module at an individual address on a :class:`Bus`."""

    def __init__(self, bus: Bus, address: int) -> None:
        self.bus = bus
        self.address = address
        self.last: codec.Status | None = None
        self.gains: codec.Gains | None = None

    def __repr__(self) -> str:
        return f"Module({self.address})"

    def _send(self, packet: bytes, items: int | None = None) -> codec.Status:
        status = self.bus.transact(packet, items)
        if status is None:  # only group commands go unanswered
            raise NmcError(f"module {self.address} gave no reply", self.address)
        if items is None or items == self.bus.items.get(self.address, 0):
            self.last = status
        return status

    # --- status -----------------------------------------------------------

    def define_status(self, items: int = DEFAULT_ITEMS) -> codec.Status:
        status = self.bus.define_status(self.address, items)
        assert status is not None
        self.last = status
        return status

    def nop(self) -> codec.Status:
        """Read the permanently defined status items."""
        return self._send(codec.nop(self.address))

    def read_status(self, items: int) -> codec.Status:
        """READ_STAT: one reply with ``items``; later replies revert to DEF_STAT's set."""
        return self._send(codec.read_stat(self.address, items), items)

    def position(self) -> int:
        return self._item(codec.SEND_POS, "position")

    def velocity(self) -> int:
        """Actual velocity in counts per tick (integer part)."""
        return self._item(codec.SEND_VEL, "velocity")

    def home_position(self) -> int:
        return self._item(codec.SEND_HOME, "home")

    def aux(self) -> int:
        return self._item(codec.SEND_AUX, "aux")

    def ad(self) -> int:
        return self._item(codec.SEND_AD, "ad")

    def _item(self, mask: int, name: str) -> int:
        st = self.nop() if self.bus.items.get(self.address, 0) & mask else self.read_status(mask)
        return getattr(st, name)

    # --- configuration ----------------------------------------------------

    def set_gains(self, gains: codec.Gains) -> codec.Status:
        status = self._send(codec.set_gain(self.address, gains))
        self.gains = gains
        return status

    def enable(self) -> codec.Status:
        """Amplifier on and servo holding the present position."""
        return self._send(codec.stop_motor(self.address, codec.AMP_ENABLE | codec.STOP_ABRUPT))

    def plain_inputs(self) -> codec.Status:
        """LIMIT1 and LIMIT2 as inputs with no action of their own, in this bus's firmware's IO_CTRL byte."""
        return self._send(codec.io_ctrl(self.address, codec.plain_inputs_io(self.bus.firmware)))

    def io_control(self, *, limit1_input: bool = True, limit2_input: bool = True, limit1_out: bool = False,
                   limit2_out: bool = False) -> codec.Status:
        """IO_CTRL in the original firmware's meaning (pin directions); on SC firmware see :meth:`plain_inputs`."""
        control = (codec.IO_LIMIT1_IN if limit1_input else 0) | (codec.IO_LIMIT2_IN if limit2_input else 0)
        control |= (codec.IO_LIMIT1_OUT if limit1_out else 0) | (codec.IO_LIMIT2_OUT if limit2_out else 0)
        return self._send(codec.io_ctrl(self.address, control))

    def clear_bits(self) -> codec.Status:
        return self._send(codec.clear_bits(self.address))

    def reset_position(self) -> codec.Status:
        return self._send(codec.reset_pos(self.address))

    def save_as_home(self) -> codec.Status:
        return self._send(codec.save_as_home(self.address))

    def set_group(self, group: int, *, leader: bool = False) -> None:
        self.bus.set_group(self.address, group, leader=leader)

    # --- motion -------------------------------------------------------------

    def load_position(self, position: int, velocity: int, acceleration: int, *, start: bool = True) -> codec.Status:
        """Trapezoidal move to ``position`` counts (16.16 velocity and acceleration)."""
        return self._send(codec.load_traj(self.address, position=position, velocity=velocity,
                                          acceleration=acceleration, start_now=start))

    def load_velocity(self, velocity: int, acceleration: int, *, start: bool = True) -> codec.Status:
        """Velocity mode: signed 16.16 target velocity, reached at ``acceleration``."""
        return self._send(codec.load_traj(self.address, velocity=abs(velocity), acceleration=acceleration,
                                          velocity_mode=True, reverse=velocity < 0, start_now=start))

    def load_pwm(self, pwm: int, *, reverse: bool = False, start: bool = True) -> codec.Status:
        """PWM mode: servo off, duty 0..255 straight to the amplifier."""
        return self._send(codec.load_traj(self.address, pwm=pwm, servo=False, reverse=reverse, start_now=start))

    def start(self) -> codec.Status:
        """START_MOVE to this module alone (a buffered trajectory)."""
        return self._send(codec.start_move(self.address))

    def stop(self, mode: str = "smooth", position: int | None = None) -> codec.Status:
        """Stop: 'abrupt', 'smooth' (at the loaded acceleration), 'off' (motor off) or 'here' (go to position)."""
        try:
            control = STOP_MODES[mode]
        except KeyError:
            raise ValueError(f"unknown stop mode {mode!r}; use one of {', '.join(STOP_MODES)}") from None
        return self._send(codec.stop_motor(self.address, control, position if mode == "here" else None))

    def arm_home(self, trigger: str | tuple[str, ...] = "limit1", action: str = "abrupt") -> codec.Status:
        """SET_HOMING: latch the position when the trigger fires, then stop as ``action`` says."""
        triggers = (trigger,) if isinstance(trigger, str) else trigger
        try:
            control = HOME_ACTIONS[action]
            for t in triggers:
                control |= HOME_TRIGGERS[t]
        except KeyError as exc:
            raise ValueError(f"unknown home trigger or action {exc.args[0]!r}") from None
        return self._send(codec.set_homing(self.address, control))

    def home_captured(self) -> bool:
        return not self.nop().home_in_progress

    def wait_move_done(self, timeout: float, poll: float = 0.002) -> codec.Status:
        """Poll until move_done; NmcError if it takes longer than ``timeout`` seconds."""
        clock = self.bus.clock
        deadline = clock.now() + timeout
        while True:
            st = self.nop()
            if st.move_done:
                return st
            if clock.now() > deadline:
                raise NmcError(f"module {self.address} did not finish its move within {timeout:.1f} s", self.address)
            clock.sleep(poll)
