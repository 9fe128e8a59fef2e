"""Home switches for the simulated CMM: one per axis at the ``home`` end of its travel (a tick hook).

A switch is active (high) while its axis reads at or beyond the axis's home
coordinate, towards the end of the travel the home lies at; it drives the
module's LIMIT2 (``[homing] input``). The probe keeps LIMIT1.
"""

from __future__ import annotations

from typing import Any


class HomeSwitches:
    def __init__(self, cmm: Any, input: str = "limit2", active_high: bool = True) -> None:
        self.cmm = cmm
        self.input = input
        self.active_high = active_high
        axes = cmm.config.axes
        self._toward_max = [a.home >= (a.min + a.max) / 2 for a in axes]
        self._home = [a.home for a in axes]
        # (threshold, towards the maximum) per axis: the switch is on at or beyond the threshold
        self._limits = tuple((h - 1e-9, True) if up else (h + 1e-9, False)
                             for h, up in zip(self._home, self._toward_max))
        self._on: tuple[bool, bool, bool] | None = None
        self._levels: list[bool | None] = [None, None, None]
        # the same thresholds on each axis's plant position in counts (mm = home + counts / k, k signed by the
        # axis's direction), so that a tick compares three numbers without converting them
        counts = []
        for (plant, home, k), (t, up) in zip(cmm._encoders, self._limits):
            counts.append((plant, (t - home) * k, up if k > 0 else not up))
        self._counts = tuple(counts)
        cmm.network.add_tick_hook(self, reads_axes_only=True)
        self(cmm.network, 0)

    def __call__(self, network: Any, tick: int) -> None:
        # every servo tick: plain comparisons, the inputs touched only when a switch changes
        (px, tx, ux), (py, ty, uy), (pz, tz, uz) = self._counts
        x, y, z = px.x, py.x, pz.x
        on = (x >= tx if ux else x <= tx, y >= ty if uy else y <= ty, z >= tz if uz else z <= tz)
        if on != self._on:
            self._on = on
            for i, o in enumerate(on):
                level = o if self.active_high else not o
                if level != self._levels[i]:
                    self._levels[i] = level
                    network.set_inputs(self.cmm._axis_module[i], **{self.input: level})


def for_homing(cmm: Any, homing: Any) -> HomeSwitches | None:
    """The switches a configuration's homing cycle (``[homing]``) looks for, fitted to ``cmm``; None when it
    homes without switches."""
    if homing.method != "switch":
        return None
    return HomeSwitches(cmm, homing.input, homing.active_level == "high")
