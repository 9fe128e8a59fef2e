"""Routine > run: *Run on next part*, the path preview, the progress, Pause / Resume / Skip step / Cancel, and the
recovery of a run stopped on a fault.

*Run on next part* runs the routine as a job: a manual 3-2-1 first when the routine says so (the prompt tells which
face and how many hits; the operator takes them with the jog and the armed probe), then everything automatically,
with a progress bar, Pause / Resume / Skip step / Cancel, and the part's results in a session of their own. A step
stopped by a fault (unexpected contact, link fault, E-STOP) stops the run with the reason shown; after Reset,
*Resume from step N* retracts to the clearance height and measures that step again (its partial hits discarded,
kept in the journal) and the rest, in the same part session; *Restart* runs it from step 1 again; *Cancel* ends it.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from ..measurement.align_wizard import routine_manual_hits
from ..measurement.routine_path import RoutinePath
from ..measurement.routine_run import RoutineRun
from .context import PanelContext
from .path_preview import PathPreview


class RunSlot:
    """The Routine tab's one run at a time: the thread of its routine run or its DMIS program."""

    def __init__(self) -> None:
        self.thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()


class RoutineRunPanel:
    """The runs of the tab's routine on the next parts; Pause / Resume / Skip step / Cancel reach a DMIS program
    too."""

    def __init__(self, ctx: PanelContext, gui: dict[str, Any], slot: RunSlot, editor: Any, dmis: Any) -> None:
        self.ctx = ctx
        self.gui = gui  # the Routine tab's widgets
        self.slot = slot
        self.editor = editor  # the routine to run (a RoutineEditPanel)
        self.dmis = dmis  # the DMIS program's panel (a DmisPanel): the run's buttons reach its run too
        self.align: Any = None  # the Align tab: its wizard prompts a routine's manual alignment
        self.run_: RoutineRun | None = None
        self.parts = 0  # parts run from this tab (names their sessions)
        self.preview = PathPreview(ctx, "/routine_preview")  # the path Run will take, drawn until Run or Clear

    @property
    def running(self) -> bool:
        return self.slot.running

    def edit_refusal(self) -> str | None:
        """Why the routine cannot be edited now (None: it can)."""
        if self.running:
            return "the routine is running: edit it when it has finished"
        if self.run_ is not None and self.run_.can_resume:
            return (f"the run stopped at step {(self.run_.faulted or 0) + 1} waits: resume, restart or cancel it "
                    "before editing the routine")
        return None

    def preview_path(self) -> list[Any] | None:
        """Draw the path the routine will take on this part, as it stands now: the alignment's datums and every
        feature (the hand hits of a manual alignment named where they come), or, while a run stopped on a fault
        waits, its resume (the back-off and the retract, then the stopped step again and the rest). The run's
        alignment moves the hits after it by what it finds."""
        r, part = self.editor.routine, self.ctx.model().part
        if r is None or part is None:
            self.ctx.error("teach or open a routine (and load its part) first", "Routine preview")
            return None
        run = self.run_ if self.run_ is not None and self.run_.can_resume and not self.running else None
        found: list[RoutinePath] = []

        def paths() -> list[Any]:
            found.append(self.ctx.commands.invoke(self.ctx.who(), "routine_path", routine=r, run=run))
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

    def start(self, part_name: str = "") -> bool:
        r = self.editor.routine
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
        self.run_ = self.ctx.commands.invoke(self.ctx.who(), "new_routine_run", routine=r, part_name=name,
                                             on_progress=lambda _p: self._show_progress())
        self._go("run", name)
        return True

    def _go(self, action: str, name: str) -> None:
        """Run the run (``action`` 'run'), its resume or its restart through the command API, in a thread; every
        stop is told."""
        run = self.run_
        cycle = self.ctx.begin_cycle(f"routine {run.routine.name}" + (f" on {name}" if name else ""))
        align = self.align  # the Align tab's wizard prompts the manual alignment's hits
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

        self.slot.thread = threading.Thread(target=work, name="routine", daemon=True)
        self.slot.thread.start()
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
        mode = self._mode()
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
        if (run is None or not self.running) and not self.dmis.dmis_running:
            self.ctx.error("no routine is running", "Routine")
            return
        if self.dmis.dmis_running and action == "cancel":
            self.dmis._dmis_cancel = True  # a question the program waits on ends too
        if self.dmis.dmis_running and action in ("pause", "resume", "skip") and getattr(self.ctx.shared, "cycle", None):
            self.ctx.shared.cycle_paused = action == "pause"  # the status bar: PAUSED, not RUNNING
        verb, title = {"pause": ("pause", "Pause"), "resume": ("resume", "Resume"), "skip": ("skip_step", "Skip step"),
                       "cancel": ("cancel", "Cancel")}[action]
        answer = self.ctx.do(title, verb)  # the core decides who may; its refusal is shown in words
        if answer is not None and not next(iter(answer.values())):
            self.ctx.error(answer["message"], title)
        self._show_progress()

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
        mode = self._mode()
        first = (f"Clear the cause, press {b}Reset{b}, then " if mode in ("fault", "e-stopped", "stopped")
                 else "Then ")
        return f"{first}{b}Resume from step {n}{b}, {b}Restart{b} from step 1, or {b}Cancel{b}."

    def _mode(self) -> str:
        """The machine's mode now (the state query): idle, moving, stopped, fault, e-stopped ..."""
        return str(getattr(self.ctx.commands.invoke(self.ctx.who(), "state").mode, "value", ""))

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
        """The part name, the path preview, Run on next part, the progress and the run's buttons."""
        g = self.gui
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

    def refresh(self) -> None:
        if self.run_ is not None:
            self._show_progress()
