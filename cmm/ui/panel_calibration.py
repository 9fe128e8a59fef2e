"""The "Calibration" tab: a wizard over the calibration routines of :mod:`cmm.calibration`.

Choose the routine (probe qualification, ISO 10360-5 test, machine geometry,
servo tuning); the tab shows the artifact certificate in use and the records
now on disk (dates, results). **Run** needs control and an idle machine; the
routine runs in its own thread (never in viser's callback thread) and its
``progress`` callback drives a progress bar. When it ends: a results table
(probe: residuals by ring and a residual-vs-azimuth plot; ISO: the figures
uncalibrated / radius only / calibrated; geometry: scale, squareness and the
bar errors before / after; servo: original and proposed gains).

Nothing is applied by running: **Save record** writes the record
(atomically, ``records.save_record``) and, for the probe and the geometry,
applies it to the live station; servo gains are sent to the modules only by
**Accept gains**. A routine that fails (CalibrationError, SurfaceNotFound,
MotionError ...) is reported as a notification and the previous calibration
stays in force.

Machine geometry needs the ball bar placed for each set-up: on the simulator
the panel places it (``SimulatedCMM.place_artifacts``); on a real machine it
shows the set-up instruction and waits for **Bar placed, continue**.
"""

from __future__ import annotations

import html
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..calibration.records import (MACHINE_RECORD, PROBE_RECORD, SERVO_RECORD, SPHERE_CERTIFICATE,
                                   BallBarCertificate, CalibrationError, LoadedCalibration,
                                   dumps, load_certificate, load_machine_record, load_probe_record,
                                   load_servo_record, load_sphere_certificate, now, save_record, write_atomic)
from ..control import MotionError
from .panel_sessions import Job, ProgressView

if TYPE_CHECKING:
    from .panels import ClientApp

ROUTINES = {"Probe qualification": "probe", "ISO 10360-5 test": "iso", "Machine geometry": "geometry",
            "Servo tuning": "servo"}
LABELS = {v: k for k, v in ROUTINES.items()}
ISO_RECORD = "iso10360-5.toml"
SERVO_PROPOSAL = "servo-proposal.toml"
BAR_CERTIFICATES = ("ball_bar_300", "ball_bar_200")


def calibration_errors() -> tuple[type[BaseException], ...]:
    from ..control import SurfaceNotFound
    from ..metrology.features import FitError

    return (CalibrationError, SurfaceNotFound, MotionError, FitError, ValueError, OSError)


# --------------------------------------------------------------------------- tables and plots


def _um(v: float) -> str:
    return f"{v:+.2f}"


def probe_markdown(q: Any) -> str:
    r = q.record
    lines = ["| result | value |", "|---|---|",
             f"| effective tip radius r_eff | **{r.tip_radius:.5f} mm** (nominal {r.nominal_tip_radius}) |",
             f"| U (k=2) of r_eff | {r.uncertainty_um:.2f} um |",
             "| sphere centre | X={:.4f} Y={:.4f} Z={:.4f} |".format(*r.sphere_centre),
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


def records_summary(directory: Path) -> list[dict[str, str]]:
    """The records in ``directory``: kind, file, date, result (or the problem that makes them unusable)."""
    rows: list[dict[str, str]] = []
    entries: list[tuple[str, str, Callable[[Path], Any], Callable[[Any], str]]] = [
        ("probe", PROBE_RECORD, load_probe_record,
         lambda r: f"r_eff {r.tip_radius:.4f} mm, form {r.form_before_um:.2f} → {r.form_after_um:.2f} um, "
                   f"{r.n_points} points"),
        ("machine", MACHINE_RECORD, load_machine_record,
         lambda r: "scale {} ppm, squareness {} urad".format(", ".join(f"{x:+.1f}" for x in r.scale_ppm),
                                                              ", ".join(f"{x:+.1f}" for x in r.squareness_urad))),
        ("servo", SERVO_RECORD, load_servo_record,
         lambda r: "; ".join(f"{a.upper()} Kp {g.get('kp')} Kd {g.get('kd')} Ki {g.get('ki')}" for a, g in r.gains.items())
                   + (" (accepted)" if r.accepted else "")),
        ("servo proposal", SERVO_PROPOSAL, load_servo_record,
         lambda r: "; ".join(f"{a.upper()} Kp {g.get('kp')} Kd {g.get('kd')}" for a, g in r.gains.items())),
    ]
    for kind, name, loader, describe in entries:
        p = directory / name
        if not p.is_file():
            continue
        try:
            r = loader(p)
            rows.append({"kind": kind, "file": str(p), "date": r.date, "result": describe(r)})
        except CalibrationError as exc:
            rows.append({"kind": kind, "file": str(p), "date": "", "result": f"refused: {exc}"})
    p = directory / ISO_RECORD
    if p.is_file():
        import tomllib

        try:
            data = tomllib.loads(p.read_text())
            cal = data.get("results", {}).get("calibrated", {})
            rows.append({"kind": "ISO 10360-5", "file": str(p), "date": str(data.get("record", {}).get("date", "")),
                         "result": f"P_Form {cal.get('form_um', float('nan')):.2f} um, "
                                   f"P_Size {cal.get('size_um', float('nan')):+.2f} um"})
        except (tomllib.TOMLDecodeError, OSError, TypeError, ValueError) as exc:
            rows.append({"kind": "ISO 10360-5", "file": str(p), "date": "", "result": f"unreadable: {exc}"})
    return rows


# --------------------------------------------------------------------------- the panel


class CalibrationPanel:
    def __init__(self, capp: "ClientApp") -> None:
        self.capp = capp
        self.station = capp.station
        self.routine = "probe"
        self.job: Job | None = None
        self.result: tuple[str, Any] | None = None  # (routine, result object) of the last successful run
        self.accepted = False
        self.saved: Path | None = None
        self.instruction = ""
        self._bar_event: threading.Event | None = None
        self._cancel = False
        self.gui: dict[str, Any] = {}
        self.progress_view = ProgressView(capp)

    # --- where things are -------------------------------------------------------

    @property
    def records_dir(self) -> Path:
        d = self.station.calibration_dir
        return Path(d) if d is not None else Path("calibration")

    @property
    def artifacts_dir(self) -> Path:
        return self.records_dir / "artifacts"

    def certificates(self, routine: str) -> Any:
        """The certificate(s) a routine uses; CalibrationError says what is missing."""
        if routine in ("probe", "iso"):
            return load_sphere_certificate(self.artifacts_dir / SPHERE_CERTIFICATE)
        if routine == "geometry":
            certs = {}
            for f in sorted(self.artifacts_dir.glob("*.toml")):
                c = load_certificate(f)
                if isinstance(c, BallBarCertificate):
                    certs[f.stem.replace("-", "_")] = c
            missing = [k for k in BAR_CERTIFICATES if k not in certs]
            if missing:
                raise CalibrationError(f"the geometry routine needs the ball bar certificates "
                                       f"{', '.join(k.replace('_', '-') + '.toml' for k in missing)} in {self.artifacts_dir}")
            return certs
        return None

    def certificate_markdown(self, routine: str | None = None) -> str:
        routine = routine or self.routine
        if routine == "servo":
            return "Servo tuning uses no artifact: small step moves on each axis at mid-travel."
        try:
            cert = self.certificates(routine)
        except CalibrationError as exc:
            return f"**certificate problem:** {exc}"
        if isinstance(cert, dict):
            return "certificates: " + "; ".join(f"{c.describe()} (certified {c.certified})" for c in cert.values())
        centre = "" if cert.approx_centre is None else " · set-up centre X={:.1f} Y={:.1f} Z={:.1f}".format(
            *cert.approx_centre)
        return (f"certificate: **{cert.describe()}**, form {cert.form * 1000:.2f} um, U {cert.uncertainty * 1000:.2f} um"
                f" (certified {cert.certified}){centre}")

    def records(self) -> list[dict[str, str]]:
        return records_summary(self.records_dir)

    def records_markdown(self) -> str:
        rows = self.records()
        lines = [f"records in `{self.records_dir}`:", ""]
        if rows:
            lines += ["| record | date | result |", "|---|---|---|"]
            lines += [f"| {r['kind']} | {r['date']} | {r['result']} |" for r in rows]
        else:
            lines.append("*no records yet: the nominal settings are in force*")
        log = getattr(self.station, "calibration_log", None) or []
        if log:
            lines += ["", "in force: " + "; ".join(log)]
        return "\n".join(lines)

    # --- run -----------------------------------------------------------------------

    def _app_job(self) -> Job | None:
        return getattr(self.capp.app, "calibration_job", None)

    @property
    def running(self) -> bool:
        job = self._app_job()
        return job is not None and not job.done

    def run(self, routine: str | None = None, **options: Any) -> Job | None:
        """Start a routine in a background thread. Options: probe ``per_ring``, ``polar_deg``, ``repeats``;
        iso ``repeats``; geometry ``repeats``, ``verify``; servo ``axes``."""
        routine = ROUTINES.get(routine, routine) if routine else self.routine  # type: ignore[arg-type]
        if routine not in LABELS:
            self.capp.error(f"unknown routine {routine!r}; choose one of {', '.join(ROUTINES)}", "Calibration")
            return None
        label = LABELS[routine]
        if not self.capp.allowed(label):
            return None
        if self.running:
            self.capp.error(f"'{self._app_job().title}' is running: wait for it or press STOP", f"{label} refused")
            return None
        api = self.station.controller
        if not api.allowed("job"):
            self.capp.error(f"the machine is {api.state.mode.value}" + (f" ({api.state.reason})" if api.state.reason else "")
                            + ": calibrate when it is homed and idle (or press STOP)", f"{label} refused")
            return None
        try:
            certs = self.certificates(routine)
        except CalibrationError as exc:
            self.capp.error(f"{exc}. The previous calibration stays in force.", f"{label} refused")
            return None
        self.routine = routine
        self.result = None
        self.accepted = False
        self.saved = None
        self._cancel = False
        self._set("results", "content", f"*{label} running...*")
        self._set("plot", "content", "")
        self._show_accept(False)

        def in_machine_loop(progress: Callable[[float, str], None]) -> Any:
            # the routine runs in the control core's machine loop, with the machine to itself; its progress
            # reports reach the browser from the dispatcher thread
            def posted(fraction: float, message: str) -> None:
                api.dispatcher.post(progress, fraction, message)
            return api.run_job(self.capp.client_id, label, lambda: self._work(routine, certs, options, posted))

        job = Job(label, in_machine_loop,
                  on_progress=self.progress_view.update, on_done=self._done)
        self.job = job
        self.capp.app.calibration_job = job
        self.progress_view.start(job)
        return job.start()

    def _work(self, routine: str, certs: Any, options: dict[str, Any], progress: Callable[[float, str], None]) -> Any:
        st = self.station
        machine = st.machine
        if routine == "probe":
            from ..calibration.probe import qualify_probe

            master = None
            try:
                if (self.records_dir / PROBE_RECORD).is_file():
                    master = load_probe_record(self.records_dir / PROBE_RECORD).sphere_centre
            except CalibrationError:
                master = None
            kw = {k: options[k] for k in ("per_ring", "polar_deg", "repeats", "approx_centre") if k in options}
            kw.setdefault("repeats", 2)
            return qualify_probe(machine, certs, master_centre=master, progress=progress, **kw)
        if routine == "iso":
            from ..calibration.iso10360 import run_iso10360_5

            return run_iso10360_5(machine, certs, st.prober.settings, repeats=int(options.get("repeats", 1)),
                                  approx_centre=options.get("approx_centre"), progress=progress)
        if routine == "geometry":
            from ..calibration.geometry import calibrate_geometry, default_setups

            setups = default_setups(lengths={k: c.length for k, c in certs.items() if k in BAR_CERTIFICATES})
            previous = machine.correction
            try:
                result = calibrate_geometry(machine, st.prober.settings, certs, setups, self._placer(certs),
                                            repeats=int(options.get("repeats", 1)),
                                            verify=bool(options.get("verify", True)), progress=progress)
            finally:
                machine.correction = previous  # the new correction is applied by Save record only
                self.instruction = ""
                self._bar_event = None
            return result
        if routine == "servo":
            from ..calibration.servo import tune_servos

            axes = tuple(options.get("axes") or ("x", "y", "z"))
            return tune_servos(machine, axes, progress=progress)
        raise CalibrationError(f"unknown routine {routine!r}")

    def _placer(self, certs: dict[str, BallBarCertificate]) -> Callable[[Any], None]:
        if self.station.simulated:
            rng = np.random.default_rng(7)

            def place_sim(s: Any) -> None:  # the simulated operator clamps the bar within 0.3 mm
                d = certs[s.artifact].ball_diameter
                off = rng.uniform(-0.3, 0.3, 3)
                self.station.place_sim_artifacts([(np.add(s.ball1, off), d), (np.add(s.ball2, off), d)])
            return place_sim

        def place_operator(s: Any) -> None:
            event = threading.Event()
            self.instruction = (f"Place **{certs[s.artifact].describe()}** for set-up **{s.name}**: balls at "
                                "X={:.1f} Y={:.1f} Z={:.1f} and X={:.1f} Y={:.1f} Z={:.1f}, ".format(*s.ball1, *s.ball2)
                                + "clamp it, then press **Bar placed, continue**.")
            self._bar_event = event
            self._set("instruction", "content", self.instruction)
            self._show_bar(True)
            self.capp.notify("Ball bar", self.instruction.replace("**", ""))
            while not self.station.controller.wait_event(event, 0.2):
                if self._cancel:
                    raise CalibrationError("the operator cancelled the geometry calibration")
            self._show_bar(False)
            self._set("instruction", "content", "")
        return place_operator

    def bar_placed(self) -> bool:
        """The operator has clamped the bar for the set-up shown: the routine goes on."""
        if not self.capp.allowed("Bar placed"):
            return False
        if self._bar_event is None:
            self.capp.error("no set-up is waiting for the bar", "Bar placed")
            return False
        self._bar_event.set()
        return True

    def cancel(self) -> None:
        """Stop the running routine (it ends with an error; the previous calibration stays in force)."""
        if not self.running:
            return
        self._cancel = True
        if self._bar_event is not None:
            self._bar_event.set()
        self.capp.stop()

    def _done(self, job: Job) -> None:
        if job.error is not None:
            exc = job.error
            known = isinstance(exc, calibration_errors())
            text = (str(exc) if known else f"{type(exc).__name__}: {exc}") + ". The previous calibration stays in force."
            self.capp.error(text, f"{job.title} stopped")
            self.progress_view.finish(job, text, False)
            self._set("results", "content", f"**stopped:** {html.escape(text)}")
            return
        self.result = (self.routine, job.result)
        self.progress_view.finish(job, job.message or "done", True)
        self.capp.notify(f"{job.title} done", job.message)
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
        if not self.capp.allowed("Accept gains"):
            return False
        if self.result is None or self.result[0] != "servo":
            self.capp.error("run the servo tuning first", "Accept gains")
            return False
        if self.running or not self.station.controller.allowed("configure"):
            self.capp.error("wait until the machine is idle", "Accept gains")
            return False
        from ..calibration.servo import apply_gains

        r = self.result[1]
        try:
            self.station.controller.configure(self.capp.client_id,
                                              lambda: apply_gains(self.station.machine, r.proposed))
            self.saved = save_record(r.record(True, self.station.config.source), self.records_dir / SERVO_RECORD)
        except calibration_errors() as exc:
            self.capp.error(exc, "Accept gains")
            return False
        self.accepted = True
        self.station.note("servo gains accepted: " + "; ".join(
            f"{a.upper()} Kp {g.kp} Kd {g.kd} Ki {g.ki} IL {g.il}" for a, g in r.proposed.items()))
        self.capp.notify("Gains applied", f"recorded in {self.saved}; copy them into the machine configuration "
                                          "[gains] to keep them after a restart")
        self._show_results()
        self._refresh_records()
        return True

    def save_record(self) -> Path | None:
        """Write the last result's record; probe and geometry are also applied to the live station."""
        if not self.capp.allowed("Save record"):
            return None
        if self.result is None:
            self.capp.error("run a routine first: there is nothing to save", "Save record")
            return None
        if self.running:
            self.capp.error("wait until the routine has finished", "Save record")
            return None
        routine, r = self.result
        st = self.station
        try:
            if routine == "probe":
                path = save_record(r.record, self.records_dir / PROBE_RECORD)
                applied = st.apply_calibration(LoadedCalibration(probe=r.record), client=self.capp.client_id)
                self._log(applied)
                st.note(f"probe calibration applied: r_eff {r.record.tip_radius:.5f} mm, "
                        f"{r.settings.pretravel.describe()}")
            elif routine == "geometry":
                rec = r.record(self._geometry_artifact(), st.config.source)
                path = save_record(rec, self.records_dir / MACHINE_RECORD)
                applied = st.apply_calibration(LoadedCalibration(machine=rec), client=self.capp.client_id)
                self._log(applied)
                st.note(f"machine geometry applied: scale {rec.scale_ppm} ppm, squareness {rec.squareness_urad} urad")
            elif routine == "servo":
                path = save_record(r.record(self.accepted, st.config.source),
                                   self.records_dir / (SERVO_RECORD if self.accepted else SERVO_PROPOSAL))
            else:
                data = {"record": {"kind": "iso10360-5", "date": now(), "machine": st.config.source,
                                   "repeats": r.repeats},
                        "results": {k: {"form_um": f.form_um, "size_um": f.size_um, "diameter": f.diameter}
                                    for k, f in r.figures.items()}}
                path = write_atomic(self.records_dir / ISO_RECORD,
                                    dumps(data, "ISO 10360-5 style probing test written by the station's calibration tab."))
        except calibration_errors() + (TypeError,) as exc:
            self.capp.error(f"{exc}. The previous calibration stays in force.", "Save record failed")
            return None
        self.saved = path
        self.capp.notify("Record saved", str(path) + (" and applied to the station" if routine in ("probe", "geometry")
                                                      else ""))
        self._refresh_records()
        return path

    def _geometry_artifact(self) -> str:
        try:
            return ", ".join(sorted(c.describe() for c in self.certificates("geometry").values()))
        except CalibrationError:
            return "ball bar"

    def _log(self, applied: list[str]) -> None:
        log = list(getattr(self.station, "calibration_log", None) or [])
        kinds = {a.split(" ", 1)[0] for a in applied}
        log = [line for line in log if line.split(" ", 1)[0] not in kinds] + applied
        self.station.calibration_log = log

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
        gui.add_button("Cancel").on_click(lambda _: self.cancel())
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

    def refresh(self) -> None:
        """Called by ClientApp.refresh (5 Hz): a running routine started in another tab shows here too."""
        job = self._app_job()
        if job is not None and job is not self.job and not job.done:
            if self.progress_view.status is not None:
                text = f"**{job.title}** (another tab): {job.fraction * 100:.0f} % · {job.message}"
                if self.progress_view.status.content != text:
                    self.progress_view.status.content = text

    def _set(self, key: str, attr: str, value: Any) -> None:
        h = self.gui.get(key)
        if h is not None and getattr(h, attr, None) != value:
            setattr(h, attr, value)


__all__ = ["CalibrationPanel", "ROUTINES", "residual_svg", "residual_series", "records_summary"]
