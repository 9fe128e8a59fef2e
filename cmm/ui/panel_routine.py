"""The "Routine" tab: the taught measurement routine as an ordered list, edited and run on the next part.

The tab is three panels, one job each: the routine and its edits (:mod:`.panel_routine_edit`), its runs on the
next parts (:mod:`.panel_routine_run`) and the DMIS programs (:mod:`.panel_dmis`); :class:`RoutinePanel` lays
them out and keeps their actions reachable on the tab (what the tests call).

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

from typing import Any

from .context import PanelContext
from .panel_dmis import DmisPanel
from .panel_routine_edit import RoutineEditPanel, parse_nominal
from .panel_routine_run import RoutineRunPanel, RunSlot

__all__ = ["RoutinePanel", "parse_nominal"]


def _on(panel: str, name: str, *, settable: bool = False) -> property:
    """An action or a state of one of the tab's panels, reached on the tab (``panel.edit`` is the editor's)."""
    def get(self: Any) -> Any:
        return getattr(getattr(self, panel), name)

    def put(self: Any, value: Any) -> None:
        setattr(getattr(self, panel), name, value)
    return property(get, put if settable else None, doc=f"The {panel} panel's ``{name}``.")


class RoutinePanel:
    """The Routine tab: the editor, the runs and the DMIS program share its widgets and its one run at a time."""

    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.slot = RunSlot()
        self.editor = RoutineEditPanel(ctx, self.gui, busy=lambda: self.runs.edit_refusal())
        self.dmis_panel = DmisPanel(ctx, self.gui, self.slot, self.editor._path)
        self.runs = RoutineRunPanel(ctx, self.gui, self.slot, self.editor, self.dmis_panel)

    # the routine and its edits
    routine = _on("editor", "routine", settable=True)
    teach = _on("editor", "teach")
    open = _on("editor", "open")
    save = _on("editor", "save")
    export_dmis = _on("editor", "export_dmis")
    _path = _on("editor", "_path")
    edit = _on("editor", "edit")
    insert_text = _on("editor", "insert_text")
    select = _on("editor", "select")
    selected = _on("editor", "selected")
    text = _on("editor", "text")
    fill_fields = _on("editor", "fill_fields")
    _show = _on("editor", "_show")
    # the runs
    align = _on("runs", "align", settable=True)
    run_ = _on("runs", "run_", settable=True)
    parts = _on("runs", "parts", settable=True)
    preview = _on("runs", "preview")
    preview_path = _on("runs", "preview_path")
    clear_preview = _on("runs", "clear_preview")
    start = _on("runs", "start")
    recover = _on("runs", "recover")
    control = _on("runs", "control")
    progress_text = _on("runs", "progress_text")
    _recovery = _on("runs", "_recovery")
    _show_progress = _on("runs", "_show_progress")
    thread = _on("slot", "thread", settable=True)
    running = _on("slot", "running")
    # the DMIS program
    dmis = _on("dmis_panel", "dmis", settable=True)
    dmis_text = _on("dmis_panel", "dmis_text", settable=True)
    dmis_status = _on("dmis_panel", "dmis_status", settable=True)
    dmis_results = _on("dmis_panel", "dmis_results", settable=True)
    dmis_running = _on("dmis_panel", "dmis_running", settable=True)
    dmis_question = _on("dmis_panel", "dmis_question", settable=True)
    dmis_answer = _on("dmis_panel", "dmis_answer", settable=True)
    open_dmis = _on("dmis_panel", "open_dmis")
    upload_dmis = _on("dmis_panel", "upload_dmis")
    run_dmis = _on("dmis_panel", "run_dmis")
    answer_dmis = _on("dmis_panel", "answer_dmis")
    _dmis_progress = _on("dmis_panel", "_dmis_progress", settable=True)

    def build(self, gui: Any) -> None:
        """The tab top to bottom: the routine and its edits, the run, the DMIS program."""
        self.editor.build(gui)
        self.runs.build(gui)
        self.dmis_panel.build(gui)

    def refresh(self) -> None:
        self.runs.refresh()
