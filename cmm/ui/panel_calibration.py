"""The "Calibration" tab: a wizard over the calibration routines of :mod:`cmm.calibration`.

Choose the routine (probe qualification, ISO 10360-5 test, machine geometry,
servo tuning); the tab shows the artifact certificate in use and the records
now on disk (dates, results). **Run** needs control and an idle machine; the
routine runs in its own thread (never in viser's callback thread) and its
``progress`` callback drives a progress bar. When it ends: a results table
(probe: residuals by ring and a residual-vs-azimuth plot; ISO: the figures
uncalibrated / radius only / calibrated; geometry: scale, squareness and the
bar errors before / after; servo: original and proposed gains).

The tab drives nothing itself: it sends the calibration's verbs of the command
API (``qualify``, ``save_calibration``, ``accept_gains``, ``select_probe``,
``add_probe``, ``set_sphere_certificate``, ``bar_placed``:
:mod:`cmm.calibration.verbs`) and reads its queries (``calibration_run``,
``calibration_records``, ``calibration_certificate``, ``probes``:
:mod:`cmm.calibration.queries`); the calibration service behind them
(:mod:`cmm.calibration.service`) runs each routine through the ``run_job`` verb,
writes the records and applies them (``configure``). This module renders what
they return.

Nothing is applied by running: **Save record** writes the record and, for the
probe and the geometry, applies it to the live machine; servo gains are sent to
the modules only by **Accept gains**. A routine that fails (CalibrationError,
SurfaceNotFound, MotionError ...) is reported as a notification and the
previous calibration stays in force.

Machine geometry needs the ball bar placed for each set-up: on the simulator
the service places it; on a real machine the tab shows the service's set-up
instruction and the **Bar placed, continue** button.
"""

from __future__ import annotations

import html
import re
from pathlib import Path
from typing import Any

import numpy as np

from .context import OPERATOR_ERRORS, PanelContext
from .jobs import Job, ProgressView

# what a calibration verb ends with that is an operator's message, not a crash (the service's calibration_errors():
# its CalibrationError is a RuntimeError; SurfaceNotFound and MotionError are too)
ERRORS = OPERATOR_ERRORS + (RuntimeError,)

# the wizard's labels (the service accepts either; cmm.calibration.service.ROUTINES is the same table)
ROUTINES = {"Probe qualification": "probe", "ISO 10360-5 test": "iso", "Machine geometry": "geometry",
            "Servo tuning": "servo"}
LABELS = {v: k for k, v in ROUTINES.items()}


# --------------------------------------------------------------------------- tables and plots


def _um(v: float) -> str:
    return f"{v:+.2f}"


def probe_markdown(q: Any) -> str:
    r = q.record
    lines = ["| result | value |", "|---|---|",
             f"| effective tip radius r_eff | **{r.tip_radius:.5f} mm** (nominal {r.nominal_tip_radius}) |",
             f"| U (k=2) of r_eff | {r.uncertainty_um:.2f} um |",
             "| sphere centre (machine) | X={:.4f} Y={:.4f} Z={:.4f} |".format(*r.sphere_centre),
             f"| tip offset to master | {', '.join(f'{x * 1000:+.2f}' for x in r.tip_offset)} um |",
             f"| tip-centre sphere form | {r.form_before_um:.2f} → {r.form_after_um:.2f} um ({r.n_points} points) |",
             f"| directional pre-travel | {q.settings.pretravel.describe()} |"]
    if q.skipped:
        lines.append(f"| skipped | {'; '.join(q.skipped)} |")
    lines += ["", "| polar | points | range before | range after | RMS after |", "|---:|---:|---:|---:|---:|"]
    for row in q.by_ring():
        lines.append("| {polar_deg:.1f}° | {n} | {range_before_um:.2f} um | {range_after_um:.2f} um | "
                     "{rms_after_um:.2f} um |".format(**row))
    return "\n".join(lines)


def residual_series(q: Any) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    """Per ring (polar angle of the surface normal): azimuths (deg), residuals before and after (um)."""
    normal = -np.asarray(q.approach, float)
    polar = np.degrees(np.arccos(np.clip(normal[:, 2], -1, 1)))
    azimuth = np.degrees(np.arctan2(normal[:, 1], normal[:, 0])) % 360.0
    out = []
    for p in sorted(set(np.round(polar, 1))):
        sel = np.abs(polar - p) < 0.05
        order = np.argsort(azimuth[sel])
        out.append((float(p), azimuth[sel][order], np.asarray(q.residuals_before)[sel][order] * 1000,
                    np.asarray(q.residuals_after)[sel][order] * 1000))
    return out


def residual_svg(q: Any, width: int = 420, height: int = 240) -> str:
    """Residual (um) vs azimuth (deg) per ring: dashed = constant pre-travel, solid = with the directional model."""
    series = [s for s in residual_series(q) if len(s[1]) > 1 or s[0] > 0.5]
    m = 34
    values = np.concatenate([np.r_[b, a] for _, _, b, a in series]) if series else np.zeros(1)
    lim = max(float(np.max(np.abs(values))) * 1.1, 0.5)
    sx = lambda x: m + (width - 2 * m) * x / 360.0  # noqa: E731
    sy = lambda y: height / 2 - (height / 2 - m / 2) * y / lim  # noqa: E731
    colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"]
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" width="100%" '
             'font-family="sans-serif" font-size="10">',
             f'<rect width="{width}" height="{height}" fill="white"/>',
             f'<line x1="{m}" y1="{sy(0):.1f}" x2="{width - m}" y2="{sy(0):.1f}" stroke="#999"/>',
             f'<line x1="{m}" y1="{m / 2}" x2="{m}" y2="{height - m / 2}" stroke="black"/>',
             f'<text x="2" y="{m / 2 + 8}">{lim:+.1f}</text><text x="2" y="{height - m / 2}">{-lim:+.1f} um</text>',
             f'<text x="{width - m}" y="{height - 4}" text-anchor="end">azimuth 360°</text>',
             f'<text x="{m + 4}" y="12">residual vs azimuth per ring (dashed: before, solid: after the model)</text>']
    for k, (polar, az, before, after) in enumerate(series):
        c = colours[k % len(colours)]
        for vals, dash in ((before, ' stroke-dasharray="3 2"'), (after, "")):
            pts = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in zip(az, vals))
            parts.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.3"{dash} points="{pts}"/>')
        for x, y in zip(az, after):
            parts.append(f'<circle cx="{sx(x):.1f}" cy="{sy(y):.1f}" r="2" fill="{c}"/>')
        parts.append(f'<text x="{width - m - 70}" y="{24 + 12 * k}" fill="{c}">polar {polar:.0f}°</text>')
    parts.append("</svg>")
    return "".join(parts)


def iso_markdown(result: Any) -> str:
    lines = [f"25 points × {result.repeats} hit(s)", "",
             "| settings | P_Form.Sph.1x25 | P_Size.Sph.1x25 | fitted D |", "|---|---:|---:|---:|"]
    for k, f in result.figures.items():
        lines.append(f"| {k} | {f.form_um:.2f} um | {f.size_um:+.2f} um | {f.diameter:.4f} mm |")
    if result.skipped:
        lines.append(f"\nskipped: {'; '.join(result.skipped)}")
    return "\n".join(lines)


def geometry_markdown(result: Any) -> str:
    c = result.correction
    lines = ["| | X / XY | Y / XZ | Z / YZ | U (k=2) |", "|---|---:|---:|---:|---:|",
             "| scale (ppm) | {:+.2f} | {:+.2f} | {:+.2f} | {:.2f} |".format(*c.scale_ppm, result.uncertainty_scale_ppm),
             "| squareness (urad) | {:+.2f} | {:+.2f} | {:+.2f} | {:.2f} |".format(
                 *c.squareness_urad, result.uncertainty_squareness_urad),
             "", "| set-up | error before | after |", "|---|---:|---:|"]
    after = {m.setup: m.error_um for m in result.verification}
    for m in result.measurements:
        a = after.get(m.setup)
        lines.append(f"| {m.setup} | {_um(m.error_um)} um | {'' if a is None else _um(a) + ' um'} |")
    return "\n".join(lines)


def servo_markdown(result: Any, accepted: bool = False) -> str:
    lines = ["| axis | | Kp | Kd | Ki | IL |", "|---|---|---:|---:|---:|---:|"]
    for a, g in result.proposed.items():
        o = result.original.get(a)
        if o is not None:
            lines.append(f"| {a.upper()} | now | {o.kp} | {o.kd} | {o.ki} | {o.il} |")
        lines.append(f"| {a.upper()} | **proposed** | **{g.kp}** | **{g.kd}** | **{g.ki}** | **{g.il}** |")
    lines.append("")
    lines.append(f"{len(result.trials)} step trials. " + (
        "**Accepted: the proposed gains are in the modules.**" if accepted else
        "Nothing is applied until you press **Accept gains**."))
    return "\n".join(lines)


# --------------------------------------------------------------------------- the panel


class CalibrationPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.routine = "probe"
        self.job: Job | None = None
        self.result: tuple[str, Any] | None = None  # (routine, result object) of the last successful run
        self.accepted = False
        self.saved: Path | None = None
        self._shown_instruction = ""
        self.gui: dict[str, Any] = {}
        self.progress_view = ProgressView(ctx)

    def _query(self, name: str, **params: Any) -> Any:
        return self.ctx.commands.invoke(self.ctx.who(), name, **params)

    def _run_state(self) -> dict[str, Any]:
        """The ``calibration_run`` query: running, paused, holding, the bar set-up waited for, resumable."""
        return self._query("calibration_run")

    @property
    def records_dir(self) -> Path:
        return Path(self._query("calibration_records")["directory"])

    def certificate_markdown(self, routine: str | None = None) -> str:
        return self._query("calibration_certificate", routine=routine or self.routine)["text"]

    def records(self) -> list[dict[str, str]]:
        return self._query("calibration_records")["records"]

    def records_markdown(self) -> str:
        info = self._query("calibration_records")
        rows = info["records"]
        lines = [f"records in `{info['directory']}`:", ""]
        if rows:
            lines += ["| record | date | result |", "|---|---|---|"]
            lines += [f"| {r['kind']} | {r['date']} | {r['result']} |" for r in rows]
        else:
            lines.append("*no records yet: the nominal settings are in force*")
        log = info["in_force"]
        if log:
            lines += ["", "in force: " + "; ".join(log)]
        return "\n".join(lines)

    # --- probes and the reference sphere --------------------------------------------

    def probes(self) -> list[dict[str, Any]]:
        try:
            listing = self._query("probes")
        except ERRORS as exc:
            self.ctx.error(exc, "Probe list")
            return []
        if listing["problem"]:
            self.ctx.error(listing["problem"], "Probe list")
        return listing["probes"]

    def probes_markdown(self) -> str:
        """A narrow table (the side panel): probe, tip, qualified radius, expiry; a detail line per probe."""
        rows = self.probes()
        lines = ["| probe | tip D | qualified r | expires |", "|---|---:|---:|---|"]
        details = []
        for r in rows:
            name = html.escape(r["name"]) + (" **(in use)**" if r["selected"] else "")
            stylus = ", ".join(f"{x:g}" for x in r["stylus"])
            if r["tip_radius"] is None:
                lines.append(f"| {name} | {r['tip_diameter']:g} | *not qualified* | |")
                details.append(f"- {html.escape(r['name'])}: stylus {stylus}"
                               + (f" · {html.escape(r['problem'])}" if r["problem"] else ""))
                continue
            exp = r["expires"] + (" **expired**" if r["expired"] else "")
            lines.append(f"| {name} | {r['tip_diameter']:g} | {r['tip_radius']:.5f} mm | {exp} |")
            details.append(f"- {html.escape(r['name'])}: stylus {stylus} · pre-travel {html.escape(r['pretravel'])} "
                           f"· qualified {r['qualified_on']} with {html.escape(r['sphere'])}")
        return "\n".join(lines + [""] + details)

    def add_probe(self, name: str, tip_diameter: Any, stylus: Any = (0.0, 0.0, -1.0)) -> bool:
        """Add a stylus to the probe list (then select it and qualify it)."""
        if not self.ctx.allowed("Add probe"):
            return False
        if isinstance(stylus, str):  # "0, 0, -1", "0 0 -1" or "0;0;-1", as the other fields of the page take numbers
            stylus = [x for x in re.split(r"[,;\s]+", stylus.strip()) if x]
        try:
            probe = self.ctx.commands.invoke(self.ctx.who(), "add_probe", name=name, tip_diameter=tip_diameter,
                                             stylus=stylus)
        except ERRORS as exc:
            self.ctx.error(exc, "Add probe")
            return False
        self.ctx.notify("Probe added", f"{probe['name']}: tip D {probe['tip_diameter']:g} mm; select it and qualify it")
        self._refresh_probes()
        return True

    def select_probe(self, name: str) -> bool:
        """Use probe ``name``: its qualified radius and pre-travel are what compensation uses from now on."""
        if self.running or not self._machine_allows("configure"):
            self.ctx.error("change the probe when the machine is idle (not during a routine or a move)", "Use probe")
            return False
        try:
            text = self.ctx.commands.invoke(self.ctx.who(), "select_probe", name=name)
        except ERRORS as exc:
            self.ctx.error(exc, "Use probe")
            return False
        self.ctx.notify("Probe in use", text)
        self._refresh_probes()
        self._refresh_records()
        return True

    def enter_certificate(self, diameter: Any, serial: str, uncertainty_um: Any, form_um: Any = 0.0,
                          certified: str = "") -> bool:
        """The reference sphere's certificate as printed (diameter mm, serial, U k=2 and form in um, its date
        YYYY-MM-DD; empty: today)."""
        if not self.ctx.allowed("Save certificate"):
            return False
        try:
            cert = self.ctx.commands.invoke(self.ctx.who(), "set_sphere_certificate", diameter=diameter,
                                            serial=serial, uncertainty_um=uncertainty_um, form_um=form_um,
                                            certified=certified or None)
        except ERRORS + (TypeError,) as exc:
            self.ctx.error(f"{exc}. The previous certificate stays.", "Save certificate")
            return False
        self.ctx.notify("Certificate saved", cert["text"])
        self._set("certificate", "content", self.certificate_markdown())
        return True

    def _refresh_probes(self) -> None:
        self._set("probes", "content", self.probes_markdown())
        h = self.gui.get("probe_choice")
        if h is not None:
            rows = self.probes()
            names = tuple(r["name"] for r in rows) or ("Probe1",)
            if tuple(h.options) != names:
                h.options = names
            selected = next((r["name"] for r in rows if r["selected"]), names[0])
            if h.value != selected:
                h.value = selected

    # --- run -----------------------------------------------------------------------

    def _app_job(self) -> Job | None:
        return self.ctx.shared.calibration_job

    @property
    def running(self) -> bool:
        job = self._app_job()
        return job is not None and not job.done

    def _machine_allows(self, command: str) -> bool:
        """Whether the machine's state allows ``command`` now (the ``state`` query's commands allowed)."""
        return command in self._query("state").allowed

    def run(self, routine: str | None = None, **options: Any) -> Job | None:
        """Start a routine (the service runs it in the machine loop; this tab waits in its own thread, never in
        viser's). Options: probe ``per_ring``, ``polar_deg``, ``repeats``; iso ``repeats``; geometry
        ``repeats``, ``verify``; servo ``axes``."""
        routine = ROUTINES.get(routine, routine) if routine else self.routine  # type: ignore[arg-type]
        if routine not in LABELS:
            self.ctx.error(f"unknown routine {routine!r}; choose one of {', '.join(ROUTINES)}", "Calibration")
            return None
        label = LABELS[routine]
        if not self.ctx.allowed(label):
            return None
        if self.running or self._run_state()["running"]:
            title = self._app_job().title if self.running else "a calibration routine"  # type: ignore[union-attr]
            self.ctx.error(f"'{title}' is running: wait for it or press STOP", f"{label} refused")
            return None
        state = self._query("state")
        if "job" not in state.allowed:
            self.ctx.error(f"the machine is {state.mode.value}" + (f" ({state.reason})" if state.reason else "")
                           + ": calibrate when it is homed and idle (or press STOP)", f"{label} refused")
            return None
        problem = self._query("calibration_certificate", routine=routine)["problem"]
        if problem is not None:
            self.ctx.error(f"{problem}. The previous calibration stays in force.", f"{label} refused")
            return None
        self.routine = routine
        self._set("certificate", "content", self.certificate_markdown())  # the certificate the run uses
        self.result = None
        self.accepted = False
        self.saved = None
        self._set("results", "content", f"*{label} running...*")
        self._set("plot", "content", "")
        self._show_accept(False)
        job = Job(label, lambda progress: self.ctx.commands.invoke(self.ctx.who(), "qualify", routine=routine,
                                                                   progress=progress, options=options),
                  on_progress=self.progress_view.update, on_done=self._done)
        self.job = job
        self.ctx.shared.calibration_job = job
        self.progress_view.start(job)
        return job.start()

    def bar_placed(self) -> bool:
        """The operator has clamped the bar for the set-up shown: the routine goes on."""
        if not self.ctx.allowed("Bar placed"):
            return False
        placed = self.ctx.do("Bar placed", "bar_placed")  # the core decides who may; its refusal is shown
        if placed is None:
            return False
        if not placed:
            self.ctx.error("no set-up is waiting for the bar", "Bar placed")
            return False
        self._show_instruction()
        return True

    def cancel(self) -> None:
        """Stop the running routine (it ends with an error; the previous calibration stays in force)."""
        if not self.running:
            return
        self.ctx.do("Cancel", "cancel")  # the routine's own cancel: ends a wait, stops a move

    def pause(self) -> bool:
        """Hold the probe qualification after the point in progress."""
        if not self.running or self.routine != "probe":
            self.ctx.error("no probe qualification is running: only it can be paused", "Pause")
            return False
        answer = self.ctx.do("Pause", "pause")  # the core decides who may; its refusal is shown
        if answer is None:
            return False
        if not answer["paused"]:
            self.ctx.error("no probe qualification is running: only it can be paused", "Pause")
            return False
        self.ctx.notify("Qualification paused", "after the point in progress; Resume lifts to the clearance height "
                        "and goes on")
        return True

    def resume(self) -> bool:
        """A paused qualification goes on; one a fault stopped goes on after Reset with the points kept."""
        if self.running:
            answer = self.ctx.do("Resume", "resume")  # the core decides who may
            if answer is None:
                return False
            if not answer["resumed"]:
                self.ctx.error("the qualification is not paused", "Resume")
                return False
            return True
        if not self._run_state()["resumable"]:
            self.ctx.error("no qualification was paused or stopped by a fault: press Run", "Resume")
            return False
        g = self.gui
        opts: dict[str, Any] = {"resume": True}
        if "per_ring" in g:
            opts.update(per_ring=int(g["per_ring"].value), repeats=int(g["repeats"].value))
        return self.run("probe", **opts) is not None

    def _done(self, job: Job) -> None:
        if job.error is not None:
            exc = job.error
            known = isinstance(exc, ERRORS)
            text = (str(exc) if known else f"{type(exc).__name__}: {exc}") + ". The previous calibration stays in force."
            self.ctx.error(text, f"{job.title} stopped")
            self.progress_view.finish(job, text, False)
            self._set("results", "content", f"**stopped:** {html.escape(text)}")
            return
        self.result = (self.routine, job.result)
        self.progress_view.finish(job, job.message or "done", True)
        self.ctx.notify(f"{job.title} done", job.message)
        self._show_results()

    # --- results -------------------------------------------------------------------------

    def results_markdown(self) -> str:
        if self.result is None:
            return "*no results yet*"
        routine, r = self.result
        if routine == "probe":
            return probe_markdown(r)
        if routine == "iso":
            return iso_markdown(r)
        if routine == "geometry":
            return geometry_markdown(r)
        if routine == "servo":
            return servo_markdown(r, self.accepted)
        return ""

    def _show_results(self) -> None:
        self._set("results", "content", self.results_markdown())
        if self.result is not None and self.result[0] == "probe":
            self._set("plot", "content", residual_svg(self.result[1]))
        self._show_accept(self.result is not None and self.result[0] == "servo" and not self.accepted)

    def accept_gains(self) -> bool:
        """Send the proposed servo gains to the modules and record them (servo.toml, accepted)."""
        if self.result is None or self.result[0] != "servo":
            self.ctx.error("run the servo tuning first", "Accept gains")
            return False
        if self.running or not self._machine_allows("configure"):
            self.ctx.error("wait until the machine is idle", "Accept gains")
            return False
        try:
            self.saved = self.ctx.commands.invoke(self.ctx.who(), "accept_gains", result=self.result[1])
        except ERRORS as exc:
            self.ctx.error(exc, "Accept gains")
            return False
        self.accepted = True
        self.ctx.notify("Gains applied", f"recorded in {self.saved}; copy them into the machine configuration "
                                          "[gains] to keep them after a restart")
        self._show_results()
        self._refresh_records()
        return True

    def save_record(self) -> Path | None:
        """Write the last result's record; probe and geometry are also applied to the live machine."""
        if self.result is None:
            self.ctx.error("run a routine first: there is nothing to save", "Save record")
            return None
        if self.running:
            self.ctx.error("wait until the routine has finished", "Save record")
            return None
        routine, r = self.result
        try:
            path, applied = self.ctx.commands.invoke(self.ctx.who(), "save_calibration", routine=routine, result=r,
                                                     accepted=self.accepted)
        except ERRORS + (TypeError,) as exc:
            self.ctx.error(f"{exc}. The previous calibration stays in force.", "Save record failed")
            return None
        self.saved = path
        self.ctx.notify("Record saved", str(path) + (" and applied to the station" if applied else ""))
        self._refresh_records()
        self._refresh_probes()
        return path

    # --- GUI -----------------------------------------------------------------------------------

    def choose(self, label: str) -> None:
        self.routine = ROUTINES.get(label, label)
        self._set("certificate", "content", self.certificate_markdown())
        for key, routine in (("probe_opts", "probe"), ("iso_opts", "iso"), ("servo_opts", "servo"),
                             ("geometry_opts", "geometry")):
            if key in self.gui:
                self.gui[key].visible = routine == self.routine

    def _run_from_gui(self) -> None:
        g = self.gui
        opts: dict[str, Any] = {}
        if self.routine == "probe":
            opts = {"per_ring": int(g["per_ring"].value), "repeats": int(g["repeats"].value)}
        elif self.routine == "iso":
            opts = {"repeats": int(g["iso_repeats"].value)}
        elif self.routine == "geometry":
            opts = {"repeats": int(g["geo_repeats"].value), "verify": bool(g["verify"].value)}
        elif self.routine == "servo":
            v = g["axes"].value
            opts = {"axes": ("x", "y", "z") if v == "X, Y, Z" else (v.lower(),)}
        self.run(self.routine, **opts)

    def build(self, gui: Any) -> None:
        g = self.gui
        label = gui.add_dropdown("Routine", tuple(ROUTINES), initial_value=LABELS[self.routine])
        label.on_update(lambda e: self.choose(e.target.value))
        g["certificate"] = gui.add_markdown(self.certificate_markdown())
        with gui.add_folder("Reference sphere certificate", expand_by_default=False):
            g["cert_diameter"] = gui.add_number("Diameter (mm)", 25.0, min=1.0, max=200.0, step=0.0001)
            g["cert_serial"] = gui.add_text("Serial", "")
            g["cert_uncertainty"] = gui.add_number("U k=2 (um)", 0.1, min=0.0, max=10.0, step=0.01)
            g["cert_form"] = gui.add_number("Form (um)", 0.0, min=0.0, max=100.0, step=0.01)
            g["cert_date"] = gui.add_text("Certified on", "", hint="the certificate's date, YYYY-MM-DD; empty: today")
            gui.add_button("Save certificate").on_click(lambda _: self.enter_certificate(
                g["cert_diameter"].value, g["cert_serial"].value, g["cert_uncertainty"].value, g["cert_form"].value,
                g["cert_date"].value))
        with gui.add_folder("Probes", expand_by_default=True):
            g["probes"] = gui.add_markdown(self.probes_markdown())
            rows = self.probes()
            names = tuple(r["name"] for r in rows) or ("Probe1",)
            g["probe_choice"] = gui.add_dropdown("Probe", names, initial_value=next(
                (r["name"] for r in rows if r["selected"]), names[0]))
            gui.add_button("Use this probe").on_click(lambda _: self.select_probe(g["probe_choice"].value))
            g["new_name"] = gui.add_text("New probe name", "")
            g["new_tip"] = gui.add_number("Tip diameter (mm)", 2.0, min=0.1, max=30.0, step=0.01)
            g["new_stylus"] = gui.add_text("Stylus vector", "0, 0, -1",
                                           hint="I J K from the probe head to the tip, e.g. 0 0 -1 (vertical)")
            gui.add_button("Add probe").on_click(lambda _: self.add_probe(
                g["new_name"].value, g["new_tip"].value, g["new_stylus"].value))
        g["probe_opts"] = gui.add_folder("Probe options", expand_by_default=False)
        with g["probe_opts"]:
            g["per_ring"] = gui.add_number("Points per ring", 24, min=3, max=72, step=1)
            g["repeats"] = gui.add_number("Hits per point", 2, min=1, max=10, step=1)
        g["iso_opts"] = gui.add_folder("ISO options", expand_by_default=False, visible=False)
        with g["iso_opts"]:
            g["iso_repeats"] = gui.add_number("Hits per point", 1, min=1, max=10, step=1)
        g["geometry_opts"] = gui.add_folder("Geometry options", expand_by_default=False, visible=False)
        with g["geometry_opts"]:
            g["geo_repeats"] = gui.add_number("Hits per point", 1, min=1, max=10, step=1)
            g["verify"] = gui.add_checkbox("Verification pass", True)
        g["servo_opts"] = gui.add_folder("Servo options", visible=False)
        with g["servo_opts"]:
            g["axes"] = gui.add_dropdown("Axes", ("X", "Y", "Z", "X, Y, Z"), initial_value="X, Y, Z")
        gui.add_button("Run", color="green").on_click(lambda _: self._run_from_gui())
        gui.add_button_group("Calibration run", ("Pause", "Resume", "Cancel")).on_click(
            lambda e: {"Pause": self.pause, "Resume": self.resume, "Cancel": self.cancel}[e.target.value]())
        self.progress_view.build(gui)
        g["instruction"] = gui.add_markdown("")
        g["bar"] = gui.add_button("Bar placed, continue", color="orange", visible=False)
        g["bar"].on_click(lambda _: self.bar_placed())
        g["results"] = gui.add_markdown(self.results_markdown())
        g["plot"] = gui.add_html("")
        g["accept"] = gui.add_button("Accept gains", color="orange", visible=False)
        g["accept"].on_click(lambda _: self.accept_gains())
        gui.add_button("Save record").on_click(lambda _: self.save_record())
        with gui.add_folder("Records", expand_by_default=True):
            g["records"] = gui.add_markdown(self.records_markdown())
            gui.add_button("Reload list").on_click(lambda _: self._refresh_records())

    def _show_accept(self, on: bool) -> None:
        if "accept" in self.gui:
            self.gui["accept"].visible = on

    def _show_bar(self, on: bool) -> None:
        if "bar" in self.gui:
            self.gui["bar"].visible = on

    def _refresh_records(self) -> None:
        self._set("records", "content", self.records_markdown())

    def _show_instruction(self, text: str | None = None) -> None:
        """The ball-bar set-up the service waits for (shown in every tab; a toast in the tab that started it)."""
        text = self._run_state()["instruction"] if text is None else text
        if text == self._shown_instruction:
            return
        self._shown_instruction = text
        self._set("instruction", "content", text)
        self._show_bar(bool(text))
        if text and self.job is not None and not self.job.done:
            self.ctx.notify("Ball bar", text.replace("**", ""))

    def refresh(self) -> None:
        """Called by ClientApp.refresh (5 Hz): the set-up to place, and a routine started in another tab."""
        run = self._run_state()
        self._show_instruction(run["instruction"])
        job = self._app_job()
        if job is not None and not job.done and self.progress_view.status is not None and run["paused"]:
            text = (f"**PAUSED** {job.title}: {job.message}" + (" · holding; **Resume** lifts to the clearance "
                    "height and goes on" if run["holding"] else " · stopping after the point in progress"))
            if self.progress_view.status.content != text:
                self.progress_view.status.content = text
        if job is not None and job is not self.job and not job.done:
            if self.progress_view.status is not None:
                text = f"**{job.title}** (another tab): {job.fraction * 100:.0f} % · {job.message}"
                if self.progress_view.status.content != text:
                    self.progress_view.status.content = text

    def _set(self, key: str, attr: str, value: Any) -> None:
        h = self.gui.get(key)
        if h is not None and getattr(h, attr, None) != value:
            setattr(h, attr, value)


__all__ = ["CalibrationPanel", "ROUTINES", "residual_svg", "residual_series"]
