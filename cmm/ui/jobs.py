"""Background work of the panels: a :class:`Job` thread with progress, and its :class:`ProgressView`.

Work that may take a while (opening a big session, exports, reports, re-evaluation, calibration routines) runs
in a Job thread, never in viser's callback thread; its ProgressView shows a progress bar, a status line and a
notification with a loading state in the tab that started it.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

from .context import PanelContext


class Job:
    """Work in its own thread with a progress callback ``(fraction 0..1, sentence)``.

    ``fn(progress)`` returns the result; an exception is kept in ``error``.
    ``on_done(job)`` runs in the worker thread before ``wait()`` returns.
    """

    def __init__(self, title: str, fn: Callable[[Callable[[float, str], None]], Any], *,
                 on_progress: Callable[["Job"], None] | None = None,
                 on_done: Callable[["Job"], None] | None = None) -> None:
        self.title = title
        self.fn = fn
        self.fraction = 0.0
        self.message = ""
        self.result: Any = None
        self.error: BaseException | None = None
        self.on_progress = on_progress
        self.on_done = on_done
        self._done = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"ui-job-{title}", daemon=True)

    def start(self) -> "Job":
        self.thread.start()
        return self

    def progress(self, fraction: float, message: str = "") -> None:
        self.fraction = min(max(float(fraction), 0.0), 1.0)
        if message:
            self.message = message
        if self.on_progress is not None:
            try:
                self.on_progress(self)
            except Exception:  # noqa: BLE001 - a closed tab must not stop the work
                pass

    def _run(self) -> None:
        try:
            self.result = self.fn(self.progress)
        except BaseException as exc:  # noqa: BLE001 - reported to the operator by on_done
            self.error = exc
        finally:
            try:
                if self.on_done is not None:
                    self.on_done(self)
            finally:
                self._done.set()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)


class ProgressView:
    """A progress bar + status line in a panel, and a notification with a loading state."""

    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.bar: Any = None
        self.status: Any = None
        self._note: Any = None
        self._last = 0.0

    def build(self, gui: Any) -> None:
        self.status = gui.add_markdown("")
        self.bar = gui.add_progress_bar(0.0, visible=False, animated=True)

    def start(self, job: Job) -> None:
        self._last = 0.0
        if self.bar is not None:
            self.bar.value = 0.0
            self.bar.visible = True
        if self.status is not None:
            self.status.content = f"**{job.title}** started"
        client = self.ctx.client
        if client is not None:
            try:
                self._note = client.add_notification(job.title, "started", loading=True, with_close_button=False)
            except Exception:  # noqa: BLE001 - the tab may have closed
                self._note = None

    def update(self, job: Job) -> None:
        now = time.monotonic()
        if now - self._last < 0.1 and job.fraction < 1.0:
            return  # at most 10 updates a second
        self._last = now
        text = f"{job.fraction * 100:.0f} % · {job.message}"
        if self.bar is not None:
            self.bar.value = round(job.fraction * 100, 1)
        if self.status is not None:
            self.status.content = f"**{job.title}**: {text}"
        if self._note is not None:
            try:
                self._note.body = text
            except Exception:  # noqa: BLE001
                pass

    def finish(self, job: Job, text: str, ok: bool) -> None:
        if self.bar is not None:
            self.bar.value = 100.0 if ok else self.bar.value
            self.bar.visible = False
        if self.status is not None:
            self.status.content = f"**{job.title}**: {text}"
        if self._note is not None:
            try:
                self._note.title = job.title + (" done" if ok else " stopped")
                self._note.body = text
                self._note.loading = False
                self._note.color = None if ok else "red"
                self._note.with_close_button = True
                self._note.auto_close_seconds = 6.0 if ok else 10.0
            except Exception:  # noqa: BLE001
                pass
            self._note = None
