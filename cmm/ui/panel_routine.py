"""The "Routine" tab: the taught measurement routine as an ordered list, edited and run on the next part.

*Teach from this session* turns what the operator did (the 3-2-1 alignment, every measured feature, the
constructions) into a routine (:mod:`cmm.measurement.routine`); each step is a line the operator can select,
rename, move up or down, skip, delete, and for feature steps give a tolerance or a clearance height; a
construction or report step can be inserted. *Save* / *Open* use the program file format; *Export DMIS* writes
the routine as a DMIS program beside it (and offers it as a download). *Run on next part*
runs it as a job: a manual 3-2-1 first when the routine says so (the prompt tells which face and how many
hits; the operator takes them with the jog and the armed probe), then everything automatically, with a
progress bar, Pause / Resume / Skip step / Cancel, and the part's results in a session of their own. A step
stopped by a fault (unexpected contact, link fault, E-STOP) stops the run with the reason shown; after Reset,
*Resume from step N* retracts to the clearance height and measures that step again (its partial hits
discarded, kept in the journal) and the rest, in the same part session; *Restart* runs it from step 1 again;
*Cancel* ends it. Each step may name its probe (the stylus is changed to before the step); the nominal, the
hit plan (which hits, in which order) and single hits can be edited too.

*DMIS program*: open a ``.dmi`` / ``.dms`` file (:mod:`cmm.dmis`): the whole program is checked first (a
statement the station does not support stops it with its line number, before anything moves), its
statements are listed as steps, and *Run DMIS* runs it as one job in a session of its own (each run a part:
``PROGRAM n``, n the first number no session has, the previous part's features put away); the DMIS output
(``FA`` actuals, ``TA`` tolerances with INTOL / OUTOL) is written beside the sessions.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any

from ..measurement.align_wizard import routine_manual_hits
from ..measurement.routine import CONSTRUCTIONS, Routine, RoutineError, teach_routine
from ..measurement.routine_path import RoutinePath, routine_path
from ..measurement.routine_run import RoutineRun
from ..program.toml_program import ProgramError, load, part_hash
from ..journal.store import open_session
from .context import OPERATOR_ERRORS, PanelContext
from .path_preview import PathPreview


def parse_nominal(text: str) -> dict[str, Any]:
    """'radius=15.01 point=30 40 0' -> {'radius': 15.01, 'point': [30.0, 40.0, 0.0]}."""
    out: dict[str, Any] = {}
    key = None
    for word in text.replace(",", " ").replace(";", " ").replace("=", "= ").split():
        if word.endswith("="):
            key = word[:-1].strip()
            if not key:
                raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
            out[key] = []
            continue
        if key is None:
            raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
        try:
            out[key].append(float(word))
        except ValueError:
            raise RoutineError(f"{key}: {word!r} is not a number") from None
    if not out or any(not v for v in out.values()):
        raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
    return {k: v[0] if len(v) == 1 else v for k, v in out.items()}


class RoutinePanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.station = ctx.station
        self.gui: dict[str, Any] = {}
        self.routine: Routine | None = None
        self.run_: RoutineRun | None = None
        self.thread: threading.Thread | None = None
        self.parts = 0  # parts run from this tab (names their sessions)
        self.dmis: tuple[Path, str] | None = None  # the DMIS program opened and checked: (path, text)
        self.dmis_text = ""
        self.dmis_status = ""
        self.dmis_results: list[Any] = []
        self.dmis_running = False  # a DMIS program runs: the routine's Pause / Resume / Cancel reach it
        self.dmis_question = ""  # what the running program asks the operator (TEXT/MAN, TEXT/QUERY)
        self.dmis_answer = ""
        self._dmis_answered = threading.Event()
        self._dmis_cancel = False
        from ..dmis.runner import register_verbs

        register_verbs(self.station)  # this tab runs DMIS programs with the run_dmis verb (registered once)
        self.preview = PathPreview(ctx, "/routine_preview")  # the path Run will take, drawn until Run or Clear

    # --- actions (also what the tests call) ------------------------------------------------

    def teach(self, name: str = "") -> Routine | None:
        model = self.station.measurement
        if model.journal is None or not hasattr(model.journal, "path"):
            self.ctx.error("this session has no journal file to teach from", "Routine")
            return None
        try:
            session = open_session(model.journal.path)
            part = model.part
            self.routine = teach_routine(session, name=name.strip() or None,
                                         part_mesh=None if part is None else part.mesh,
                                         part_nominals=None if part is None else part.nominal_features)
        except (ProgramError, ValueError, OSError) as exc:
            self.ctx.error(exc, "Teach")
            return None
        self.ctx.notify("Routine taught", f"{len(self.routine.steps)} steps from this session")
        self._show()
        return self.routine

    def open(self, path: str) -> Routine | None:
        try:
            self.routine = Routine(load(self._path(path)))
        except (ProgramError, OSError) as exc:
            self.ctx.error(exc, "Open routine")
            return None
        self._show()
        return self.routine

    def save(self, path: str) -> Path | None:
        if self.routine is None:
            self.ctx.error("teach or open a routine first", "Save routine")
            return None
        try:
            saved = self.routine.save(self._path(path))
        except OSError as exc:
            self.ctx.error(f"cannot write {path}: {exc.strerror or exc}", "Save routine")
            return None
        try:
            self.ctx.commands.invoke(self.ctx.who(), "record_event", kind="routine_saved",
                                     data={"name": self.routine.name, "path": str(saved), "text": self.routine.text()})
        except OPERATOR_ERRORS as exc:  # the file is written; the journal refused to say so (this tab observes)
            self.ctx.notify("Routine saved", f"{saved} (not in the session journal: {exc})", "error")
            return saved
        self.ctx.notify("Routine saved", str(saved))
        return saved

    def export_dmis(self, path: str) -> Path | None:
        """Write the routine as a DMIS program, ``<routine name>.dmi`` beside its routine file (``path``, as Save
        takes it), for the part where the station has it now (a feature's later hits hop over its mesh as the
        routine runner's); offered to the browser as a download."""
        from ..dmis.export import to_dmis

        if self.routine is None:
            self.ctx.error("teach or open a routine first", "Export DMIS")
            return None
        part = self.station.measurement.part
        pose = part.pose if part is not None else [[1, 0, 0, 190.0], [0, 1, 0, 150.0], [0, 0, 1, 0], [0, 0, 0, 1]]
        probe = self.station.config.probe
        # the part the routine was taught on: its later hits of a feature hop over its mesh as the runner's
        mesh = part.mesh if part is not None and part_hash(part) == self.routine.program.part_sha256 else None
        stem = re.sub(r"[^\w.-]+", "_", self.routine.name).strip("._") or "routine"
        out = self._path(path).parent / f"{stem}.dmi"
        try:
            text = to_dmis(self.routine.program, pose, tip_radius=probe.tip_radius,
                           approach=probe.approach_distance, search=probe.search_distance,
                           retract=probe.retract_distance, mesh=mesh)
            out.write_text(text, encoding="utf-8")
        except OSError as exc:
            self.ctx.error(f"cannot write {out}: {exc.strerror or exc}", "Export DMIS")
            return None
        except (ProgramError, ValueError, KeyError) as exc:
            self.ctx.error(f"the routine cannot be written as DMIS: {exc}", "Export DMIS")
            return None
        send = getattr(self.ctx.client, "send_file_download", None)
        if send is not None:
            try:
                send(out.name, out.read_bytes())
            except Exception:  # noqa: BLE001 - the tab may have closed; the file is on disk anyway
                pass
        self.ctx.notify("DMIS program exported", f"{out} ({len(self.routine.steps)} steps; run it with cmm run "
                        "or Open DMIS here)")
        return out

    def _path(self, text: str) -> Path:
        p = Path(text.strip() or f"{self.routine.name if self.routine else 'routine'}.toml").expanduser()
        base = self.station.measurement.session_dir
        return p if p.is_absolute() or not isinstance(base, Path) else base / p

    def edit(self, action: str, *args: Any) -> bool:
        """An edit of the selected step: rename, up, down, delete, skip, tolerance, clearance, nominal, hits, hit,
        probe, insert."""
        r = self.routine
        if r is None:
            self.ctx.error("teach or open a routine first", "Routine")
            return False
        if self.running:
            self.ctx.error("the routine is running: edit it when it has finished", "Routine")
            return False
        if self.run_ is not None and self.run_.can_resume:
            self.ctx.error(f"the run stopped at step {(self.run_.faulted or 0) + 1} waits: resume, restart or cancel "
                           "it before editing the routine", "Routine")
            return False
        i = self.selected()
        try:
            if action == "rename":
                r.rename(i, args[0])
            elif action in ("up", "down"):
                i = r.move(i, -1 if action == "up" else 1)
            elif action == "delete":
                r.delete(i)
                i = min(i, len(r.steps) - 1)
            elif action == "skip":
                r.set_skip(i, not r.steps[i].get("skip"))
            elif action == "manual":
                if r.steps[i]["kind"] != "align":
                    raise RoutineError(f"{r.steps[i]['name']} is not an alignment: choose the align step")
                r.set_manual(i, not r.steps[i].get("manual"))
            elif action == "probe":
                if r.steps[i]["kind"] not in ("feature", "align"):
                    raise RoutineError(f"{r.steps[i]['name']} does not measure: choose a feature or alignment step")
                r.set_probe(i, str(args[0]))
            elif action in ("tolerance", "clearance", "nominal", "hits", "hit"):
                step = r.steps[i]
                if step["kind"] != "feature":
                    raise RoutineError(f"{step['name']} is not a feature: choose a feature step")
                if action == "tolerance":
                    words = str(args[0]).replace(",", " ").split()
                    if len(words) != 3:
                        raise RoutineError("write three tolerances in mm: size form location (e.g. 0.02 0.01 0.05)")
                    size, form, location = (float(x) for x in words)
                    r.set_tolerance(step["name"], size=size, form=form, location=location)
                elif action == "clearance":
                    r.set_clearance(step["name"], float(args[0]))
                elif action == "nominal":
                    r.set_nominal(step["name"], **parse_nominal(str(args[0])))
                elif action == "hits":
                    r.set_hits(step["name"], [int(x) for x in str(args[0]).replace(",", " ").split()])
                else:
                    words = str(args[0]).replace(",", " ").split()
                    if len(words) not in (4, 7):
                        raise RoutineError("write the hit's id and its point X Y Z, optionally its approach I J K")
                    hid = int(words[0])
                    if hid not in r.feature(step["name"]).hits:
                        raise RoutineError(f"hit {hid} is not one of {step['name']}'s hits "
                                           f"({', '.join(map(str, r.feature(step['name']).hits))})")
                    nums = [float(x) for x in words[1:]]
                    r.set_hit(hid, nums[:3], nums[3:] or None)
            elif action == "insert":
                r.insert(i + 1, args[0])
                i += 1
        except (RoutineError, ValueError, IndexError) as exc:
            self.ctx.error(exc, "Routine")
            return False
        self._selected = i
        self._show(select=i)
        return True

    def insert_text(self, text: str) -> bool:
        """'report NAME', 'feature NAME' (a feature of the routine), 'align PRIMARY SECONDARY TERTIARY [manual]'
        or 'OPERATION A B [NAME]' (distance, angle, intersection, midpoint)."""
        words = text.split()
        if len(words) >= 1 and words[0] == "report":
            return self.edit("insert", {"kind": "report", "name": " ".join(words[1:]) or "report"})
        if len(words) == 2 and words[0] == "feature":
            return self.edit("insert", {"kind": "feature", "name": words[1]})
        if len(words) in (4, 5) and words[0] == "align" and (len(words) == 4 or words[4] == "manual"):
            taken = {s["name"] for s in self.routine.steps} if self.routine is not None else set()
            name = next(n for n in ("alignment", *(f"alignment {k}" for k in range(2, 99))) if n not in taken)
            return self.edit("insert", {"kind": "align", "name": name, "datums": words[1:4],
                                        "manual": len(words) == 5 or None})
        if len(words) in (3, 4) and words[0] in CONSTRUCTIONS:
            name = words[3] if len(words) == 4 else f"{words[1]}-{words[2]}"
            return self.edit("insert", {"kind": "construct", "name": name, "operation": words[0],
                                        "of": [words[1], words[2]]})
        self.ctx.error("write 'report NAME', 'feature NAME', 'align A B C [manual]' or 'distance A B [NAME]' "
                       "(distance, angle, intersection, midpoint)", "Insert step")
        return False

    # --- DMIS programs ----------------------------------------------------------------------

    def open_dmis(self, path: str) -> list[str] | None:
        """Check a DMIS program and list its statements (None and the problems told when it cannot run)."""
        from ..dmis.check import check
        from ..dmis.executor import DmisError
        from ..dmis.runner import load_text

        p = self._path(path)
        try:
            text = load_text(p)
        except DmisError as exc:
            self.ctx.error(exc, "Open DMIS")
            return None
        return self._take_dmis(p, text)

    def upload_dmis(self, name: str, content: bytes) -> list[str] | None:
        """A DMIS program uploaded from the operator's computer (the Upload DMIS button): checked as one opened."""
        from ..dmis.rules import device_file

        if not content:
            self.ctx.error("the uploaded DMIS file is empty", "Upload DMIS")
            return None
        if Path(str(name)).suffix.lower() not in (".dmi", ".dms"):
            self.ctx.error(f"{name} is not a DMIS program (.dmi or .dms)", "Upload DMIS")
            return None
        return self._take_dmis(Path(device_file(str(name)) or "upload.dms"),
                               bytes(content).decode("utf-8", errors="replace"))

    def _take_dmis(self, p: Path, text: str) -> list[str] | None:
        from ..dmis.check import check, warnings

        stmts, problems = check(text)
        self.dmis = (p, text)
        if problems:
            self.dmis = None
            self.dmis_text = f"**{p.name}** cannot run:\n\n" + "\n".join(f"- {x}" for x in problems[:20])
            self.ctx.error(problems[0], "DMIS program refused")
        else:
            lines = [f"line {st.line}: {(st.text or st.major).strip()[:70]}" for st in stmts]
            told = "".join(f"\n\nwarning: {w}" for w in warnings(text, stmts))
            self.dmis_text = f"**{p.name}** · {len(stmts)} statements, all supported{told}\n\n" + "\n".join(
                f"- {x}" for x in lines[:60]) + ("\n- ..." if len(lines) > 60 else "")
        self.ctx.set("routine:dmis", "content", self.dmis_text, self.gui.get("dmis"))
        return None if self.dmis is None else lines

    def run_dmis(self, wait: bool = False) -> bool:
        if self.dmis is None:
            self.ctx.error("open a DMIS program that passes the check first", "Run DMIS")
            return False
        if self.running:
            self.ctx.error("a routine or program is already running", "Run DMIS")
            return False
        path, text = self.dmis  # the new_part and run_dmis verbs decide who may; a refusal is shown in words

        def work() -> None:
            model = self.station.measurement
            # each run is a part of the program's series: a session of its own (a name no earlier run took, also
            # of another page or before a restart) with none of the previous part's features or tolerances
            try:
                session = self.ctx.commands.invoke(self.ctx.who(), "new_part", name=self._part_session(path.stem))
            except Exception as exc:  # noqa: BLE001 - a store that cannot take the session, in words
                self.dmis_status = f"**NOT STARTED**: {exc}"
                self.ctx.end_cycle(cycle, exc)
                self.ctx.error(exc, "DMIS program not started")
                self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))
                return
            failure = None
            try:
                self.dmis_running, self._dmis_cancel = True, False
                # manual mode: hits taken by jog; TEXT/MAN and QUERY answered here; the routine's bar and stops
                result = self.ctx.commands.invoke(self.ctx.who(), "run_dmis", text=text, name=path.name,
                                                  on_prompt=self._dmis_prompt, query=self._dmis_query,
                                                  progress=self._dmis_progress)
            except Exception as exc:  # noqa: BLE001 - every stop is told; the hits taken stay in the session
                failure = exc
                self.dmis_status = f"**STOPPED**: {exc}"
                self.ctx.error(exc, "DMIS program stopped")
            else:
                out_dir = model.session_dir if isinstance(model.session_dir, Path) else Path(".")
                written = []
                for device, content in result.outputs.items():
                    target = out_dir / (device or f"{Path(str(session)).stem}_out.dms")
                    target.write_text(content, encoding="utf-8")
                    written.append(target.name)
                bad = [e for e in result.evaluations if not e.intol]
                self.dmis_status = (f"**DONE**: {len(result.actuals)} features, {result.hits} hits, "
                                    f"{len(result.evaluations)} tolerances, {len(bad)} out of tolerance; "
                                    f"output {', '.join(written) or '-'}")
                self.dmis_results.append(result)
                self.ctx.notify("DMIS program done", self.dmis_status.replace("**", ""))
            finally:
                self.dmis_running = False
                self.ctx.end_cycle(cycle, failure)  # a stop: the status bar says STOPPED with the reason
                bar = self.gui.get("bar")
                if bar is not None:
                    self.ctx.set("routine:bar", "visible", False, bar)
            self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))

        self.dmis_status = f"**RUNNING** {path.name}"
        cycle = self.ctx.begin_cycle(f"DMIS program {path.name}")
        self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))
        self.thread = threading.Thread(target=work, name="dmis", daemon=True)
        self.thread.start()
        if wait:
            self.thread.join()
        return True

    def _part_session(self, stem: str) -> str:
        """``PROGRAM n``: the first n from this page's run count on that names no session in the store yet."""
        from ..journal.store import open_store

        store = open_store(self.station.measurement.session_dir)
        n = len(self.dmis_results) + 1
        while store.exists(f"{stem} {n}"):
            n += 1
        return f"{stem} {n}"

    def _dmis_progress(self, fraction: float, message: str) -> None:
        """The run goes on: the routine's progress bar and the program's status line."""
        bar = self.gui.get("bar")
        if bar is not None:
            self.ctx.set("routine:bar", "visible", True, bar)
            self.ctx.set("routine:bar:value", "value", round(100.0 * fraction, 1), bar)
        if self.dmis is not None and not self.dmis_question:
            head = "PAUSED" if message.startswith("paused") else "RUNNING"
            self.dmis_status = f"**{head}** {self.dmis[0].name} · {message}"
            self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))

    def _dmis_query(self, prompt: str, answer: bool) -> str:
        """TEXT/MAN (confirm) or TEXT/QUERY (answer): asked on this tab; the run waits (the machine standing still)
        until the operator presses Answer, or Cancel."""
        self.dmis_question = prompt
        self._dmis_answered.clear()
        self.dmis_status = (f"**QUESTION**: {prompt}" + (" (type the answer in Answer, then press Answer)" if answer
                                                          else " (press Answer to go on)"))
        self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))
        self.ctx.notify("DMIS program asks", prompt)
        try:
            while not self.station.controller.wait_event(self._dmis_answered, 0.2):
                if not self.dmis_running or self._dmis_cancel:
                    break
            if not self._dmis_answered.is_set():
                from ..dmis.executor import DmisError

                raise DmisError(f"{prompt.split(':')[0]}: the question was not answered")
            return self.dmis_answer
        finally:
            self.dmis_question = ""

    def answer_dmis(self, text: str = "") -> bool:
        """The operator's answer to the program's question (False: none is asked)."""
        if not self.dmis_question:
            self.ctx.error("the DMIS program asks nothing now", "Answer")
            return False
        self.dmis_answer = str(text)
        self._dmis_answered.set()
        return True

    def _dmis_prompt(self, text: str) -> None:
        """A DMIS program in manual mode asks the operator for hits (text) or has them (empty)."""
        self.dmis_status = f"**WAITING**: {text}" if text else f"**RUNNING** {self.dmis[0].name if self.dmis else ''}"
        self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))

    def preview_path(self) -> list[Any] | None:
        """Draw the path the routine will take on this part, as it stands now: the alignment's datums and every
        feature (the hand hits of a manual alignment named where they come), or, while a run stopped on a fault
        waits, its resume (the back-off and the retract, then the stopped step again and the rest). The run's
        alignment moves the hits after it by what it finds."""
        r, part = self.routine, self.station.measurement.part
        if r is None or part is None:
            self.ctx.error("teach or open a routine (and load its part) first", "Routine preview")
            return None
        run = self.run_ if self.run_ is not None and self.run_.can_resume and not self.running else None
        found: list[RoutinePath] = []

        def paths() -> list[Any]:
            found.append(routine_path(r, self.station.controller, part.pose, run, mesh=part.mesh))
            return found[0].cycles
        cycles = self.preview.show_cycles(paths, "Routine preview")
        words = found[0].text() if found and cycles is not None else ""
        head = f" Resume from step {(run.faulted or 0) + 1}: " if run is not None else " "
        text = (self.preview.text() + head + words).strip() if self.preview.cycles else ""
        self.ctx.set("routine:preview", "content", text, self.gui.get("preview"))
        return cycles

    def clear_preview(self) -> None:
        self.preview.clear()
        self.ctx.set("routine:preview", "content", "", self.gui.get("preview"))

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def start(self, part_name: str = "") -> bool:
        r = self.routine
        if r is None:
            self.ctx.error("teach or open a routine first", "Run routine")
            return False
        if self.running:
            self.ctx.error("the routine is already running", "Run routine")
            return False
        if not self.ctx.allowed("Run routine"):
            return False
        self.clear_preview()  # the machine draws the path now
        if self.run_ is not None and self.run_.can_resume:
            self.run_.cancel()  # a new part: the run stopped on a fault is given up (its hits stay recorded)
        self.parts += 1
        name = part_name.strip() or f"part {self.parts}"
        self.run_ = RoutineRun(r, self.station.measurement, part_name=name, on_progress=lambda _p: self._show_progress())
        self._go("run", name)
        return True

    def _go(self, action: str, name: str) -> None:
        """Run the run (``action`` 'run'), its resume or its restart through the command API, in a thread; every
        stop is told."""
        run = self.run_
        cycle = self.ctx.begin_cycle(f"routine {run.routine.name}" + (f" on {name}" if name else ""))
        align = getattr(self, "align", None)  # the Align tab's wizard prompts the manual alignment's hits
        manual = None if align is None else routine_manual_hits(
            run, lambda datums: align.routine_wizard(run.routine, datums))

        def work() -> None:
            failure = None
            try:
                self.ctx.commands.invoke(self.ctx.who(), "run_routine", run=run, action=action,
                                         manual_hits=manual)  # the API runs it
            except Exception as exc:  # noqa: BLE001 - every stop is told; the machine layer stopped itself
                failure = exc
                if run.can_resume:  # the step's stop, or a resume that could not start (the retract refused)
                    what = run.progress.message if str(exc) in run.progress.message else str(exc)
                    self.ctx.error(f"{what}. {self._recovery(run)}", "Routine stopped")
                else:
                    self.ctx.error(exc, "Routine stopped")
            else:
                self.ctx.notify("Routine done", f"{run.routine.name} on {name}: results in session {Path(str(run.progress.session)).stem}")
            finally:
                self.ctx.end_cycle(cycle, failure)  # a stop: the status bar says STOPPED with the reason
            self._show_progress()

        self.thread = threading.Thread(target=work, name="routine", daemon=True)
        self.thread.start()
        self._show_progress()

    def recover(self, action: str) -> bool:
        """After a step stopped on a fault: 'resume' (from that step) or 'restart' (from step 1)."""
        run = self.run_
        if run is None or not run.can_resume:
            self.ctx.error("no routine stopped on a fault: there is nothing to resume", "Routine")
            return False
        if self.running:
            self.ctx.error("the routine is still stopping: wait a moment", "Routine")
            return False
        mode = str(getattr(self.station.controller.state.mode, "value", ""))
        if mode in ("fault", "e-stopped"):
            self.ctx.error(f"the machine is {'in fault' if mode == 'fault' else 'emergency stopped'}: press Reset "
                           "first, then resume", "Routine")
            return False
        if not self.ctx.allowed("Resume routine"):
            return False
        self._go(action, run.part_name or "")
        return True

    def control(self, action: str) -> None:
        run = self.run_
        if action == "cancel" and run is not None and run.can_resume and not self.running:
            run.cancel()  # stopped on a fault: cancel ends it
            self._show_progress()
            return
        if (run is None or not self.running) and not self.dmis_running:
            self.ctx.error("no routine is running", "Routine")
            return
        if self.dmis_running and action == "cancel":
            self._dmis_cancel = True  # a question the program waits on ends too
        if self.dmis_running and action in ("pause", "resume", "skip") and getattr(self.ctx.shared, "cycle", None):
            self.ctx.shared.cycle_paused = action == "pause"  # the status bar: PAUSED, not RUNNING
        verb, title = {"pause": ("pause", "Pause"), "resume": ("resume", "Resume"), "skip": ("skip_step", "Skip step"),
                       "cancel": ("cancel", "Cancel")}[action]
        answer = self.ctx.do(title, verb)  # the core decides who may; its refusal is shown in words
        if answer is not None and not next(iter(answer.values())):
            self.ctx.error(answer["message"], title)
        self._show_progress()

    # --- what the tab shows --------------------------------------------------------------

    def select(self, index: int) -> None:
        """Choose step ``index`` (0-based), as the Step dropdown does."""
        self._selected = int(index)
        r = self.routine
        if "step" in self.gui and r is not None and r.steps:
            self.gui["step"].value = r.lines()[min(max(int(index), 0), len(r.steps) - 1)]

    def selected(self) -> int:
        if "step" not in self.gui:  # no page (scripts, tests): the last select()
            return max(0, getattr(self, "_selected", 0))
        value = self.gui["step"].value
        try:
            return max(0, int(str(value).split(".")[0]) - 1)
        except ValueError:
            return 0

    def text(self) -> str:
        r = self.routine
        if r is None:
            return "*No routine yet.* Measure the part (alignment, features, constructions), then **Teach from this session**, or open a routine file."
        rows = []
        for i, line in enumerate(r.lines()):
            rows.append(f"- {line}")
            got = r.settings(i)
            if got:  # what the edits set, seen without saving the file
                rows.append(f"  <br><small>± {got['tolerance']} mm (size form location) · clearance Z {got['clearance']}"
                            f" · {got['nominal'] or 'no nominal'} · hits {got['hits']}</small>")
        return f"**{r.name}** · {len(r.steps)} steps\n\n" + "\n".join(rows)

    def fill_fields(self) -> None:
        """The edit fields show the selected step's present values (tolerance, clearance, nominal, hit plan,
        probe), so an edit starts from what the step has."""
        r = self.routine
        if r is None or not r.steps:
            return
        i = min(self.selected(), len(r.steps) - 1)
        got = r.settings(i)
        g = self.gui
        for key in ("tolerance", "nominal", "hits"):
            if key in got and g.get(key) is not None:
                g[key].value = got[key]
        if "clearance" in got and g.get("clearance") is not None and got["clearance"] != "nan":
            g["clearance"].value = float(got["clearance"])
        if g.get("probe") is not None:
            g["probe"].value = r.steps[i].get("probe") or ""

    def progress_text(self) -> str:
        run = self.run_
        if run is None:
            return ""
        p = run.progress
        head = {"running": "RUNNING", "waiting": "WAITING FOR THE OPERATOR", "paused": "PAUSED", "done": "DONE",
                "failed": "STOPPED", "cancelled": "CANCELLED", "ready": "READY"}.get(p.state, p.state.upper())
        lines = [f"**{head}** · step {min(p.step + 1, p.steps)} of {p.steps} · {p.hits} of {p.total_hits} hits"]
        if p.prompt:
            lines.append(f"**{p.prompt}** (Jog tab, probe armed)")
        if p.message:
            lines.append(p.message)
        if run.can_resume and not self.running:
            n = (run.faulted or 0) + 1
            lines.append(self._recovery(run, bold=True) + f" (the machine retracts to the clearance height and measures "
                         f"step {n} again; its partial hits are discarded)")
        return "\n\n".join(lines)

    def _recovery(self, run: RoutineRun, bold: bool = False) -> str:
        """What the operator does after a stopped step: Reset first only when the machine needs it (a fault, an
        E-STOP, a STOP), never after a stop of the routine's own (a skipped datum)."""
        b = "**" if bold else ""
        n = (run.faulted or 0) + 1
        mode = str(getattr(self.station.controller.state.mode, "value", ""))
        first = (f"Clear the cause, press {b}Reset{b}, then " if mode in ("fault", "e-stopped", "stopped")
                 else "Then ")
        return f"{first}{b}Resume from step {n}{b}, {b}Restart{b} from step 1, or {b}Cancel{b}."

    def _show(self, select: int | None = None) -> None:
        self.ctx.set("routine:list", "content", self.text(), self.gui.get("list"))
        r = self.routine
        opts = tuple(r.lines()) if r is not None and r.steps else ("-",)
        step = self.gui.get("step")
        if step is not None:
            self.ctx.set("routine:step", "options", opts, step)
            if select is not None and r is not None and r.steps:
                step.value = opts[min(select, len(opts) - 1)]

    def _show_progress(self) -> None:
        run = self.run_
        self.ctx.set("routine:progress", "content", self.progress_text(), self.gui.get("progress"))
        stopped = run is not None and run.can_resume and not self.running
        for key in ("resume", "restart"):
            if self.gui.get(key) is not None:
                self.ctx.set(f"routine:{key}", "visible", stopped, self.gui[key])
        if stopped and self.gui.get("resume") is not None:
            self.ctx.set("routine:resume:label", "label", f"Resume from step {(run.faulted or 0) + 1}",
                         self.gui["resume"])
        shared = self.ctx.shared
        if run is not None and self.running and getattr(shared, "cycle", None):
            shared.cycle_paused = run.progress.state == "paused"  # the status bar: PAUSED, not RUNNING
        bar = self.gui.get("bar")
        if bar is not None and run is not None:
            p = run.progress
            self.ctx.set("routine:bar", "visible", p.state in ("running", "waiting", "paused"), bar)
            self.ctx.set("routine:bar:value", "value",
                         round(100.0 * p.hits / p.total_hits, 1) if p.total_hits else 0.0, bar)

    def build(self, gui: Any) -> None:
        g = self.gui
        g["list"] = gui.add_markdown(self.text())
        name = gui.add_text("Routine name", "", hint="default: the session's name")
        gui.add_button("Teach from this session").on_click(lambda _: self.teach(name.value))
        g["step"] = gui.add_dropdown("Step", ("-",), initial_value="-")
        g["step"].on_update(lambda _: self.fill_fields())
        with gui.add_folder("Edit step"):
            new_name = gui.add_text("New name", "")
            gui.add_button("Rename").on_click(lambda _: self.edit("rename", new_name.value))
            gui.add_button_group("Move / skip / delete", ("Up", "Down", "Skip", "Delete")).on_click(
                lambda e: self.edit(e.target.value.lower()))
            gui.add_button("Manual 3-2-1 hits on/off", hint="an align step: the operator's 6 hits first, or not"
                           ).on_click(lambda _: self.edit("manual"))
            tol = g["tolerance"] = gui.add_text("Tolerance ± mm (size form location)", "0.02 0.02 0.02")
            gui.add_button("Set tolerance").on_click(lambda _: self.edit("tolerance", tol.value))
            clear = g["clearance"] = gui.add_number("Clearance Z (part mm)", 60.0, step=1.0)
            gui.add_button("Set clearance").on_click(lambda _: self.edit("clearance", clear.value))
            nominal = g["nominal"] = gui.add_text("Nominal (part mm)", "", hint="e.g. radius=15.01  or  point=30 40 0")
            gui.add_button("Set nominal").on_click(lambda _: self.edit("nominal", nominal.value))
            hits = g["hits"] = gui.add_text("Hit plan (hit ids in order)", "",
                                            hint="e.g. 12 13 14 16: drop or reorder hits")
            gui.add_button("Set hit plan").on_click(lambda _: self.edit("hits", hits.value))
            hit = gui.add_text("Move hit (id X Y Z [I J K], part mm)", "", hint="e.g. 14 45 40 20")
            gui.add_button("Move hit").on_click(lambda _: self.edit("hit", hit.value))
            probe = g["probe"] = gui.add_text("Probe of the step", "", hint="a probe's name (Calibration tab); empty: any")
            gui.add_button("Set probe").on_click(lambda _: self.edit("probe", probe.value))
            new = gui.add_text("Insert after", "", hint="report NAME, feature NAME, align A B C [manual], "
                               "distance A B [NAME]")
            gui.add_button("Insert step").on_click(lambda _: self.insert_text(new.value))
        with gui.add_folder("File", expand_by_default=False):
            path = g["file"] = gui.add_text("Routine file", "", hint="name.toml (in the sessions folder) or a full path")
            gui.add_button_group("Routine file actions", ("Save", "Export DMIS", "Open")).on_click(
                lambda e: {"Save": self.save, "Export DMIS": self.export_dmis, "Open": self.open}[e.target.value](
                    path.value))
        part = g["part"] = gui.add_text("Part name", "", hint="e.g. the serial number; default: part 1, part 2, ...")
        gui.add_button_group("Routine path", ("Preview path", "Clear path")).on_click(
            lambda e: self.preview_path() if e.target.value == "Preview path" else self.clear_preview())
        g["preview"] = gui.add_markdown("")
        gui.add_button("Run on next part", color="green").on_click(lambda _: self.start(part.value))
        g["bar"] = gui.add_progress_bar(0.0, visible=False, animated=True)
        g["progress"] = gui.add_markdown("")
        gui.add_button_group("Routine run", ("Pause", "Resume", "Skip step", "Cancel")).on_click(
            lambda e: self.control({"Skip step": "skip"}.get(e.target.value, e.target.value.lower())))
        g["resume"] = gui.add_button("Resume from step 1", color="orange", visible=False,
                                     hint="after Reset: retract, measure the stopped step again, go on")
        g["resume"].on_click(lambda _: self.recover("resume"))
        g["restart"] = gui.add_button("Restart", visible=False, hint="after Reset: measure the part from step 1 again")
        g["restart"].on_click(lambda _: self.recover("restart"))
        with gui.add_folder("DMIS program", expand_by_default=False):
            dmis = gui.add_text("DMIS file", "", hint="PROGRAM.dmi (in the sessions folder) or a full path")
            gui.add_button("Open DMIS").on_click(lambda _: self.open_dmis(dmis.value))
            upload = gui.add_upload_button("Upload DMIS", hint="a .dmi / .dms file from this computer: checked, then "
                                           "Run DMIS")
            upload.on_upload(lambda _: self.upload_dmis(upload.value.name, upload.value.content))
            g["dmis"] = gui.add_markdown("")
            gui.add_button("Run DMIS", color="green").on_click(lambda _: self.run_dmis())
            g["dmis_status"] = gui.add_markdown("")
            reply = gui.add_text("Answer", "", hint="the answer to the program's question (TEXT/QUERY)")
            gui.add_button("Answer").on_click(lambda _: self.answer_dmis(reply.value))

    def refresh(self) -> None:
        if self.run_ is not None:
            self._show_progress()
