"""One simulated PIC-SERVO module: command execution, profile generator,
PID control law, home capture and status packets.

Everything the firmware computes is done in integers as the PIC does:
command position, velocity and acceleration in 16.16 fixed point (counts and
counts per servo tick), the PID output in integer units, PWM 0..255. The
module talks to the outside only through ``execute`` (decoded command bytes
in, status bytes out) and through its :class:`~cmm.sim.plant.Plant` (PWM out,
encoder count and input levels in).

Addressing, baud rate and reply rules live in :mod:`cmm.sim.network`; the
profile generator in :mod:`cmm.sim.picservo_profile`, the status packet
encoding in :mod:`cmm.sim.picservo_status`.

Firmware families (``firmware``): "pic-servo" is the thesis's original module
(version 4 by default), "pic-servo-sc" the later SC module (version 10). Only
the SC sends status items 0x40 (position error) and 0x80 (path points): the
original ignores those DEF_STAT / READ_STAT bits and its packets are shorter.
SC-only behaviour, from Kerr's public NMC library header (bit names there):
- IO_CTRL: LIMIT1/LIMIT2 are always inputs; 0x04 turns the motor off and 0x08
  stops it abruptly on a limit; 0x10 3-phase, 0x20 antiphase, 0x40 fast path,
  0x80 step & direction are drive options the simulated DC motor ignores.
  Chosen where the facts are silent: a limit is active while its input is
  high (the simulator's unwired inputs read low), LIMIT1 guards positive and
  LIMIT2 negative travel, so an axis can always be moved off its limit.
- LOAD_TRAJ bit 0x40 in trapezoidal position mode: MOVE_REL, the goal is
  relative to the command position when the move starts.
- HARD_RESET with a control byte: 0x01 saves gains, addresses and the
  power-up options (the other bits) in EEPROM; at every later power-up the
  saved gains return, 0x02 restores the addresses (the module lowers ADDR_OUT
  at once), 0x04 raises the amplifier enable, 0x08 starts the servo holding,
  0x20 turns limit protection on (stop abruptly); 3-phase, antiphase and step
  mode are recorded only.
- ADD_PATHPOINT (path mode) is not modelled: its point format is not among the
  facts; the SC answers it with a status packet and reports 0 path points.
A 13-byte SET_GAIN (Kerr's header allows 13 or 14 bytes) sets everything up to
SR and leaves the deadband compensation DB as it was.
"""

from __future__ import annotations

import struct

from cmm.nmc import codec as c
from cmm.sim import picservo_status as _status
from cmm.sim.picservo_profile import HOLD, TRAPEZOID, VELOCITY, trapezoid_step, velocity_step
from cmm.sim.plant import Plant

# A 16x-oversampling UART samples mid-bit; the stop bit of an 8N1 byte (9.5 bit
# times after the start edge) is still read correctly while the two ends differ
# by less than (0.5 - 1/16) / 9.5 = 4.6 %.
UART_TOLERANCE = 0.045
STANDARD_RATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
MODULE_CLOCK_HZ = 20_000_000  # the thesis's PIC-SERVO crystal; the UART divides it by 16 (BRD + 1)


def divisor_rate(divisor: int, firmware: str = "pic-servo") -> float:
    """The line rate a module runs at after SET_BAUD ``divisor``.

    Kerr's library sends divisor 5 for 230400 baud to SC modules, which the
    20 MHz formula (208 kbaud, 9.6 % off) cannot give: the simulator takes the
    library's table for it (a choice; the data sheet facts do not say how)."""
    if firmware == "pic-servo-sc" and divisor == 5:
        return 230400.0
    return MODULE_CLOCK_HZ / (16 * (divisor + 1))


def standard_rate(rate: float) -> int | None:
    """The standard PC rate a UART at ``rate`` can talk to, if any."""
    for r in STANDARD_RATES:
        if abs(rate - r) <= UART_TOLERANCE * r:
            return r
    return None


def rates_match(module_rate: float, host_rate: float | None) -> bool:
    """Does a UART at ``host_rate`` understand one at ``module_rate``? (None: a link without a rate)"""
    return host_rate is None or (host_rate > 0 and abs(module_rate - host_rate) <= UART_TOLERANCE * host_rate)


SC = "pic-servo-sc"
_L1_IN, _L1_OUT, _L2_IN, _L2_OUT = c.IO_LIMIT1_IN, c.IO_LIMIT1_OUT, c.IO_LIMIT2_IN, c.IO_LIMIT2_OUT
# SC IO_CTRL bits
LIMSTOP_OFF, LIMSTOP_ABRUPT = 0x04, 0x08
# SC HARD_RESET control byte bits
SAVE_DATA, RESTORE_ADDR, EPU_AMP, EPU_SERVO, EPU_LIMITS = 0x01, 0x02, 0x04, 0x08, 0x20
MOVE_REL = 0x40  # LOAD_TRAJ, trapezoidal position mode on the SC (REVERSE in velocity / PWM mode)

_CAPTURE_CONDITIONS = c.ON_LIMIT1 | c.ON_LIMIT2 | c.ON_INDEX | c.ON_POS_ERR | c.ON_CUR_ERR
# as plain globals for servo() (every tick of an armed move reads them)
_ON_LIMIT1, _ON_LIMIT2, _ON_INDEX, _ON_POS_ERR, _ON_CUR_ERR = (c.ON_LIMIT1, c.ON_LIMIT2, c.ON_INDEX, c.ON_POS_ERR,
                                                               c.ON_CUR_ERR)
_LIMSTOP = LIMSTOP_OFF | LIMSTOP_ABRUPT


class PicServo:
    """Firmware state of one module. ``servo()`` runs once per servo tick."""

    def __init__(self, plant: Plant, version: int = 4, firmware: str = "pic-servo") -> None:
        self.plant = plant
        self.version = version
        self.firmware = firmware
        self.sc = firmware == SC
        self.eeprom: dict | None = None  # SC configuration saved by HARD_RESET 0x01 (survives power cycles)
        self.enc_offset = plant.count
        self.quiet = False  # True when the next tick provably changes nothing
        plant.on_change = self.wake
        self.power_up()

    # --- power-up / HARD_RESET ---------------------------------------------
    def power_up(self) -> None:
        """Power-up state as the PIC-SERVO data sheet lists it."""
        # Communications (the network reads these).
        self.address = 0x00
        self.group = 0xFF
        self.leader = False
        self.addr_out_low = False  # ADDR_OUT goes low on the first SET_ADDR
        self.comms_enabled = False  # latched once ADDR_IN is seen low
        self.baud = c.POWER_UP_BAUD  # the standard rate the module's UART runs at (nominal)
        self.line_rate = divisor_rate(c.BAUD_DIVISORS[self.firmware][c.POWER_UP_BAUD], self.firmware)  # actual
        self.pending_baud: tuple[int, float] | None = None  # (nominal, actual) set by SET_BAUD, applied after the reply
        self.stat_items = 0  # status byte only
        # Gains: all zero, SR for 1.953 kHz.
        self.kp = self.kd = self.ki = self.il = self.ol = self.cl = self.el = self.db = 0
        self.sr = 1
        # Trajectory registers (LOAD_TRAJ) and the buffered command.
        self.goal = 0
        self.vel_reg = 0
        self.acc_reg = 0
        self.pwm_reg = 0
        self.pwm_reverse = False
        self.pending: c.LoadTraj | None = None
        # Servo state: the counter is cleared, the command follows it.
        self.enc_offset = self.plant.count
        self.pos = 0
        self.velocity = 0
        self.cmd_fx = 0  # command position, 16.16
        self.v_fx = 0  # signed profile velocity, 16.16 counts per servo tick
        self.prof = HOLD
        self.goal_fx = 0
        self.vmax = 0
        self.acc = 0
        self.vtarget = 0
        self.servo_on = False
        self.amp_en = False
        self.e_prev = 0
        self.isum = 0
        self.cla = 0  # current_limit_adjustment
        self.pwm = 0
        self.reverse = False
        self.ad = 0
        self.pos_error_value = 0
        # Status bits.
        self.move_done = True
        self.pos_error = True
        self.overcurrent = False
        self.home_in_prog = False
        self.cksum_error = False
        self.accel_done = False
        self.slew_done = False
        self.pos_wrap = False
        self.servo_overrun = False
        # Home capture and I/O.
        self.home = 0
        self.home_ctrl = 0
        self.io = c.IO_LIMIT1_IN | c.IO_LIMIT2_IN  # both LIMIT pins are inputs
        self.sc_io = 0  # SC IO_CTRL byte (limit protection and drive options)
        self._levels = self._input_levels()
        if self.eeprom is not None:
            self._restore(self.eeprom)
        self.plant.drive(self.pwm, self.reverse, self.amp_en)
        self.quiet = False

    def _restore(self, saved: dict) -> None:
        """SC power-up with a saved configuration (see HARD_RESET options)."""
        self.kp, self.kd, self.ki, self.il, self.ol, self.cl, self.el, self.sr, self.db = saved["gains"]
        options = saved["options"]
        if options & RESTORE_ADDR:
            self.address, self.group, self.leader = saved["address"], saved["group"], saved["leader"]
            self.addr_out_low = True
        if options & EPU_AMP:
            self.amp_en = True
        if options & EPU_SERVO:
            self._servo_on_here()
            self.pos_error = False
        if options & EPU_LIMITS:
            self.sc_io |= LIMSTOP_ABRUPT

    def _save(self, options: int) -> None:
        self.eeprom = {"gains": (self.kp, self.kd, self.ki, self.il, self.ol, self.cl, self.el, self.sr, self.db),
                       "address": self.address, "group": self.group, "leader": self.leader, "options": options}

    def wake(self) -> None:
        self.quiet = False

    # --- inputs ---------------------------------------------------------------
    def _input_levels(self) -> tuple[bool, bool, bool]:
        p, io = self.plant, self.io  # _pin inlined: every servo tick of an armed probe move reads them
        return (p.limit1 if io & _L1_IN else bool(io & _L1_OUT), p.limit2 if io & _L2_IN else bool(io & _L2_OUT),
                p.index)

    # --- the servo interrupt ------------------------------------------------
    def servo(self) -> None:
        """One servo tick: read the counter, capture, profile, PID, PWM out."""
        plant = self.plant
        cnt = plant.count - self.enc_offset
        vel = cnt - self.pos
        self.velocity = vel
        self.pos = cnt
        old_pwm = self.pwm
        old_rev = self.reverse
        old_cla = self.cla
        old_isum = self.isum
        old_e = self.e_prev

        if self.home_in_prog:
            io = self.io  # _input_levels inlined: every tick of an armed move
            levels = (plant.limit1 if io & _L1_IN else bool(io & _L1_OUT),
                      plant.limit2 if io & _L2_IN else bool(io & _L2_OUT), plant.index)
            ctrl = self.home_ctrl
            old = self._levels
            self._levels = levels
            if ((ctrl & _ON_LIMIT1 and levels[0] != old[0]) or (ctrl & _ON_LIMIT2 and levels[1] != old[1])
                    or (ctrl & _ON_INDEX and levels[2] != old[2])):
                self._capture()
        if self.sc_io & _LIMSTOP:
            self._limit_protection()
        if not plant.power and self.servo_on:
            # The firmware watches the motor supply and drops the servo itself.
            self._servo_off()
            self.pos_error = True

        if self.servo_on:
            prof = self.prof
            if prof == TRAPEZOID:
                trapezoid_step(self)
            elif prof == VELOCITY:
                velocity_step(self)
            e = (self.cmd_fx >> 16) - cnt
            self.pos_error_value = e
            el = self.el
            if e > el or e < -el:
                self._servo_off()  # collision detector: motor off, sticky flag
                self.pos_error = True
                if self.home_in_prog and self.home_ctrl & _ON_POS_ERR:
                    self._capture()
                mag = 0
            else:
                isum = self.isum + e
                lim = self.il << 8
                if isum > lim:
                    isum = lim
                elif isum < -lim:
                    isum = -lim
                self.isum = isum
                # Negative feedback with damping: the thesis prints the Kd term
                # as "- Kd*(e - e_prev)", which under pos_error = command - actual
                # would be positive velocity feedback; the firmware damps.
                out = self.kp * e + self.kd * (e - self.e_prev) + self.ki * (isum >> 8)
                self.e_prev = e
                self.reverse = out < 0
                mag = (-out if out < 0 else out) >> 8
                if mag and self.db:
                    mag += self.db  # amplifier deadband compensation
                if mag > self.ol:
                    mag = self.ol
        else:
            self.cmd_fx = cnt << 16  # the command follows so enabling the servo holds here
            self.pos_error_value = 0
            mag = self.pwm_reg
            self.reverse = self.pwm_reverse

        # Current limit: the adjustment creeps 1 per tick (thesis, ch. 2).
        current = plant.current
        ad = int((current if current >= 0.0 else -current) * plant._ad)  # plant.ad_value inlined (every tick)
        if ad > 255:
            ad = 255
        self.ad = ad
        cl = self.cl
        over = ad > cl if cl & 1 else ad < cl  # odd CL: sensor proportional to current
        cla = self.cla
        if over:
            if cla < mag:
                cla += 1
            self.overcurrent = True
            if self.home_in_prog and self.home_ctrl & _ON_CUR_ERR:
                self._capture()
                if not self.servo_on:
                    mag = self.pwm_reg
        elif cla:
            cla -= 1
        self.cla = cla
        pwm = mag - cla
        if pwm < 0:
            pwm = 0
        self.pwm = pwm
        if self.amp_en and plant.power and pwm:  # plant.drive inlined (every tick)
            v = plant.params.supply_v * pwm / 255.0
            plant.volts = -v if self.reverse else v
        else:
            plant.volts = 0.0
        self.quiet = (vel == 0 and plant.v == 0.0 and self.prof == HOLD and pwm == old_pwm
                      and self.reverse == old_rev and cla == old_cla and self.isum == old_isum
                      and self.e_prev == old_e)

    def _limit_protection(self) -> None:
        """SC: stop travel towards an active limit (LIMIT1 positive, LIMIT2 negative)."""
        p = self.plant
        if self.servo_on:
            v = self.v_fx
            if self.prof == TRAPEZOID and v == 0:
                v = self.goal_fx - self.cmd_fx  # about to start
        else:
            v = 0 if not self.pwm_reg else (-1 if self.pwm_reverse else 1)
        if (p.limit1 and v > 0) or (p.limit2 and v < 0):
            if self.sc_io & LIMSTOP_OFF:
                self._servo_off()
            elif self.servo_on:
                self._stop_abrupt()

    # --- profile generator (cmm.sim.picservo_profile) -------------------------
    def _finish_move(self) -> None:
        self.v_fx = 0
        self.prof = HOLD
        self.move_done = self.accel_done = self.slew_done = True

    # --- servo on/off -----------------------------------------------------------
    def _servo_on_here(self) -> None:
        if not self.servo_on:
            self.servo_on = True
            self.cmd_fx = self.pos << 16
            self.v_fx = 0
            self.e_prev = 0
            self.isum = 0

    def _servo_off(self) -> None:
        """Motor off: servo and PWM off (PWM mode with PWM 0)."""
        self.servo_on = False
        self.prof = HOLD
        self.v_fx = 0
        self.pwm_reg = 0
        self.pwm = 0
        self.move_done = True

    def _stop_abrupt(self, position: int | None = None) -> None:
        self._servo_on_here()
        self.cmd_fx = (self.pos if position is None else position) << 16
        self.v_fx = 0
        self.prof = HOLD
        self.move_done = True

    def _stop_smooth(self) -> None:
        if not self.servo_on or self.prof == HOLD:
            self._stop_abrupt()
            return
        if self.acc_reg <= 0:
            self._stop_abrupt()  # no deceleration loaded: a smooth stop would never end
            return
        self.prof = VELOCITY
        self.vtarget = 0
        self.acc = self.acc_reg
        self.move_done = False

    def _capture(self) -> None:
        """Latch the home position and run the requested stop action."""
        self.home = self.pos
        self.home_in_prog = False
        ctrl = self.home_ctrl
        if ctrl & c.HOME_MOTOR_OFF:
            self._servo_off()
        elif ctrl & c.HOME_STOP_ABRUPT:
            if self.servo_on:
                self._stop_abrupt()
        elif ctrl & c.HOME_STOP_SMOOTH:
            if self.servo_on:
                self._stop_smooth()

    # --- commands ---------------------------------------------------------------
    def status_byte(self) -> int:
        return _status.status_byte(self)

    def aux_byte(self) -> int:
        return _status.aux_byte(self)

    def status_packet(self, items: int | None = None) -> bytes:
        """The status packet with ``items`` (default: the DEF_STAT set)."""
        return _status.status_packet(self, items)

    def checksum_error_reply(self) -> bytes:
        """A bad packet is not executed, but answered with cksum_error set."""
        self.cksum_error = True
        return self.status_packet()

    def execute(self, code: int, data: bytes) -> bytes | None:
        """Run one command; return the status packet (None for HARD_RESET).

        SET_ADDR and SET_BAUD change communication state the network reads
        back (``address``, ``group``, ``leader``, ``addr_out_low``, ``baud``).
        """
        self.cksum_error = False
        self.quiet = False
        items = None
        n = len(data)
        if code == c.NOP:
            pass
        elif code == c.READ_STAT and n == 1:
            items = data[0]  # one-shot; DEF_STAT's set stays
        elif code == c.DEF_STAT and n == 1:
            self.stat_items = data[0]
        elif code == c.LOAD_TRAJ:
            try:
                lt = c.parse_load_traj(data)
            except c.CodecError:
                lt = None  # malformed: ignored (the firmware would misread it)
            if lt is not None:
                if lt.control & c.START_NOW:
                    self.pending = None
                    self._start(lt)
                else:
                    self.pending = lt
        elif code == c.START_MOVE:
            if self.pending is not None:
                lt, self.pending = self.pending, None
                self._start(lt)
        elif code == c.SET_ADDR and n == 2:
            self.address = data[0]
            self.leader = not data[1] & 0x80
            self.group = data[1] | 0x80
            self.addr_out_low = True
        elif code == c.SET_GAIN and n in (13, 14, 15):
            kp, kd, ki, il, ol, cl, el, sr = struct.unpack_from("<hhhhBBhB", data)
            self.kp, self.kd, self.ki, self.il = kp, kd, ki, il
            self.ol, self.cl, self.el, self.sr = ol, cl, el, max(1, sr)
            if n >= 14:
                self.db = data[13]  # a 13-byte SET_GAIN leaves DB as it was
        elif code == c.STOP_MOTOR and n in (1, 5):
            self._stop_motor(data[0], struct.unpack_from("<i", data, 1)[0] if n == 5 else None)
        elif code == c.IO_CTRL and n == 1:
            if self.sc:
                self.sc_io = data[0]  # the LIMIT pins stay inputs
            else:
                self.io = data[0] & 0x0F
        elif code == c.SET_HOMING and n == 1:
            self.home_ctrl = data[0]
            self.home_in_prog = bool(data[0] & _CAPTURE_CONDITIONS)
            self._levels = self._input_levels()
        elif code == c.SET_BAUD and n == 1:
            pass  # the network switches the rate after the reply
        elif code == c.CLEAR_BITS:
            self.overcurrent = self.pos_error = self.pos_wrap = self.servo_overrun = False
        elif code == c.SAVE_AS_HOME:
            self.home = self.pos
        elif code == c.RESET_POS:
            self._reset_pos(data)
        elif code == c.HARD_RESET:
            if self.sc and n == 1 and data[0] & SAVE_DATA:
                self._save(data[0])
            self.power_up()
            return None
        return self.status_packet(items)

    def _reset_pos(self, data: bytes) -> None:
        """Counter and command position to 0 (later firmware: relative to home / set)."""
        if len(data) == 5 and data[0] & c.RESET_SET_POS:
            new = struct.unpack_from("<i", data, 1)[0]
        elif len(data) >= 1 and data[0] & c.RESET_REL_HOME:
            new = self.pos - self.home
            self.home = 0
        else:
            new = 0
        shift = new - self.pos
        self.enc_offset -= shift
        self.pos = new
        self.cmd_fx = new << 16
        self.goal_fx += shift << 16
        self.e_prev = 0

    def _stop_motor(self, ctrl: int, position: int | None) -> None:
        self.amp_en = bool(ctrl & c.AMP_ENABLE)
        if ctrl & c.MOTOR_OFF:
            self._servo_off()
        elif ctrl & c.STOP_ABRUPT:
            self._stop_abrupt()
        elif ctrl & c.STOP_SMOOTH:
            self._stop_smooth()
        elif ctrl & c.STOP_HERE and position is not None:
            self._stop_abrupt(position)
        self.plant.drive(self.pwm, self.reverse, self.amp_en)

    def _start(self, lt: c.LoadTraj) -> None:
        """Apply a LOAD_TRAJ now (START_NOW, or on START_MOVE)."""
        if lt.position is not None:
            self.goal = lt.position
        if lt.velocity is not None:
            self.vel_reg = lt.velocity
        if lt.acceleration is not None:
            self.acc_reg = lt.acceleration
        if lt.pwm is not None:
            self.pwm_reg = lt.pwm
        ctrl = lt.control
        if not ctrl & c.ENABLE_SERVO:
            # PWM mode: servo off, the PWM register drives the amplifier directly.
            self.servo_on = False
            self.prof = HOLD
            self.v_fx = 0
            self.pwm_reverse = bool(ctrl & c.REVERSE)
            self.move_done = True
            return
        self._servo_on_here()
        self.acc = self.acc_reg
        self.accel_done = self.slew_done = False
        if ctrl & c.VEL_MODE:
            self.prof = VELOCITY
            self.vtarget = -self.vel_reg if ctrl & c.REVERSE else self.vel_reg
            self.move_done = self.v_fx == self.vtarget
        else:
            self.prof = TRAPEZOID
            if self.sc and ctrl & MOVE_REL and lt.position is not None:
                self.goal = (self.cmd_fx >> 16) + lt.position
            self.goal_fx = self.goal << 16
            self.vmax = self.vel_reg
            self.move_done = self.goal_fx == self.cmd_fx and self.v_fx == 0
            if self.move_done:
                self._finish_move()
