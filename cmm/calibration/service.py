"""The station's calibration service: front ends run the calibration routines here, never on the machine.

The station (the composition root) builds one ``CalibrationService`` over a
narrow :class:`CalibrationHost` (the command API, the configuration, the simulator's bench), never
the station itself (``station.calibration``); the Calibration tab only calls it and shows
what it returns, so the UI imports neither the routines nor the records.

- ``load(directory)`` applies the records in force (probe settings, geometry correction) and keeps what it
  applied (``log``), their dates (``status``, written into each session's start) and the qualified probing
  speed manual hits are limited to; ``apply(loaded, client)`` applies records while the machine is still;
- ``run(client, routine, ...)`` runs one routine through the command API's
  ``run_job`` verb (in the machine loop, with the machine the control core hands
  it, the client's access checked there; the ``cancel`` verb ends it); its result
  is returned, nothing is applied.
- ``save(client, routine, result)`` writes the record atomically and, for the
  probe and the geometry, applies it through the ``configure`` verb (while the
  machine is still); ``accept_gains`` sends proposed servo gains the same way.
- ``records()``, ``certificate_text()``, ``certificate_problem()``,
  ``in_force()``, ``instruction`` (a ball-bar set-up the operator must place)
  are plain data for any front end.

Machine geometry places the ball bar for each set-up: on the simulator the
service places it (under the simulator's lock, through the simulator's bench, :class:`CalibrationHost`);
on a real machine it publishes the set-up in ``instruction`` and waits (keeping
the machine loop running) for ``bar_placed()`` or ``cancel()``.
"""

from __future__ import annotations

import threading
import tomllib
from pathlib import Path
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from ..machine.probing import SurfaceNotFound
from ..machine.status import MotionError
from ..metrology.features import FitError
from .probe_list import DEFAULT_PROBE, ProbeList  # noqa: F401  (DEFAULT_PROBE: still importable from here)
from .records import (MACHINE_RECORD, PROBE_LIST, PROBE_QUALIFICATIONS, PROBE_RECORD, SERVO_RECORD,
                      SPHERE_CERTIFICATE, BallBarCertificate, CalibrationError, LoadedCalibration, ProbeDefinition,
                      dumps, load_certificate, load_machine_record, load_probe_record, load_servo_record,
                      load_sphere_certificate, now, save_record, write_atomic, write_sphere_certificate)

ROUTINES = {"Probe qualification": "probe", "ISO 10360-5 test": "iso", "Machine geometry": "geometry",
            "Servo tuning": "servo"}
LABELS = {v: k for k, v in ROUTINES.items()}
ISO_RECORD = "iso10360-5.toml"
SERVO_PROPOSAL = "servo-proposal.toml"
BAR_CERTIFICATES = ("ball_bar_300", "ball_bar_200")
Progress = Callable[[float, str], None]


def calibration_errors() -> tuple[type[BaseException], ...]:
    """The errors a routine or a save ends with that are an operator's message, not a crash."""
    return (CalibrationError, SurfaceNotFound, MotionError, FitError, ValueError, OSError)


def probe_status(record: Any) -> dict[str, Any]:
    """What the station shows and journals of the probe qualification in force."""
    return {"date": record.date, "tip_radius": record.tip_radius, "artifact": record.artifact,
            "probing_speed": record.probing_speed}


def machine_status(record: Any) -> dict[str, Any]:
    """What the station shows and journals of the machine geometry calibration in force."""
    return {"date": record.date, "scale_ppm": list(record.scale_ppm), "squareness_urad": list(record.squareness_urad)}

class Bench(Protocol):
    """The simulator's bench (:class:`cmm.sim.bench.SimBench`): what the simulated operator does at the machine."""

    sphere_centre: tuple[float, float, float]

    def place_artifacts(self, spheres: list) -> None: ...

    def mount_stylus(self, tip_diameter: float) -> None: ...


@dataclass(frozen=True)
class CalibrationHost:
    """What the service needs, and nothing of the station: the composition root hands it these."""

    api: Any  # the command API (cmm.api.CommandAPI): its run_job, configure, stop and note verbs
    config: Any  # the machine configuration (probing speed, nominal tip, its source for the records)
    settings_lock: Any  # held while records are applied (the measurement reads the probe settings under it)
    wait_event: Callable[[threading.Event, float], bool]  # wait for the operator while the machine loop serves STOP
    bench: Bench | None = None  # the simulator's bench; None: a real machine (its operator places the ball bar)


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
        try:
            data = tomllib.loads(p.read_text())
            cal = data.get("results", {}).get("calibrated", {})
            rows.append({"kind": "ISO 10360-5", "file": str(p), "date": str(data.get("record", {}).get("date", "")),
                         "result": f"P_Form {cal.get('form_um', float('nan')):.2f} um, "
                                   f"P_Size {cal.get('size_um', float('nan')):+.2f} um"})
        except (tomllib.TOMLDecodeError, OSError, TypeError, ValueError) as exc:
            rows.append({"kind": "ISO 10360-5", "file": str(p), "date": "", "result": f"unreadable: {exc}"})
    return rows


class CalibrationService:
    """The calibration routines, records and results of the station, for every front end. ``use_probe(name)`` makes
    a probe the one the measurement journals with its hits; ``tell(kind, message)`` writes the operator's event
    log (the station wires both to its measurement model)."""

    def __init__(self, host: CalibrationHost, directory: str | Path | None = None, *,
                 use_probe: Callable[[str], None] = lambda _name: None,
                 tell: Callable[[str, str], None] = lambda _kind, _message: None) -> None:
        self.host = host
        self.use_probe = use_probe
        self.tell = tell
        self.directory = None if directory is None else Path(directory)  # records are read and written here
        self.log: list[str] = []  # what was applied from the records, and the records refused
        self.status: dict[str, Any] = {"probe": None, "machine": None, "problems": []}  # for the session journal
        self.errors = calibration_errors()
        self.instruction = ""  # the ball-bar set-up the operator is asked to place ("" when none waits)
        self._bar_event: threading.Event | None = None
        self._cancel = False
        self._running = threading.Lock()  # one routine at a time, whichever front end started it
        self._go = threading.Event()  # cleared while the operator has paused the probe qualification
        self._go.set()
        self.paused = False
        self.holding = False  # a paused qualification holds the machine between two points
        self.checkpoint: Any = None  # a probe qualification a fault stopped (QualificationCheckpoint), to resume
        self._artifacts: Path | None = None
        self._sphere_cache: tuple[Any, Any] | None = None  # (certificate file stamp, reference_sphere())
        self.probe_book = ProbeList(self)  # the probe list and each probe's qualification record

    # --- the records in force -----------------------------------------------------

    def load(self, directory: str | Path = "calibration") -> list[str]:
        """Apply <directory>/probe.toml (ProbeSettings) and machine.toml (machine.correction) to the live machine.

        A missing record leaves the nominal settings; a malformed one is reported and not applied.
        """
        from .records import load_station_calibration

        self.directory = Path(directory)
        loaded = load_station_calibration(directory)
        nominal = None
        try:
            probes, selected = self.use_listed_probe()
            if loaded.probe is None and (self.records_dir / PROBE_LIST).is_file():
                nominal = next(p for p in probes if p.name == selected)  # selected, never qualified
        except CalibrationError as exc:
            loaded.problems.append(str(exc))
        applied = self.apply(loaded)
        if nominal is not None:
            applied.append(self.probe_book.apply_nominal(None, nominal))
        for problem in loaded.problems:
            self.tell("error", f"calibration record refused: {problem}")
        self.log = applied + [f"refused: {p}" for p in loaded.problems]
        self.status = {"probe": None if loaded.probe is None else probe_status(loaded.probe),
                       "machine": None if loaded.machine is None else machine_status(loaded.machine),
                       "problems": list(loaded.problems)}
        return self.log

    def apply(self, loaded: Any, client: str | None = None) -> list[str]:
        """Apply loaded calibration records to the live machine and probe (in the machine loop, while still)."""
        from .records import apply_calibration

        host = self.host
        with host.settings_lock:
            return host.api.invoke(
                client, "configure", change=lambda setup: apply_calibration(loaded, setup.machine, setup.prober))

    @property
    def qualified_probing_speed(self) -> float:
        """The speed the probe was qualified at (its record), else the configured probing speed (mm/s): manual
        hits are taken at no more than this (the pre-travel calibration holds only at that speed)."""
        probe = self.status.get("probe") or {}
        speed = float(probe.get("probing_speed") or 0.0)
        return speed if speed > 0 else float(self.host.config.speeds.probing)

    # --- the probe list ------------------------------------------------------------

    def use_listed_probe(self) -> tuple[list[ProbeDefinition], str]:
        """The list's selected probe (Probe1 without a list) becomes the probe in use (:class:`ProbeList`)."""
        return self.probe_book.use_listed()

    def probe_list(self) -> tuple[list[ProbeDefinition], str]:
        """(probes, selected) from <records>/probes.toml (:meth:`ProbeList.listing`)."""
        return self.probe_book.listing()

    def probe_record(self, name: str) -> Any:
        """The last qualification of probe ``name`` (a ProbeRecord), None when it was never qualified."""
        return self.probe_book.record(name)

    def probes(self) -> list[dict[str, Any]]:
        """The probe list for a front end, one row per probe (:meth:`ProbeList.rows`)."""
        return self.probe_book.rows()

    def add_probe(self, name: str, tip_diameter: Any, stylus: Any = (0.0, 0.0, -1.0)) -> ProbeDefinition:
        """Add a stylus to the list (not selected, not qualified); CalibrationError when the entry is wrong."""
        return self.probe_book.add(name, tip_diameter, stylus)

    def select_probe(self, client: Any, name: str) -> str:
        """Make ``name`` the probe in use (:meth:`ProbeList.select`); returns what was applied."""
        return self.probe_book.select(client, name)

    def set_sphere_certificate(self, *, diameter: Any, serial: str, uncertainty: Any, form: Any = 0.0,
                               centre: Any = None, client: Any = None, certified: str | None = None) -> Any:
        """Write the reference sphere's certificate where qualification and the ISO test read it. ``centre``
        None keeps the set-up centre of the previous certificate (on the simulator: where its sphere stands);
        the journal notes it as ``client`` (the operator who entered it)."""
        path = self.artifacts_dir / SPHERE_CERTIFICATE
        if centre is None:
            try:
                centre = load_sphere_certificate(path).approx_centre
            except CalibrationError:
                centre = None
            if centre is None and self.host.bench is not None:
                centre = self.host.bench.sphere_centre
        cert = write_sphere_certificate(path, diameter=diameter, serial=serial, uncertainty=uncertainty, form=form,
                                        centre=centre, certified=certified)
        self._note(client, f"reference sphere certificate entered: {cert.describe()}, "
                           f"U {cert.uncertainty * 1000:.2f} um")
        return cert

    # --- where things are ---------------------------------------------------------

    def reference_sphere(self) -> tuple[tuple[float, float, float], float] | None:
        """Where the reference sphere stands and its diameter (machine mm), for the motion rails to keep the tip
        clear of it: its certificate's set-up centre and diameter, else the simulator's sphere; None when neither
        says. Read again only when the certificate file changes (the rails ask before every move)."""
        path = self.artifacts_dir / SPHERE_CERTIFICATE
        try:
            stamp: Any = (str(path), path.stat().st_mtime_ns)
        except OSError:
            stamp = None
        if self._sphere_cache is not None and self._sphere_cache[0] == stamp:
            return self._sphere_cache[1]
        found = None
        if stamp is not None:
            try:
                cert = load_sphere_certificate(path)
                if cert.approx_centre is not None:
                    found = (tuple(float(v) for v in cert.approx_centre), float(cert.diameter))
            except CalibrationError:
                found = None
        bench = self.host.bench
        if found is None and bench is not None:
            found = (bench.sphere_centre, float(bench.settings.sphere_diameter))
        self._sphere_cache = (stamp, found)
        return found

    @property
    def records_dir(self) -> Path:
        return self.directory if self.directory is not None else Path("calibration")

    @property
    def artifacts_dir(self) -> Path:
        """The artifact certificates (default: ``<records>/artifacts``; a front end may point elsewhere)."""
        return self._artifacts if self._artifacts is not None else self.records_dir / "artifacts"

    @artifacts_dir.setter
    def artifacts_dir(self, path: Path | None) -> None:
        self._artifacts = None if path is None else Path(path)

    @property
    def running(self) -> bool:
        return self._running.locked()

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
        if routine == "servo":
            return None
        raise CalibrationError(f"unknown routine {routine!r}; choose one of {', '.join(LABELS)}")

    def certificate_problem(self, routine: str) -> str | None:
        """Why ``routine`` cannot run with the certificates on disk (None: it can)."""
        try:
            self.certificates(routine)
        except CalibrationError as exc:
            return str(exc)
        return None

    def certificate_text(self, routine: str) -> str:
        """The artifact certificate(s) in use, one line of markdown."""
        if routine == "servo":
            return "Servo tuning uses no artifact: small step moves on each axis at mid-travel."
        if routine in ("probe", "iso") and not (self.artifacts_dir / SPHERE_CERTIFICATE).is_file():
            return (f"**certificate problem:** no reference sphere certificate in {self.artifacts_dir} yet: enter the "
                    "sphere's diameter, serial and uncertainty from its certificate in the folder below")
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

    def in_force(self) -> list[str]:
        """What the station applied from the records (and the records it refused)."""
        return list(self.log or [])

    # --- run --------------------------------------------------------------------------

    def run(self, client: Any, routine: str, progress: Progress | None = None, **options: Any) -> Any:
        """Run ``routine`` (probe, iso, geometry, servo) through the command API; blocks until it ends and returns
        its result (nothing applied). Options: probe ``per_ring``, ``polar_deg``, ``repeats``, ``approx_centre``;
        iso ``repeats``, ``approx_centre``; geometry ``repeats``, ``verify``, ``place`` (how the operator is asked
        to place the bar, ``place(setup)`` in the machine loop: a terminal prompt; default :meth:`placer`);
        servo ``axes``.
        Probe ``resume=True``: go on with the qualification a fault stopped (:attr:`checkpoint`) instead of
        starting it again.
        Raises Refused (machine busy, no control), CalibrationError, or the routine's error."""
        routine = ROUTINES.get(routine, routine)
        if routine not in LABELS:
            raise CalibrationError(f"unknown routine {routine!r}; choose one of {', '.join(ROUTINES)}")
        if not self._running.acquire(blocking=False):
            raise CalibrationError("a calibration routine is running: wait for it or press STOP")
        try:
            certs = self.certificates(routine)
            self._cancel = False
            self.paused = False
            self._go.set()
            return self.host.api.invoke(
                client, "run_job", description=LABELS[routine], work=lambda job: self._work(job, routine, certs, options),
                progress=progress, cancel=self._cancel_run,
                **({"pause": self.pause, "resume": self.resume} if routine == "probe" else {}))  # the verbs
        finally:
            self.instruction = ""
            self._bar_event = None
            self._running.release()

    def _work(self, job: Any, routine: str, certs: Any, options: dict[str, Any]) -> Any:
        """In the machine loop (the core's run_routine): the routine has the job's machine to itself."""
        machine, settings, progress = job.machine, job.prober.settings, job.progress
        if routine == "probe":
            from .probe import qualify_probe

            master = None
            try:
                if (self.records_dir / PROBE_RECORD).is_file():
                    master = load_probe_record(self.records_dir / PROBE_RECORD).sphere_centre
            except CalibrationError:
                master = None
            from .probe import QualificationInterrupted

            kw = {k: options[k] for k in ("per_ring", "polar_deg", "repeats", "approx_centre") if k in options}
            kw.setdefault("repeats", 2)
            probes, selected = self.probe_list()
            tip = next(p.tip_diameter / 2 for p in probes if p.name == selected)
            key = (selected, certs.serial, certs.diameter)
            resume = None
            if options.get("resume"):
                resume = self.checkpoint
                if resume is None:
                    raise CalibrationError("there is no stopped probe qualification to resume: press Run")
                if resume.key[:3] != key:
                    raise CalibrationError(f"the stopped qualification was of probe {resume.key[0]} on sphere "
                                           f"{resume.key[1]}: select that probe, or press Run to qualify again")
                kw = dict(resume.key[3])  # the pattern it was measuring
            key = (*key, tuple(sorted(kw.items())))
            try:
                result = qualify_probe(machine, certs, master_centre=master, progress=progress, tip_radius=tip,
                                       resume=resume, between=self._between_points, key=key, **kw)
            except QualificationInterrupted as exc:
                self.checkpoint = exc.checkpoint  # Reset, then resume: the points measured are kept
                raise CalibrationError(f"{exc}. {len(exc.checkpoint.points)} points are kept: press Reset, then "
                                       "Resume qualification") from None
            self.checkpoint = None
            result.record.note = f"probe {selected}: {result.record.note}"
            result.probe = selected  # the probe it qualified: save() files the record under its name
            return result
        if routine == "iso":
            from .iso10360 import run_iso10360_5
            from .probe import SphereProber

            if progress is not None:
                progress(0.0, "lifting to the clearance height")
            SphereProber(machine).lift_clear(options.get("approx_centre") or certs.approx_centre or machine.position,
                                             certs.diameter / 2)

            return run_iso10360_5(machine, certs, settings, repeats=int(options.get("repeats", 1)),
                                  approx_centre=options.get("approx_centre"), progress=progress)
        if routine == "geometry":
            from .geometry import calibrate_geometry, default_setups

            setups = default_setups(lengths={k: c.length for k, c in certs.items() if k in BAR_CERTIFICATES})
            previous = machine.correction
            try:
                return calibrate_geometry(machine, settings, certs, setups, options.get("place") or self.placer(certs),
                                          repeats=int(options.get("repeats", 1)),
                                          verify=bool(options.get("verify", True)), progress=progress)
            finally:
                machine.correction = previous  # still in the job: the new correction is applied by save() only
        from .servo import tune_servos

        return tune_servos(machine, tuple(options.get("axes") or ("x", "y", "z")), progress=progress)

    def placer(self, certs: dict[str, BallBarCertificate]) -> Callable[[Any], None]:
        """How each ball-bar set-up gets its bar: the simulated operator, or the real one (instruction + wait)."""
        bench = self.host.bench
        if bench is not None:
            rng = np.random.default_rng(7)

            def place_sim(s: Any) -> None:  # the simulated operator clamps the bar within 0.3 mm
                d = certs[s.artifact].ball_diameter
                off = rng.uniform(-0.3, 0.3, 3)
                bench.place_artifacts([(np.add(s.ball1, off), d), (np.add(s.ball2, off), d)])
            return place_sim

        def place_operator(s: Any) -> None:
            event = threading.Event()
            self._bar_event = event
            self.instruction = (f"Place **{certs[s.artifact].describe()}** for set-up **{s.name}**: balls at "
                                "X={:.1f} Y={:.1f} Z={:.1f} and X={:.1f} Y={:.1f} Z={:.1f}, ".format(*s.ball1, *s.ball2)
                                + "clamp it, then press **Bar placed, continue**.")
            try:
                while not self.host.wait_event(event, 0.2):
                    if self._cancel:
                        break
                if self._cancel:
                    raise CalibrationError("the operator cancelled the geometry calibration")
            finally:
                self.instruction = ""
                self._bar_event = None
        return place_operator

    def pause(self) -> bool:
        """Hold the running probe qualification after the point in progress (False: none runs)."""
        if not self.running:
            return False
        self.paused = True
        self._go.clear()
        return True

    def resume(self) -> bool:
        """Go on with a paused qualification: it lifts to the safe height, then measures the next point."""
        was = self.paused
        self.paused = False
        self._go.set()
        return was

    def _between_points(self) -> bool:
        """In the machine loop, before each qualification point: hold while paused (the loop keeps serving STOP
        and E-STOP); True when it was paused."""
        if self._go.is_set():
            return False
        self.holding = True
        try:
            while not self.host.wait_event(self._go, 0.2):
                if self._cancel:
                    break
        finally:
            self.holding = False
        if self._cancel:
            raise CalibrationError("the operator cancelled the qualification while it was paused")
        return True

    def bar_placed(self) -> bool:
        """The operator has clamped the bar for the set-up shown: the routine goes on. False: nothing waits."""
        event = self._bar_event
        if event is None:
            return False
        event.set()
        return True

    def _cancel_run(self) -> None:
        """The ``cancel`` verb: a routine waiting for the operator ends there; one that moves is stopped (its
        routines do not look for a cancel between their hits)."""
        waiting = self._bar_event is not None or self.holding  # a paused qualification holds: nothing moves
        self.cancel()
        if not waiting:
            self.host.api.invoke(None, "stop")

    def cancel(self) -> None:
        """End a routine that waits for the operator (the front end also sends STOP for one that moves)."""
        if not self.running:
            return
        self._cancel = True
        self._go.set()
        event = self._bar_event
        if event is not None:
            event.set()

    # --- results ---------------------------------------------------------------------------

    def save(self, client: Any, routine: str, result: Any, *, accepted: bool = False) -> tuple[Path, bool]:
        """Write ``result``'s record; the probe and the geometry are also applied to the live machine (through
        the ``configure`` verb). Returns (path, applied)."""
        host = self.host
        if routine == "probe":
            probes, selected = self.probe_list()
            name = getattr(result, "probe", None) or selected
            self.probe_book.keep_legacy_record(probes)
            save_record(result.record, self.records_dir / PROBE_QUALIFICATIONS / f"{name}.toml")
            if name != selected:  # qualified while another probe was selected: filed, not applied
                return self.records_dir / PROBE_QUALIFICATIONS / f"{name}.toml", False
            path = save_record(result.record, self.records_dir / PROBE_RECORD)
            self._log(self.apply(LoadedCalibration(probe=result.record), client=client))
            self.status["probe"] = probe_status(result.record)  # the status bar and manual hits' speed follow it
            self._note(client, f"probe calibration applied: r_eff {result.record.tip_radius:.5f} mm, "
                               f"{result.settings.pretravel.describe()}")
            return path, True
        if routine == "geometry":
            rec = result.record(self._geometry_artifact(), host.config.source)
            path = save_record(rec, self.records_dir / MACHINE_RECORD)
            self._log(self.apply(LoadedCalibration(machine=rec), client=client))
            self.status["machine"] = machine_status(rec)
            self._note(client, f"machine geometry applied: scale {rec.scale_ppm} ppm, squareness {rec.squareness_urad} urad")
            return path, True
        if routine == "servo":
            return save_record(result.record(accepted, host.config.source),
                               self.records_dir / (SERVO_RECORD if accepted else SERVO_PROPOSAL)), False
        if routine == "iso":
            data = {"record": {"kind": "iso10360-5", "date": now(), "machine": host.config.source,
                               "repeats": result.repeats},
                    "results": {k: {"form_um": f.form_um, "size_um": f.size_um, "diameter": f.diameter}
                                for k, f in result.figures.items()}}
            return write_atomic(self.records_dir / ISO_RECORD,
                                dumps(data, "ISO 10360-5 style probing test written by the station's calibration tab.")), False
        raise CalibrationError(f"unknown routine {routine!r}")

    def accept_gains(self, client: Any, result: Any) -> Path:
        """Send a servo tuning's proposed gains to the modules (the ``configure`` verb) and record them."""
        from .servo import apply_gains

        host = self.host
        host.api.invoke(client, "configure", change=lambda setup: apply_gains(setup.machine, result.proposed))
        path = save_record(result.record(True, host.config.source), self.records_dir / SERVO_RECORD)
        self._note(client, "servo gains accepted: " + "; ".join(
            f"{a.upper()} Kp {g.kp} Kd {g.kd} Ki {g.ki} IL {g.il}" for a, g in result.proposed.items()))
        return path

    def _note(self, client: Any, text: str) -> None:
        """A line in the session journal, as ``client`` (the command API's ``note`` verb)."""
        self.host.api.invoke(client, "note", text=text)

    def _geometry_artifact(self) -> str:
        try:
            certs = self.certificates("geometry")
            return ", ".join(sorted({certs[k].describe() for k in BAR_CERTIFICATES}))  # the bars the set-ups use
        except CalibrationError:
            return "ball bar"

    def _log(self, applied: list[str]) -> None:
        kinds = {a.split(" ", 1)[0] for a in applied}
        self.log = [line for line in self.in_force() if line.split(" ", 1)[0] not in kinds] + applied


__all__ = ["BAR_CERTIFICATES", "CalibrationHost", "CalibrationService", "LABELS", "ROUTINES", "calibration_errors",
           "records_summary"]
