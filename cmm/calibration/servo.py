"""Servo tuning assistant: the thesis's procedure on step moves, per axis.

Kp = Ki = 0, raise Kd until the axis "buzzes" (sustained oscillation or the
position-error trip), back off to half; then raise Kp the same way; if a
steady-state error remains, IL = 16000 and raise Ki until it is cancelled,
then lower IL to the smallest value that still cancels it. Each trial is a
small step (LOAD_TRAJ with large velocity and acceleration, so the profile
jumps) sampled in time; overshoot, settling time and final error are
recorded. The proposal is NOT applied: :func:`apply_gains` does that when the
operator accepts; the original gains are restored after the trials.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..machine.config import AXES
from ..machine.motion import Machine
from ..nmc import codec
from .probe import Progress, report
from .records import ServoRecord, now, write_atomic

STEP_COUNTS = 50
WINDOW_S = 0.15
BIG = 0x7FFFFFFF // 4


@dataclass
class Trial:
    axis: str
    stage: str  # "kd", "kp", "ki", "il"
    gains: codec.Gains
    times: np.ndarray = field(repr=False)  # s from the step
    positions: np.ndarray = field(repr=False)  # counts relative to the start
    step: int = STEP_COUNTS
    tripped: bool = False

    @property
    def error(self) -> np.ndarray:
        return self.step - self.positions

    @property
    def overshoot(self) -> float:
        """Counts beyond the goal (>= 0)."""
        return float(max(0.0, np.max(self.positions) - self.step)) if self.step > 0 else 0.0

    @property
    def final_error(self) -> float:
        return float(np.mean(self.error[-10:]))

    @property
    def settling_time(self) -> float:
        """Last time the error was outside +-1 count (s); the window length if never settled."""
        out = np.nonzero(np.abs(self.error) > 1)[0]
        if len(out) == 0:
            return 0.0
        return float(self.times[out[-1]]) if out[-1] < len(self.times) - 1 else float(self.times[-1])

    @property
    def buzzing(self) -> bool:
        """Sustained oscillation in the second half of the window, or the position-error trip."""
        if self.tripped:
            return True
        tail = self.positions[len(self.positions) // 2:]
        d = np.diff(tail)
        d = d[d != 0]
        flips = int(np.sum(np.diff(np.sign(d)) != 0)) if len(d) > 1 else 0
        k = np.arange(len(tail))
        wobble = tail - np.polyval(np.polyfit(k, tail, 1), k) if len(tail) > 2 else tail  # creep is not buzz
        return flips >= 6 and float(np.ptp(wobble)) >= 3

    def summary(self) -> dict[str, Any]:
        return {"axis": self.axis, "stage": self.stage, "kp": self.gains.kp, "kd": self.gains.kd, "ki": self.gains.ki,
                "il": self.gains.il, "overshoot_counts": self.overshoot, "settling_ms": self.settling_time * 1000,
                "final_error_counts": self.final_error, "buzz": self.buzzing}


@dataclass
class TuningResult:
    proposed: dict[str, codec.Gains]
    original: dict[str, codec.Gains]
    trials: list[Trial]

    def table(self) -> str:
        lines = [f"{'axis':<4} {'stage':<5} {'Kp':>6} {'Kd':>6} {'Ki':>5} {'IL':>6} {'overshoot':>10} {'settle ms':>9} "
                 f"{'final':>6} buzz"]
        for t in self.trials:
            s = t.summary()
            lines.append(f"{s['axis']:<4} {s['stage']:<5} {s['kp']:>6} {s['kd']:>6} {s['ki']:>5} {s['il']:>6} "
                         f"{s['overshoot_counts']:>10.1f} {s['settling_ms']:>9.1f} {s['final_error_counts']:>6.1f} "
                         f"{'yes' if s['buzz'] else ''}")
        for a, g in self.proposed.items():
            lines.append(f"proposed {a.upper()}: Kp {g.kp} Kd {g.kd} Ki {g.ki} IL {g.il}")
        return "\n".join(lines)

    def record(self, accepted: bool, machine: str = "") -> ServoRecord:
        return ServoRecord(now(), {a: {"kp": g.kp, "kd": g.kd, "ki": g.ki, "il": g.il} for a, g in self.proposed.items()},
                           accepted, machine)


def step_response(machine: Machine, axis: str, gains: codec.Gains, step: int = STEP_COUNTS,
                  window: float = WINDOW_S, stage: str = "") -> Trial:
    """Send the gains, step the axis by ``step`` counts (profile jumps), sample its position for ``window`` s."""
    i = AXES.index(axis)
    mod = machine.modules[i]
    clock = machine.clock
    mod.clear_bits()
    mod.enable()  # stop abrupt: the command position becomes the present position
    mod.set_gains(gains)
    end = clock.now() + 0.02
    while clock.now() < end:  # let the previous trial die out under the new gains
        mod.nop()
    mod.enable()
    start = mod.nop().position
    mod.load_position(start + step, BIG, BIG)
    t0 = clock.now()
    ts, ps, tripped = [], [], False
    while clock.now() - t0 < window:
        st = mod.nop()
        ts.append(clock.now() - t0)
        ps.append(st.position - start)
        if st.status & codec.POS_ERROR:
            tripped = True
            break
    trial = Trial(axis, stage, gains, np.array(ts), np.array(ps, float), step, tripped)
    if tripped:
        mod.clear_bits()
        mod.enable()
    return trial


def tune_axis(machine: Machine, axis: str, *, progress: Progress = None) -> tuple[codec.Gains, list[Trial]]:
    base = machine.config.axis(axis).gains
    trials: list[Trial] = []
    sign = [1]

    def run(g: codec.Gains, stage: str) -> Trial:
        t = step_response(machine, axis, g, STEP_COUNTS * sign[0], stage=stage)
        if sign[0] < 0:  # keep the data positive-going for plots and figures
            t.positions, t.step = -t.positions, -t.step
        sign[0] = -sign[0]
        trials.append(t)
        return t

    g = replace(base, kp=0, ki=0, il=0, kd=0)
    kd_ok = 0
    for kd in (500, 1000, 2000, 4000, 8000, 16000, 32000):
        if progress:
            progress(0.0, f"{axis.upper()}: Kd {kd}")
        if run(replace(g, kd=kd), "kd").buzzing:
            break
        kd_ok = kd
    kd = max(kd_ok // 2 if kd_ok >= 32000 or kd_ok == 0 else kd_ok, 500)
    g = replace(g, kd=kd)
    kp_ok = 0
    for kp in (250, 500, 1000, 2000, 4000, 8000, 16000):
        if progress:
            progress(0.4, f"{axis.upper()}: Kp {kp}")
        t = run(replace(g, kp=kp), "kp")
        if t.buzzing or t.overshoot > 2:
            break
        kp_ok = kp
    g = replace(g, kp=kp_ok // 2 if kp_ok >= 16000 else max(kp_ok, 250))
    last = run(g, "kp")
    if abs(last.final_error) > 1:
        g = replace(g, il=16000)
        for ki in (1, 2, 5, 10, 20, 50, 100):
            if progress:
                progress(0.7, f"{axis.upper()}: Ki {ki}")
            t = run(replace(g, ki=ki), "ki")
            if abs(t.final_error) <= 1 and not t.buzzing:
                g = replace(g, ki=ki)
                break
        il = g.il
        while il > 250:
            t = run(replace(g, il=il // 2), "il")
            if abs(t.final_error) > 1 or t.buzzing:
                break
            il //= 2
        g = replace(g, il=il if g.ki else 0)
    return g, trials


def tune_servos(machine: Machine, axes: tuple[str, ...] = AXES, *, progress: Progress = None) -> TuningResult:
    """Run the procedure on each axis at mid-travel; restore the original gains afterwards."""
    original = {a: machine.modules[AXES.index(a)].gains or machine.config.axis(a).gains for a in axes}
    mid = [(ax.min + ax.max) / 2 for ax in machine.config.axes]
    machine.move_to(mid).wait()
    proposed, trials = {}, []
    try:
        for k, a in enumerate(axes):
            g, t = tune_axis(machine, a, progress=report(progress, k / len(axes), (k + 1) / len(axes)))
            proposed[a], trials = g, trials + t
    finally:
        for a, g in original.items():
            mod = machine.modules[AXES.index(a)]
            mod.set_gains(g)
            mod.clear_bits()
            mod.enable()
    if progress:
        progress(1.0, "proposal ready; nothing applied until accepted")
    return TuningResult(proposed, original, trials)


def apply_gains(machine: Machine, gains: dict[str, codec.Gains]) -> None:
    """The operator accepted: send the gains (SET_GAIN) to the modules."""
    for a, g in gains.items():
        machine.modules[AXES.index(a)].set_gains(g)


def svg_plot(trials: list[Trial], path: str | Path, title: str = "step responses") -> Path:
    """A tiny SVG: one polyline per trial (counts vs ms), the goal as a dashed line."""
    w, h, m = 720, 420, 40
    tmax = max((float(t.times[-1]) for t in trials if len(t.times)), default=1.0)
    pmax = max((max(float(np.max(t.positions)), t.step) for t in trials if len(t.positions)), default=1.0) * 1.1
    pmin = min((float(np.min(t.positions)) for t in trials if len(t.positions)), default=0.0)
    sx = lambda x: m + (w - 2 * m) * x / tmax  # noqa: E731
    sy = lambda y: h - m - (h - 2 * m) * (y - pmin) / max(pmax - pmin, 1e-9)  # noqa: E731
    colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"]
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">',
             f'<rect width="{w}" height="{h}" fill="white"/><text x="{m}" y="20" font-size="14">{title}</text>',
             f'<line x1="{m}" y1="{h - m}" x2="{w - m}" y2="{h - m}" stroke="black"/>',
             f'<line x1="{m}" y1="{m}" x2="{m}" y2="{h - m}" stroke="black"/>',
             f'<text x="{w - m}" y="{h - 10}" text-anchor="end">{tmax * 1000:.0f} ms</text>',
             f'<text x="5" y="{m}">{pmax:.0f}</text><text x="5" y="{h - m}">{pmin:.0f} counts</text>']
    if trials:
        parts.append(f'<line x1="{m}" y1="{sy(trials[0].step):.1f}" x2="{w - m}" y2="{sy(trials[0].step):.1f}" '
                     'stroke="gray" stroke-dasharray="4 3"/>')
    for k, t in enumerate(trials):
        c = colours[k % len(colours)]
        pts = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in zip(t.times, t.positions))
        parts.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.2" points="{pts}"/>')
        parts.append(f'<text x="{w - m - 150}" y="{m + 14 * k}" fill="{c}">{t.axis.upper()} {t.stage} Kp {t.gains.kp} '
                     f'Kd {t.gains.kd} Ki {t.gains.ki}</text>')
    parts.append("</svg>")
    return write_atomic_text(path, "\n".join(parts))


def write_atomic_text(path: str | Path, text: str) -> Path:
    import os
    import tempfile

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, p)
    return p


__all__ = ["Trial", "TuningResult", "step_response", "tune_axis", "tune_servos", "apply_gains", "svg_plot",
           "write_atomic"]
