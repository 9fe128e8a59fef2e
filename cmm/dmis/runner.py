"""Run a DMIS program on the station: check it all, then run it as one job of the control core.

:func:`run_text` refuses a program with any problem (syntax, an unsupported statement, an unclosed block) before
anything moves, then holds the machine for the whole run (the command API's ``run_job`` verb) and moves and probes
through the same API, so the access policy, STOP, ``cancel`` and the journal work as for every other front end.

A program that measures in manual mode (``MODE/MAN`` or ``MODE/PROG, MAN``) cannot hold the machine: the
operator jogs and probes between its statements. It runs outside a job, each move and hit its own command of
the client that runs it (the access policy keeps others out), and waits at each manual ``MEAS`` for the
operator's hits: ``manual_hits(prompt, n, guides)`` when given (the command line asks at the terminal, tests
probe where the part really is), else the next n hits the operator takes, the prompt shown through ``on_prompt``.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..control.modes import Refused
from ..measurement.run_end import end_at_clearance
from .check import check, outside_recalls, warnings
from .executor import DmisError, Executor, RunResult
from .parser import Statement, Word
from .rules import sensor_problems

ManualHits = Callable[[str, int, list[tuple[np.ndarray, np.ndarray]]], list[int]]
Query = Callable[[str, bool], str]  # (prompt, an answer wanted) -> the operator's answer ("" to confirm)


class ModelView:
    """The measurement model as a DMIS run reads it: each attribute from the command API's ``model`` query (a
    snapshot taken under the model's lock), never the model itself."""

    def __init__(self, commands: Any, client: Any) -> None:
        self._commands, self._client = commands, client

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._commands.invoke(self._client, "model"), name)


class StationTarget:
    """The station as a DMIS target, through its command API as ``client``: straight moves, programmed hits with
    the program's cycle, the model's fits and records (verbs), its hits and features (queries)."""

    def __init__(self, commands: Any, client: Any = None, timeout: float = 120.0, *,
                 manual_hits: ManualHits | None = None, on_prompt: Callable[[str], None] | None = None,
                 manual_timeout: float = 1800.0, cancel: threading.Event | None = None,
                 query: Query | None = None) -> None:
        self.commands = commands  # moves, hits, fits and records go through the command API as ``client``
        self.model = ModelView(commands, client)
        self.client = client
        self.timeout = timeout
        self._manual_hits = manual_hits
        self.on_prompt = on_prompt
        self.manual_timeout = manual_timeout
        self.cancel = cancel or threading.Event()
        self._query = query

    def _tell(self, text: str) -> None:
        if self.on_prompt is not None:
            self.on_prompt(text)

    def hold(self, done: Callable[[], bool]) -> None:
        """Wait (the machine standing still, the machine loop serving STOP) until ``done()``."""
        event = threading.Event()
        while not done():  # inside the machine loop: the loop goes on serving STOP
            self.commands.invoke(self.client, "loop_wait", event=event, timeout=0.1)

    def tell(self, text: str) -> None:
        """TEXT/OPER: the operator reads it (the page's program status, the terminal) and the journal keeps it."""
        self._tell(text)
        self.note(f"DMIS operator text: {text}")

    def ask(self, prompt: str, *, answer: bool) -> str:
        """TEXT/MAN (confirm) and TEXT/QUERY (answer): the operator's reply, the given way; refused in words
        where no operator can be asked."""
        if self._query is None:
            raise DmisError(f"{prompt.split(':')[0]}: the program asks the operator "
                            f"({'for an answer' if answer else 'to confirm'}) and this run has no one to ask: run "
                            "it at a terminal or from the page's Routine tab")
        self._tell(prompt)
        # the operator answers in another thread (the page's Answer, the terminal): the run holds meanwhile, the
        # machine loop serving STOP when the run holds the machine
        got: list[Any] = []

        def ask() -> None:
            try:
                got.append(("answer", str(self._query(prompt, answer))))  # type: ignore[misc]
            except BaseException as exc:  # noqa: BLE001 - raised in the run's thread below
                got.append(("error", exc))

        threading.Thread(target=ask, name="dmis question", daemon=True).start()
        try:
            self.hold(lambda: bool(got))
        finally:
            self._tell("")
        kind, value = got[0]
        if kind == "error":
            raise value
        return value

    def manual_hits(self, prompt: str, n: int, guides: list[tuple[np.ndarray, np.ndarray]]) -> list[int]:
        """The ids of n hits the operator takes by hand (MODE/MAN): the given way, else the next n hits that
        reach the measurement model (taken with the pendant or the page's armed jog), the prompt told meanwhile."""
        if self._manual_hits is not None:
            self._tell(prompt)
            try:
                return list(self._manual_hits(prompt, n, guides))
            finally:
                self._tell("")
        start = set(self.model.hits)
        end = time.monotonic() + self.manual_timeout
        told = ""
        try:
            while True:
                new = [h for h in self.model.hits if h not in start]
                if len(new) >= n:
                    return new[:n]
                if self.cancel.is_set():
                    raise DmisError(f"{prompt.split(':')[0]}: the program was cancelled while waiting for hits by hand")
                if time.monotonic() > end:
                    raise DmisError(f"{prompt.split(':')[0]}: no {n} hits by hand within {self.manual_timeout:g} s")
                text = f"{prompt} ({len(new)} of {n} taken)"
                if text != told:
                    self._tell(text)
                    told = text
                time.sleep(0.1)  # a person's pace
        finally:
            self._tell("")

    def position(self) -> np.ndarray:
        return np.asarray(self.commands.invoke(self.client, "position", frame="machine"), float)

    def move(self, target: np.ndarray, speed: float | None) -> None:
        """A DMIS GOTO: a straight line, which the control core's rails take only when it is proven free of the
        part (else they refuse it in words, and the program stops on that line)."""
        self.commands.invoke(self.client, "move", target=target, frame="machine", path="straight",
                             speed=speed).wait(self.timeout)

    def probe(self, point: np.ndarray, approach: np.ndarray, *, speed: float | None, approach_distance: float,
              search_distance: float, retract_distance: float, rapid_speed: float | None) -> int:
        """A PTMEAS: straight to the pre-hit point (proven free of the part), then the probing move."""
        hit = self.commands.invoke(self.client, "probe", target=point, approach=approach, frame="machine",
                                   path="straight", speed=speed or self.probing_speed,
                                   approach_distance=approach_distance, search_distance=search_distance,
                                   retract_distance=retract_distance, rapid_speed=rapid_speed).wait(self.timeout)
        return self.hit_id(hit)

    def hit_id(self, hit: Any) -> int:
        """The session id of the hit a probe verb returned (the model recorded it as it came)."""
        key = (hit.time, tuple(hit.counts), tuple(hit.machine))
        hits = self.model.hits
        for hid in reversed(list(hits)):
            h = hits[hid]
            if (h.time, tuple(h.counts), tuple(h.machine)) == key:
                return int(hid)
        raise DmisError("the hit was not recorded")

    def align(self, measured: np.ndarray, nominal: np.ndarray, points: np.ndarray, name: str) -> str:
        """The program's alignment moves the station's part (the align verb, as the page's Align tab does): the
        rails, the 3-D view and the report then see the part where the program found it. Returns what moved."""
        result = self.commands.invoke(self.client, "align", measured=measured, nominal=nominal, points=points,
                                      name=name)
        t = np.asarray(result.pose, float)[:3, 3]
        return (f"{name} moved the station's part: origin at X {t[0]:.4f} Y {t[1]:.4f} Z {t[2]:.4f} "
                f"(the datums' hits within {result.residuals['datum hits off the part (max)']:.4f} mm of it)")

    def fit(self, kind: str, hit_ids: list[int], name: str, nominal: Any) -> Any:
        """The feature a MEAS block ends with: the measurement model fits it (the command API's verb)."""
        return self.commands.invoke(self.client, "measure_feature", kind=kind, hits=hit_ids, method="ls", name=name,
                                    nominal=nominal)

    def note(self, text: str) -> None:
        """A line in the session journal (the command API's ``note`` verb, as the program's client)."""
        self.commands.invoke(self.client, "note", text=text)

    def set_tolerance(self, feature_id: int, tolerance: dict[str, float]) -> None:
        """A DMIS tolerance the station's report carries too (the feature's tolerance in the model)."""
        self.commands.invoke(self.client, "set_nominal", feature=feature_id, tolerance=tolerance)

    def set_nominal(self, feature_id: int, nominal: Any) -> None:
        """The program's nominal of a feature it measured, moved with the part by its alignment (the station's
        feature takes it, so its report compares with the same nominal)."""
        self.commands.invoke(self.client, "set_nominal", feature=feature_id, nominal=nominal)

    def define_datum(self, label: str, feature_id: int) -> None:
        """A DATDEF the station's GD&T takes too: its datum on the same feature, at RFS (the define_datum verb)."""
        self.commands.invoke(self.client, "define_datum", label=label, feature=feature_id)

    def define_position(self, feature_id: int, tolerance: float, datums: list[str], *, material: str, name: str,
                        datum_modifiers: dict[str, str] | None) -> None:
        """A TOL/POS the station's GD&T takes too (the define_gdt verb): the same value and bonus in its report."""
        self.commands.invoke(self.client, "define_gdt", characteristic="position", feature=feature_id,
                             tolerance=tolerance, datums=datums, material=material, name=name,
                             datum_modifiers=datum_modifiers)

    def run_end(self, series: str, *, values: Any = None, event: Any = None, stopped: Any = None) -> None:
        """The run's end: its trend values and its journal event, or why it stopped (the record_event verb)."""
        data = {"series": series, "stopped": stopped} if stopped is not None else \
            {"series": series, "values": values, "event": event}
        self.commands.invoke(self.client, "record_event", kind="program_stopped" if stopped is not None
                             else "program_end", data=data)

    def setup(self) -> dict[str, Any]:
        """What the station measures with (the probing_setup query)."""
        return self.commands.invoke(self.client, "probing_setup")

    def probes(self) -> list[dict[str, Any]] | None:
        """The station's probe list (name, tip_diameter, qualified, selected); None without a calibration folder,
        where its one probe measures whatever the program's sensor."""
        probes = self.setup()["probes"]
        return None if probes is None else [{**p, "qualified_diameters": tuple(p["qualified_diameters"])}
                                            for p in probes]

    def select_probe(self, name: str) -> str:
        """Make a probe of the list the one in use (the command API's select_probe verb, as the Calibration tab
        and the I++ server's ChangeTool do); "" when it already is."""
        if name == self.setup()["probe_name"]:
            return ""
        return str(self.commands.invoke(self.client, "select_probe", name=name))

    def saved_items(self) -> Any:
        """The station's record of what DMIS programs SAVE (cmm.dmis.saved): in its sessions folder; None without
        one (SAVE then holds within the run)."""
        from .saved import SavedItems

        folder = self.setup()["session_dir"]
        return SavedItems(Path(folder)) if folder is not None else None

    @property
    def tip_radius(self) -> float:
        return float(self.setup()["tip_radius"])

    @property
    def nominal_tip_diameter(self) -> float:
        """The configured probe's tip (mm): the one a station without a probe list measures with."""
        return float(self.setup()["nominal_tip_diameter"])

    @property
    def probing_speed(self) -> float:
        return float(self.setup()["probing_speed"])

    @property
    def positioning_speed(self) -> float:
        return float(self.setup()["positioning_speed"])

    @property
    def probe_distances(self) -> tuple[float, float, float]:
        p = self.setup()
        return float(p["approach_distance"]), float(p["search_distance"]), float(p["retract_distance"])


def load_text(path: str | Path) -> str:
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DmisError(f"cannot read the DMIS program {p}: {exc.strerror or exc}") from None


def needs_operator(stmts: list[Statement]) -> bool:
    """Whether the program measures or moves in manual mode (read in order: a MODE holds until the next)."""
    manual = False
    for s in stmts:
        if s.major == "MODE":
            manual = not any(isinstance(p, Word) and p.text == "AUTO" for p in s.params)
        elif manual and s.major in ("MEAS", "GOTO"):
            return True
    return False


def run_text(text: str, commands: Any, *, name: str = "program", client: Any = None,
             manual_hits: ManualHits | None = None, on_prompt: Callable[[str], None] | None = None,
             cancel: threading.Event | None = None, query: Query | None = None,
             progress: Callable[[float, str], None] | None = None) -> RunResult:
    """Check ``text`` and run it on the station whose command API is ``commands`` (connected, homed), as
    ``client``: the run's actuals, tolerances and output.
    ``manual_hits``, ``on_prompt``, ``cancel``: how the operator's hits are taken in manual mode (see above);
    ``query(prompt, answer)``: how TEXT/MAN and TEXT/QUERY ask the operator."""
    stmts, problems = check(text)
    if problems:
        raise DmisError(problems[0])
    target = StationTarget(commands, client, manual_hits=manual_hits, on_prompt=on_prompt, cancel=cancel, query=query)
    # a sensor that is no qualified probe of the list (no list: not the station's tip): refused before motion
    problems = sensor_problems(stmts, target.probes(), target.nominal_tip_diameter)
    if problems:
        raise DmisError(problems[0])
    store = target.saved_items()  # a RECALL of what an earlier program saved: refused before motion when none did
    for line, key in outside_recalls(stmts):
        try:
            found = None if store is None else store.recall(key)
        except OSError as exc:
            raise DmisError(f"line {line}: {exc}") from None
        if found is None:
            raise DmisError(f"line {line}: RECALL/{key}: nothing named {key} is defined or saved before it, nor "
                            "saved by an earlier program on this station")
    executor = Executor(stmts, target, name=name, text=text)
    executor.result.log.extend(f"warning: {w}" for w in warnings(text, stmts))
    description = f"DMIS program {name!r}"
    # a program in manual mode cannot hold the machine (the operator jogs between its statements): it runs beside
    # the machine loop, and the cancel verb ends its waits for the operator's hits
    manual = needs_operator(stmts)

    def work(job: Any) -> RunResult:
        if job is not None and progress is not None:  # the progress reaches ``progress`` on the dispatcher thread
            executor.on_progress = job.progress
        elif progress is not None:
            executor.on_progress = progress
        report = commands.invoke(client, "job_reporter")  # the job query: hits taken, the statement in progress
        executor.runner.report = lambda p: report(description, p.hits, p.total_hits, p.message)
        result = executor.run()
        # the program's last hit retracts a few mm only: the run ends at the clearance plane, so the next
        # program's first GOTO does not start beside the part (cmm.measurement.run_end)
        try:
            z = end_at_clearance(commands, client, target.timeout)
        except Exception as exc:  # noqa: BLE001 - the program's results stand; the failed climb is told
            result.log.append(f"the climb to the clearance plane at the end failed: {exc}")
            target.note(f"DMIS program {name!r}: the climb to the clearance plane at its end failed: {exc}")
            return result
        if z is not None:
            target.note(f"DMIS program {name!r} ended at the clearance plane, machine Z {z:.3f}")
        return result

    controls = executor.runner.controls()  # the part programs' one runner: pause, resume, skip, cancel

    def cancel_run() -> None:  # the cancel verb: the run ends before its next statement (or its wait for hits)
        controls["cancel"]()
        target.cancel.set()

    return commands.invoke(client, "run_job", description=description, work=work,
                                              hold_machine=not manual, cancel=cancel_run, pause=controls["pause"],
                                              resume=controls["resume"], skip=controls["skip"],
                                              **({"progress": progress} if progress is not None and not manual else {}))


def register_verbs(commands: Any) -> None:
    """The ``run_dmis`` verb on the station's command API (once): front ends that run DMIS programs send it."""
    if any(v.name == "run_dmis" for v in commands.verbs()):
        return

    def run_dmis(client: Any, text: str | None = None, path: Any = None, name: str | None = None,
                 manual_hits: ManualHits | None = None, on_prompt: Callable[[str], None] | None = None,
                 query: Query | None = None, progress: Callable[[float, str], None] | None = None) -> RunResult:
        refusal = commands.invoke(client, "access", command="measure")
        if refusal:
            raise Refused(refusal)
        if (text is None) == (path is None):
            raise DmisError("run_dmis needs the program's text or the path of its file (one of them)")
        if text is None:
            text, name = load_text(path), name or Path(path).name
        return run_text(str(text), commands, name=name or "program", client=client, manual_hits=manual_hits,
                        on_prompt=on_prompt, query=query, progress=progress)

    commands.register("run_dmis", run_dmis, {"text": None, "path": None, "name": None, "manual_hits": None,
                                             "on_prompt": None, "query": None,
                                             "progress": None},
                      "run a DMIS program (its text, or the path of its file) after checking all of it; the control "
                      "holder only; the machine is the program's until it ends (in manual mode the operator jogs and "
                      "probes the hits it asks for: on_prompt(text), in process, tells them); cancel ends it "
                      "after the hit in progress; pause holds it between statements, resume goes on, skip_step ends "
                      "the feature measurement in progress after its current hit (or leaves out the next one); "
                      "returns its actuals, tolerances and output")
