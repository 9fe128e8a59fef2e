"""The PIC-SERVO profile generator: one servo tick of the trapezoidal and the
velocity profile, in the firmware's 16.16 fixed point.

The functions act on a :class:`~cmm.sim.picservo.PicServo` (``m``): its command
position ``cmd_fx``, profile velocity ``v_fx``, goal, limits and status bits.
"""

from __future__ import annotations

from typing import Any


# Profile state.
HOLD, TRAPEZOID, VELOCITY = 0, 1, 2


def stop_distance(u: int, a: int) -> int:
    """Distance (16.16) covered while decelerating from speed ``u`` by ``a`` per tick to rest."""
    n = u // a
    return n * u - a * n * (n + 1) // 2


def trapezoid_step(m: Any) -> None:
    """One tick of the trapezoidal profile; lands exactly on the goal."""
    a = m.acc
    rem = m.goal_fx - m.cmd_fx
    v = m.v_fx
    if rem == 0 or a <= 0:
        if rem == 0:
            m._finish_move()
        return
    if rem > 0:
        r, u = rem, v
    else:
        r, u = -rem, -v
    vmax = m.vmax
    if u > vmax:
        un = u - a
        if un < vmax:
            un = vmax
    else:
        un = u + a
        if un > vmax:
            un = vmax
    n = un // a  # stop_distance(un, a) inlined: every tick of every moving axis
    if un > 0 and un + n * un - a * n * (n + 1) // 2 > r:
        if u > 0 and un > u and u + stop_distance(u, a) <= r:
            un = u  # cannot accelerate further: hold (slew)
        else:
            un = u - a  # decelerate
            if un <= 0 <= u:
                un = a if a < r else r  # final creep onto the goal
    if un > r:
        un = r
    if un <= u:
        m.accel_done = True
        if un < u:
            m.slew_done = True
    if un == r:
        m.cmd_fx = m.goal_fx
        m._finish_move()
        return
    if rem > 0:
        m.cmd_fx += un
        m.v_fx = un
    else:
        m.cmd_fx -= un
        m.v_fx = -un


def velocity_step(m: Any) -> None:
    """One tick of the velocity profile: ramp towards the target velocity."""
    vt = m.vtarget
    v = m.v_fx
    a = m.acc
    if v < vt:
        v = v + a if v + a < vt else vt
    elif v > vt:
        v = v - a if v - a > vt else vt
    m.v_fx = v
    m.cmd_fx += v
    if v == vt:
        m.move_done = m.accel_done = True
        if v == 0:
            m.prof = HOLD  # a smooth stop has ended
