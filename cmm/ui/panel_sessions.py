"""The "Sessions" tab: list recorded sessions, replay one, rename/delete/new, export, report, re-evaluate.

:class:`SessionsPanel` belongs to one browser tab (``capp.sessions``; it
gets the tab's :class:`~cmm.ui.context.PanelContext`); every action is a plain method so tests drive exactly
what a button does. A replay moves nothing: the session's part, hits and
features are drawn into this browser's own scene
(:class:`~cmm.ui.scene.ReplayView`), the live scene stays as it is for
everyone else. Actions that change the record (rename, delete, new session,
re-evaluate) need control; looking, replaying and exporting do not. The tab reads the store's place, the
session list and the trends through the command API's queries and changes the record with its verbs
(``rename_session``, ``delete_session``, ``reevaluate_session``: :mod:`cmm.session.verbs`), so the core's access
policy decides; it opens the store itself only to read a session for replay.

Work that may take a while (opening a big session, exports with deviations,
reports, re-evaluation) runs in a :class:`Job` thread, never in viser's
callback thread, and shows its progress (a progress bar, and a notification
with a loading state): :class:`~cmm.ui.jobs.Job` and :class:`~cmm.ui.jobs.ProgressView`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from ..control import MotionError
from ..journal.bulk import dispose, gc_paused
from ..journal.store import StoreError, check_name, open_store
from ..session.verbs import REEVALUATE_METHODS, check_reevaluation
from ..session.worker import shared_worker

from .context import PanelContext
from .jobs import Job, ProgressView

METHODS = REEVALUATE_METHODS
LIST_EVERY = 10  # refresh() calls between re-listing the store (refresh runs at 5 Hz)


# --------------------------------------------------------------------------- words


def _when(t: Any) -> str:
    try:
        return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(t)))
    except (TypeError, ValueError):
        return "?"


def _xyz(p: Any) -> str:
    try:
        return "X={:.3f} Y={:.3f} Z={:.3f}".format(*p)
    except (TypeError, ValueError, IndexError):
        return "?"


def describe_event(e: dict) -> str:
    """One recorded event in an operator's words."""
    kind = e.get("kind")
    if kind == "start":
        part = e.get("part")
        return (f"session started on {e.get('port', '?')}" + (f" with part {part}" if part else "")
                + (f", tip radius {e['tip_radius']:.4f} mm" if isinstance(e.get("tip_radius"), (int, float)) else "")
                + (f" (re-evaluated from {e['derived_from'].get('session')})" if e.get("derived_from") else ""))
    if kind == "hit":
        return f"hit {e.get('id')} ({e.get('mode', 'programmed')}) at {_xyz(e.get('point'))} (machine)"
    if kind == "hit_deleted":
        return f"hit {e.get('id')} deleted" + (" (undo)" if e.get("undo") else "")
    if kind == "hit_restored":
        return f"hit {e.get('id')} restored" + (" (undo)" if e.get("undo") else "")
    if kind == "feature":
        form = e.get("form")
        return (f"feature {e.get('name')!r} fitted: {e.get('feature_kind')} ({e.get('method')}) from hits "
                f"{e.get('hit_ids')}" + (f", form {form * 1000:.2f} um" if isinstance(form, (int, float)) else ""))
    if kind == "feature_deleted":
        return f"feature {e.get('id')} deleted"
    if kind == "alignment":
        rms = e.get("rms")
        return f"part aligned ({e.get('method', 'manual')})" + (
            f", RMS {rms * 1000:.2f} um" if isinstance(rms, (int, float)) else "")
    if kind == "part":
        return f"part {e.get('name')} loaded"
    if kind == "note":
        return f"note: {e.get('text', '')}"
    if kind == "error":
        return f"error ({e.get('source', '?')}): {e.get('message', '')}"
    if kind == "program":
        return f"program {e.get('name')} ran" + (f" ({e.get('status')})" if e.get("status") else "")
    return f"{kind} event"


# --------------------------------------------------------------------------- the panel


class SessionsPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.session: Any = None  # the Session being replayed (None: live)
        self.replay: Any = None
        self.index = -1
        self.state: Any = None
        self.mesh: Any = None
        self.deviations: dict[int, float] = {}
        self.job: Job | None = None
        self.last_files: list[Path] = []
        self.gui: dict[str, Any] = {}
        self.progress_view = ProgressView(ctx)
        self._view: Any = None
        self._ticks = 0

    # --- store --------------------------------------------------------------

    def _query(self, name: str, **params: Any) -> Any:
        return self.ctx.commands.invoke(self.ctx.who(), name, **params)

    def where(self) -> str:
        """The session store (a folder or a postgresql:// URL), as the ``session_store`` query gives it."""
        return self._query("session_store")["store"]

    def store(self) -> Any:
        """The store, opened here to read a session for replay (its changes go through the API's verbs)."""
        return open_store(self.where())

    def live_name(self) -> str | None:
        """The name of the session being recorded now."""
        return self._query("session_store")["live"]

    def export_dir(self) -> Path:
        return Path(self._query("session_store")["export_dir"])

    def sessions(self, wait: bool = True) -> list[dict[str, Any]]:
        """name, events, hits, features, recording, modified for every session in the store (the ``sessions``
        query).

        The summaries are read by the session worker process, once per journal version for every tab;
        ``wait=False`` (the list the tab shows) gives "…" for one still being read."""
        return self._query("sessions", wait=wait)

    def list_markdown(self) -> str:
        try:
            rows = self.sessions(wait=False)
        except (StoreError, OSError) as exc:
            return f"*cannot list the sessions: {exc}*"
        if not rows:
            return "*no sessions yet*"
        lines = ["| session | hits | features | events | |", "|---|---:|---:|---:|---|"]
        for r in rows:
            flag = "● recording" if r["recording"] else ""
            if self.session is not None and r["name"] == self.session.name:
                flag = (flag + " · replaying").strip(" ·")
            lines.append(f"| {r['name']} | {r['hits']} | {r['features']} | {r['events']} | {flag} |")
        return "\n".join(lines)

    # --- jobs ---------------------------------------------------------------------

    def _start(self, title: str, fn: Callable[[Callable[[float, str], None]], Any],
               done: Callable[[Any], str]) -> Job | None:
        if self.job is not None and not self.job.done:
            self.ctx.error(f"wait until '{self.job.title}' has finished", title)
            return None

        def on_done(job: Job) -> None:
            if job.error is not None:
                exc = job.error
                text = str(exc) or type(exc).__name__
                self.ctx.error(text, f"{title} failed")
                self.progress_view.finish(job, text, False)
                return
            try:
                text = done(job.result)
            except Exception as exc:  # noqa: BLE001 - never a traceback in the UI
                job.error = exc
                self.ctx.error(str(exc), f"{title} failed")
                self.progress_view.finish(job, str(exc), False)
                return
            self.progress_view.finish(job, text, True)
            self.ctx.notify(title, text)
            self.refresh_list()

        job = Job(title, fn, on_progress=self.progress_view.update, on_done=on_done)
        self.job = job
        self.progress_view.start(job)
        return job.start()

    # --- replay ------------------------------------------------------------------------

    def _part_mesh(self, session: Any) -> Any:
        from ..session.export import resolve_part_mesh

        return resolve_part_mesh(session, self._live_mesh())

    def _live_mesh(self) -> Any:
        part = self.ctx.model().part
        return part.mesh if part is not None else None

    def open(self, name: str) -> Job | None:
        """Open a recorded session for replay (no machine motion); the scrubber goes to its last event."""
        from ..session.export import hit_deviations
        from ..session.replay import Replay

        def work(progress: Callable[[float, str], None]) -> Any:
            progress(0.0, f"reading {name}")
            with gc_paused():  # millions of new objects: no full collector passes that stall the machine loop
                contents = self.store().read(name)
                progress(0.2, f"indexing {len(contents.events)} events")
                replay = Replay.from_events(contents.events, name, contents.damage, progress=lambda i, n: progress(
                    0.2 + 0.5 * i / max(n, 1), f"event {i} of {n}"))
            session = replay.session
            if len(replay) == 0:
                raise StoreError(f"session {name!r} has no events")
            progress(0.75, "finding the part mesh")
            mesh = self._part_mesh(session)
            progress(0.85, "deviations of the hits")
            devs = hit_deviations(session, mesh) if mesh is not None else {}
            return [session, replay, mesh, devs]

        def done(result: Any) -> str:
            old = (self.session, self.replay, self.state)
            self.session, self.replay, self.mesh, self.deviations = result
            result.clear()  # the job keeps no reference: closing the replay frees it (in pieces)
            self.state = None
            if old[1] is not self.replay:
                dispose(*old)
            self.index = -1
            self.scrub(len(self.replay) - 1)
            if "scrub" in self.gui:
                self.gui["scrub"].max = max(len(self.replay) - 1, 1)
                self.gui["scrub"].value = len(self.replay) - 1
                self.gui["scrub"].disabled = False
            warn = "; ".join(self.session.warnings)
            return (f"replaying {name}: {len(self.replay)} events" + ("" if self.mesh is not None or
                    self.session.part is None else " (part mesh not found: hits only)") + (f". {warn}" if warn else ""))

        return self._start("Open session", work, done)

    def scrub(self, i: int) -> Any:
        """Show the state after event ``i`` (the slider)."""
        if self.replay is None:
            self.ctx.error("open a session for replay first", "Replay")
            return None
        i = min(max(int(i), 0), len(self.replay) - 1)
        if i == self.index and self.state is not None:
            return self.state
        self.index = i
        self.state = self.replay.at(i)
        self._draw()
        self._set("event", "content", self.event_text())
        return self.state

    def event_text(self) -> str:
        if self.replay is None or self.state is None:
            return "*live: no session is being replayed*"
        e = self.replay.event(self.index)
        s = self.state
        return (f"**{self.session.name}** · event {self.index + 1} of {len(self.replay)} · {_when(e.get('time'))}\n\n"
                f"{describe_event(e)}\n\n"
                f"state: {len(s.hits)} hits, {len(s.features)} features"
                + (f", {len(s.deleted_hits)} deleted" if s.deleted_hits else "")
                + (f", {len(s.errors)} errors" if s.errors else ""))

    def _draw(self) -> None:
        client = self.ctx.client
        if client is None or self.state is None:
            return
        from .scene import ReplayView

        if self._view is None:
            self._view = ReplayView(client.scene, self.ctx.view.scale)
        try:
            self._view.show(self.state, self.mesh, self.deviations)
        except Exception as exc:  # noqa: BLE001 - the tab may have closed
            self.ctx.error(str(exc), "Replay drawing")

    def back_to_live(self) -> None:
        old = (self.session, self.replay, self.state)
        self.session = self.replay = self.state = self.mesh = None
        dispose(*old)  # a 200,000-hit replay freed at once would hold the interpreter (and the machine loop) ~1 s
        self.index = -1
        self.deviations = {}
        if self._view is not None:
            try:
                self._view.clear()
            except Exception:  # noqa: BLE001
                pass
        if "scrub" in self.gui:
            self.gui["scrub"].disabled = True
        self._set("event", "content", self.event_text())
        self.refresh_list()

    # --- record management -------------------------------------------------------------

    def _change(self, action: str, verb: str, **params: Any) -> Any:
        """Send a verb that changes the record; the core decides who may, its refusal is shown (None)."""
        if not self.ctx.allowed(action):
            return None
        try:
            return self.ctx.commands.invoke(self.ctx.who(), verb, **params)
        except (StoreError, OSError, MotionError) as exc:
            self.ctx.error(exc, f"{action.split()[0]} refused")
            return None

    def rename(self, old: str, new: str) -> bool:
        new = self._change("Rename session", "rename_session", old=old, new=new)
        if new is None:
            return False
        if self.session is not None and self.session.name == old:
            self.session.name = new
        self.ctx.notify("Renamed", f"{old} → {new}")
        self.refresh_list()
        return True

    def delete(self, name: str) -> bool:
        if self._change("Delete session", "delete_session", name=name) is None:
            return False
        if self.session is not None and self.session.name == name:
            self.back_to_live()
        self.ctx.notify("Deleted", f"session {name}")
        self.refresh_list()
        return True

    def new_session(self, name: str = "") -> Any:
        """Close the live session and start recording a new one (empty name: a time stamp) for the next part:
        the tree empties (the hits and features taken so far stay in the closed session's journal), so what the
        page shows is what the new session records."""
        try:  # the new_part verb decides who may; its refusal is shown
            name = name.strip()
            if name:
                check_name(name)
                if self.store().exists(name):
                    raise StoreError(f"a session named {name!r} already exists: choose another name")
            path = self.ctx.commands.invoke(self.ctx.who(), "new_part", name=name or None)
        except (StoreError, OSError, MotionError) as exc:
            self.ctx.error(exc, "New session refused")
            return None
        self.ctx.notify("New session", f"recording {self.live_name()}")
        self.refresh_list()
        return path

    # --- exports ----------------------------------------------------------------------------

    def _download(self, path: Path) -> None:
        client = self.ctx.client
        send = getattr(client, "send_file_download", None) if client is not None else None
        if send is not None:
            try:
                send(path.name, path.read_bytes())
            except Exception:  # noqa: BLE001 - the file is on disk anyway
                pass

    def export(self, name: str, csv: bool = True, json: bool = True) -> Job | None:
        """Write ``<name>.csv`` (hits) and/or ``<name>.json`` (whole session) into the sessions folder
        (in the session worker process)."""
        from ..session import worker

        def work(progress: Callable[[float, str], None]) -> list[Path]:
            progress(0.1, f"exporting {name} (session worker)")
            return shared_worker().call(worker.export, self.where(), name, self.export_dir(), self._live_mesh(), csv,
                                        json)

        return self._start("Export", work, self._files_done)

    def qif(self, name: str) -> Job | None:
        """Write the session's QIF 3 Results ``<name>.qif`` into the sessions folder (and offer it); written in the
        session worker process (:func:`cmm.session.worker.qif`)."""
        from ..session import worker

        def work(progress: Callable[[float, str], None]) -> list[Path]:
            progress(0.1, f"writing the QIF results of {name} (session worker)")
            return shared_worker().call(worker.qif, self.where(), name, self.export_dir(), self._live_mesh())

        return self._start("QIF", work, self._files_done)

    def _files_done(self, files: list[Path]) -> str:
        self.last_files = list(files)
        for f in files:
            self._download(f)
        text = "wrote " + ", ".join(str(f) for f in files)
        self._set("files", "content", text)
        return text

    def report(self, name: str, trends: bool = False) -> Job | None:
        """Write the inspection report ``<name>-report.html`` and its feature table ``<name>-features.csv``
        into the sessions folder (and offer them); rendered in the session worker process. ``trends``: with the
        control charts of the series the session's part belongs to (as ``cmm report --trend``)."""
        from ..session import worker

        store = self.where()
        if trends and self._query("trends") is None:
            self.ctx.error("this station records no trends: start it with cmm serve --trends DIR", "Report")
            return None

        def work(progress: Callable[[float, str], None]) -> list[Path]:
            charts = None
            if trends:
                from ..session.trends import TrendError

                series = shared_worker().call(worker.trend_series, store, name)
                if not series:
                    raise TrendError(f"{name} was not recorded as a part of a series: run a routine or a DMIS "
                                     "program with trends on to make one")
                progress(0.05, f"the control charts of {series[-1]!r}")
                charts = self._query("trend_charts", series=series[-1])
            progress(0.1, f"rendering the report of {name} (session worker)")
            return shared_worker().call(worker.report, store, name, self.export_dir(),
                                        self._live_mesh(), self.ctx.view.scale, charts)  # the colour map's bands

        return self._start("Report", work, self._files_done)

    def reevaluate(self, name: str, new: str = "", tip_radius: float = 0.0, method: str = "recorded") -> Job | None:
        """Recompute hits and features from the raw counts with another tip radius / fit method into a new session."""
        if not self.ctx.allowed("Re-evaluate"):
            return None
        new = (new or "").strip() or f"{name}-reevaluated"
        try:  # refused now, in the operator's words; the verb checks again when the job sends it
            check_reevaluation(self.where(), new, tip_radius, method)
        except (StoreError, ValueError, OSError) as exc:
            self.ctx.error(exc, "Re-evaluate refused")
            return None

        def work(progress: Callable[[float, str], None]) -> Any:
            from ..dmis.replay import reevaluate_event  # a DMIS run's tolerances: its program run again

            progress(0.1, f"re-evaluating {name} (session worker)")
            return self.ctx.commands.invoke(self.ctx.who(), "reevaluate_session", name=name, new=new,
                                            tip_radius=float(tip_radius or 0.0), method=method,
                                            tolerances=reevaluate_event)

        def done(result: Any) -> str:
            errors = result["errors"]
            return (f"wrote {new}: {result['hits']} hits, {result['features']} features"
                    + (f"; {len(errors)} feature(s) could not be refitted: {errors[0]}" if errors else "")
                    + (f"; {result['left_out']}" if result.get("left_out") else ""))

        return self._start("Re-evaluate", work, done)

    # --- GUI ----------------------------------------------------------------------------------

    def selected(self) -> str:
        dd = self.gui.get("session")
        return "" if dd is None or dd.value == "-" else str(dd.value)

    def _need(self) -> str | None:
        name = self.selected()
        if not name:
            self.ctx.error("choose a session first", "Sessions")
            return None
        return name

    def build(self, gui: Any) -> None:
        g = self.gui
        g["list"] = gui.add_markdown(self.list_markdown())
        g["session"] = gui.add_dropdown("Session", self._names() or ("-",))
        gui.add_button("Refresh list").on_click(lambda _: self.refresh_list())
        with gui.add_folder("Replay"):
            gui.add_button("Open for replay").on_click(lambda _: (n := self._need()) and self.open(n))
            g["scrub"] = gui.add_slider("Event", min=0, max=1, step=1, initial_value=0, disabled=True)
            g["scrub"].on_update(lambda e: self.replay is not None and self.scrub(int(e.target.value)))
            step = gui.add_button_group("Step", ("|◀", "◀", "▶", "▶|"))
            step.on_click(lambda e: self._step(e.target.value))
            g["event"] = gui.add_markdown(self.event_text())
            gui.add_button("Back to live", color="green").on_click(lambda _: self.back_to_live())
        with gui.add_folder("Export", expand_by_default=False):
            gui.add_button("Export CSV + JSON").on_click(lambda _: (n := self._need()) and self.export(n))
            g["with_trends"] = gui.add_checkbox("Report with trends", False,
                                                hint="the control charts of the series the session's part belongs to")
            gui.add_button("Report (HTML + CSV)").on_click(
                lambda _: (n := self._need()) and self.report(n, bool(g["with_trends"].value)))
            gui.add_button("QIF 3 results").on_click(lambda _: (n := self._need()) and self.qif(n))
            g["files"] = gui.add_markdown("")
        with gui.add_folder("Re-evaluate", expand_by_default=False):
            g["re_name"] = gui.add_text("New session", "", hint="empty: <name>-reevaluated")
            g["re_tip"] = gui.add_number("Tip radius (mm)", 0.0, min=0.0, step=0.0001, hint="0 = as recorded")
            g["re_method"] = gui.add_dropdown("Fit method", METHODS, initial_value="recorded")
            gui.add_button("Re-evaluate").on_click(lambda _: (n := self._need()) and self.reevaluate(
                n, g["re_name"].value, float(g["re_tip"].value), g["re_method"].value))
        with gui.add_folder("Manage", expand_by_default=False):
            g["new_name"] = gui.add_text("Name", "", hint="new session / rename to")
            gui.add_button("New session").on_click(lambda _: self.new_session(g["new_name"].value))
            gui.add_button("Rename selected").on_click(
                lambda _: (n := self._need()) and self.rename(n, g["new_name"].value))
            gui.add_button("Delete selected", color="red").on_click(lambda _: self._confirm_delete())
        self.progress_view.build(gui)

    def _step(self, which: str) -> None:
        if self.replay is None:
            self.ctx.error("open a session for replay first", "Replay")
            return
        i = {"|◀": 0, "◀": self.index - 1, "▶": self.index + 1, "▶|": len(self.replay) - 1}.get(which, self.index)
        self.scrub(i)
        if "scrub" in self.gui:
            self.gui["scrub"].value = self.index

    def _confirm_delete(self) -> None:
        name = self._need()
        if not name or self.ctx.client is None:
            return
        if not self.ctx.allowed("Delete session"):
            return
        with self.ctx.client.gui.add_modal("Delete session?") as modal:
            self.ctx.client.gui.add_markdown(f"Delete **{name}** and its journal? This cannot be undone.")

            def yes(_: Any) -> None:
                modal.close()
                self.delete(name)

            self.ctx.client.gui.add_button("Delete", color="red").on_click(yes)
            self.ctx.client.gui.add_button("Cancel").on_click(lambda _: modal.close())

    def _names(self) -> tuple[str, ...]:
        try:
            return tuple(i.name for i in self.store().list())
        except (StoreError, OSError):
            return ()

    def refresh_list(self) -> None:
        if not self.gui:
            return
        self._set("list", "content", self.list_markdown())
        names = self._names() or ("-",)
        dd = self.gui["session"]
        if tuple(dd.options) != names:
            keep = dd.value
            dd.options = names
            if keep in names:
                dd.value = keep

    def refresh(self) -> None:
        """Called by ClientApp.refresh (5 Hz): re-list the store every couple of seconds."""
        if not self.gui:
            return
        self._ticks += 1
        if self._ticks % LIST_EVERY == 0:
            self.refresh_list()

    def _set(self, key: str, attr: str, value: Any) -> None:
        h = self.gui.get(key)
        if h is not None and getattr(h, attr, None) != value:
            setattr(h, attr, value)


__all__ = ["SessionsPanel", "describe_event"]
