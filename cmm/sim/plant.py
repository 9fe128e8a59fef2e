"""One simulated axis: PWM amplifier -> DC motor -> leadscrew -> linear encoder.

The plant is integrated once per base servo tick (0.512 ms) with the PWM held
constant over the tick (a zero-order hold, as the PIC-SERVO updates its PWM
once per tick). Its linear part, the motor speed under armature resistance,
back-EMF and viscous friction, is a first-order system, so its exact
discretisation over one tick is precomputed (one exponential). Coulomb
friction is a constant torque opposing the motion: it is folded into the
tick's constant input, and a tick in which the speed would cross zero is
split at the exact stopping instant, so the axis really sticks at rest while
the drive torque stays below the friction.

Armature inductance is neglected: L/R of a small servo motor (about 1 mH /
2.5 ohm = 0.4 ms) is below one tick, so the current is taken as algebraic.

Internal units are encoder counts and base ticks; everything user facing is
documented in SI or millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cmm.nmc.codec import TICK_SECONDS, Gains


@dataclass(frozen=True)
class PlantParams:
    """Physical parameters of one axis (defaults: a small 24 V servo on a 2 mm lead screw).

    Top speed with the default motor: 24 V / 0.1 V.s/rad = 240 rad/s no load,
    about 75 mm/s on the 2 mm lead; about 70 mm/s against the default friction.
    """

    supply_v: float = 24.0  # motor supply (amplifier rail)
    resistance: float = 2.5  # armature resistance, ohm
    k_t: float = 0.1  # torque constant N.m/A (= back-EMF constant V.s/rad)
    j_rotor: float = 1.0e-5  # motor rotor inertia, kg.m^2
    j_screw: float = 8.0e-6  # leadscrew inertia (12 mm x 500 mm steel), kg.m^2
    mass: float = 5.0  # carriage + moving axes, kg (reflected through the lead)
    viscous: float = 2.0e-5  # viscous friction at the motor, N.m/(rad/s)
    coulomb: float = 0.02  # Coulomb friction at the motor, N.m (screw nut + guides)
    lead_mm: float = 2.0  # carriage travel per motor revolution, mm
    counts_per_mm: float = 500.0  # linear encoder resolution (2 um per count)
    ad_per_amp: float = 25.0  # current-sense A/D counts per ampere (255 = 10.2 A)

    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_mm * self.lead_mm / (2.0 * math.pi)

    @property
    def inertia(self) -> float:
        """Total inertia seen by the motor shaft, kg.m^2."""
        r = self.lead_mm / 1000.0 / (2.0 * math.pi)
        return self.j_rotor + self.j_screw + self.mass * r * r

    @property
    def top_speed_mm_s(self) -> float:
        """Steady speed at full PWM against viscous and Coulomb friction."""
        k, r = self.k_t, self.resistance
        w = (k * self.supply_v / r - self.coulomb) / (self.viscous + k * k / r)
        return w * self.lead_mm / (2.0 * math.pi)


DEFAULT_PLANT = PlantParams()

# Gains tuned for DEFAULT_PLANT at SR = 1 by a scan over Kp/Kd on moves of
# 1..50000 counts at up to 70 mm/s and 5000 mm/s^2: every move ends within
# +-1 count with no overshoot beyond 1 count and settles within 1 ms of the
# profile's end. Kp must beat the Coulomb friction (about 5 PWM) on a 1 count
# error: Kp > 5.3 * 256. No integral is needed (IL = 0 keeps the sum at 0).
# Following error is about 20 counts at 70 mm/s (no feed-forward in the
# firmware); EL = 500 counts (1 mm) is the collision detector. CL = 0 turns
# current limiting off (an odd CL, e.g. 201 = 8 A, enables it).
# Power-up gains are all 0: a host must send these (SET_GAIN).
DEFAULT_GAINS = Gains(kp=4000, kd=10000, ki=0, il=0, ol=255, cl=0, el=500, sr=1, db=0)


class Plant:
    """Dynamic state of one axis plus the world-side input levels of its module."""

    __slots__ = (
        "params", "x", "v", "volts", "current", "power", "blocked",
        "limit1", "limit2", "index", "count", "on_change",
        "_e", "_f", "_h", "_a", "_gv", "_fc", "_emf", "_ad",
    )

    def __init__(self, params: PlantParams = DEFAULT_PLANT) -> None:
        self.params = params
        self.x = 0.0  # carriage position in counts (continuous)
        self.v = 0.0  # counts per base tick
        self.volts = 0.0  # amplifier output over the current tick
        self.current = 0.0  # armature current, A
        self.count = 0  # quadrature counter reading: nearest count to x
        self.power = True  # motor supply present
        self.blocked = False  # carriage jammed (collision): it cannot move
        self.limit1 = False  # input levels (True = high) driven by the world model
        self.limit2 = False
        self.index = False
        self.on_change = None  # callback when code changes inputs (wakes the module)
        p = params
        c = p.counts_per_rad
        t = TICK_SECONDS
        j = p.inertia
        self._a = (p.viscous + p.k_t * p.k_t / p.resistance) / j * t  # decay per tick
        self._e = math.exp(-self._a)
        self._f = (1.0 - self._e) / self._a  # int_0^1 e^{-a s} ds
        self._h = (1.0 - self._f) / self._a  # int_0^1 (1 - e^{-a s}) / a ds
        self._gv = c * t * t * p.k_t / (p.resistance * j)  # counts/tick^2 per volt
        self._fc = c * t * t * p.coulomb / j  # Coulomb deceleration, counts/tick^2
        self._emf = p.k_t / (c * t)  # back-EMF volts per count/tick
        self._ad = p.ad_per_amp

    # --- world side ---------------------------------------------------------
    @property
    def position_mm(self) -> float:
        return self.x / self.params.counts_per_mm

    def set_inputs(self, *, limit1: bool | None = None, limit2: bool | None = None,
                   index: bool | None = None) -> None:
        """Set LIMIT1 / LIMIT2 / INDEX levels (True = high); the module sees them this tick."""
        if limit1 is not None:
            self.limit1 = bool(limit1)
        if limit2 is not None:
            self.limit2 = bool(limit2)
        if index is not None:
            self.index = bool(index)
        self._changed()

    def set_power(self, on: bool) -> None:
        self.power = bool(on)
        self._changed()

    def set_blocked(self, blocked: bool) -> None:
        self.blocked = bool(blocked)
        if blocked:
            self.v = 0.0
        self._changed()

    def move_to(self, x_counts: float) -> None:
        """Teleport the carriage (test set-up); the module is woken."""
        self.x = float(x_counts)
        self.v = 0.0
        self.count = math.floor(self.x + 0.5)
        self._changed()

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    # --- amplifier ----------------------------------------------------------
    def drive(self, pwm: int, reverse: bool, amp_enable: bool) -> None:
        """PWM duty 0..255 and direction from the module, held for the next tick."""
        if amp_enable and self.power and pwm:
            v = self.params.supply_v * pwm / 255.0
            self.volts = -v if reverse else v
        else:
            self.volts = 0.0

    @property
    def ad_value(self) -> int:
        """Current-sense A/D reading (proportional sensor), 0..255."""
        a = int(abs(self.current) * self._ad)
        return 255 if a > 255 else a

    # --- dynamics -----------------------------------------------------------
    def step(self) -> None:
        """Advance one base tick with the held amplifier voltage."""
        volts = self.volts
        v = self.v
        if self.blocked:
            self.current = volts / self.params.resistance
            return
        u = volts * self._gv  # drive acceleration (back-EMF is in the decay rate)
        fc = self._fc
        if v == 0.0:
            if -fc <= u <= fc:  # static friction holds the axis
                self.current = volts / self.params.resistance
                return
            s = 1.0 if u > 0.0 else -1.0
        else:
            s = 1.0 if v > 0.0 else -1.0
        g = u - s * fc
        v1 = v * self._e + g * self._f
        if v1 * s > 0.0:
            self.x += v * self._f + g * self._h
            self.v = v1
        else:
            self._stop_within_tick(v, g, u, s)
        self.count = math.floor(self.x + 0.5)
        self.current = (volts - self.v * self._emf) / self.params.resistance

    def _stop_within_tick(self, v: float, g: float, u: float, s: float) -> None:
        """The speed reaches zero inside this tick: split the tick at that instant."""
        a = self._a
        # v(t) = v e^{-at} + g (1 - e^{-at}) / a = 0  ->  e^{-at} = g / (g - a v)
        ratio = g / (g - a * v) if g != a * v else 1.0
        t_stop = -math.log(ratio) / a if 0.0 < ratio < 1.0 else 0.0
        self.x += v * (1.0 - ratio) / a + g * (t_stop - (1.0 - ratio) / a) / a
        self.v = 0.0
        rest = 1.0 - t_stop
        fc = self._fc
        if rest > 0.0 and (u > fc or u < -fc):  # breaks away the other way
            s2 = 1.0 if u > 0.0 else -1.0
            g2 = u - s2 * fc
            e = math.exp(-a * rest)
            self.v = g2 * (1.0 - e) / a
            self.x += g2 * (rest - (1.0 - e) / a) / a
