"""Routine > DMIS program: open or upload a ``.dmi`` / ``.dms`` file (:mod:`cmm.dmis`), check it, run it, answer
its questions.

The whole program is checked first (a statement the station does not support stops it with its line number, before
anything moves), its statements are listed, and *Run DMIS* runs it as one job in a session of its own (each run a
part: ``PROGRAM n``, n the first number no session has, the previous part's features put away); the DMIS output
(``FA`` actuals, ``TA`` tolerances with INTOL / OUTOL) is written beside the sessions. The routine's progress bar
and its Pause / Resume / Skip step / Cancel reach a running program too.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, Callable

from .context import PanelContext
from .panel_routine_run import RunSlot


class DmisPanel:
    """One tab's DMIS program: the one opened and checked, its run, its question and its results."""

    def __init__(self, ctx: PanelContext, gui: dict[str, Any], slot: RunSlot, path: Callable[[str], Path]) -> None:
        self.ctx = ctx
        self.gui = gui  # the Routine tab's widgets (the progress bar is the routine's)
        self.slot = slot  # one run at a time: a routine's or a program's
        self._path = path  # a file name as the Routine tab takes it (relative: in the sessions folder)
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

        register_verbs(ctx.commands)  # this tab runs DMIS programs with the run_dmis verb (registered once)

    @property
    def running(self) -> bool:
        return self.slot.running

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
                folder = self.ctx.commands.invoke(self.ctx.who(), "probing_setup")["session_dir"]
                out_dir = Path(folder) if folder is not None else Path(".")
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
        self.slot.thread = threading.Thread(target=work, name="dmis", daemon=True)
        self.slot.thread.start()
        if wait:
            self.slot.thread.join()
        return True

    def _part_session(self, stem: str) -> str:
        """``PROGRAM n``: the first n from this page's run count on that names no session in the store yet."""
        from ..journal.store import open_store

        store = open_store(self.ctx.commands.invoke(self.ctx.who(), "probing_setup")["sessions"])
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
        """TEXT/MAN (confirm) or TEXT/QUERY (answer): asked on this tab; the run waits (the machine standing still,
        the runner holding it) until the operator presses Answer, or Cancel."""
        self.dmis_question = prompt
        self._dmis_answered.clear()
        self.dmis_status = (f"**QUESTION**: {prompt}" + (" (type the answer in Answer, then press Answer)" if answer
                                                          else " (press Answer to go on)"))
        self.ctx.set("routine:dmis_status", "content", self.dmis_status, self.gui.get("dmis_status"))
        self.ctx.notify("DMIS program asks", prompt)
        try:
            while not self._dmis_answered.wait(0.2):
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

    def build(self, gui: Any) -> None:
        g = self.gui
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
