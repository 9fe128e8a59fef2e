"""The status bar at the top of every tab's panel: machine state, control, link, DRO, probe, STOP / E-STOP.

It is the first thing in the panel and stays on screen while the tabs below
scroll (a sticky block: CSS plus a layout-only script, see ``STICKY_CSS``). The read-out
shows the machine state (not homed / idle / moving / jogging / probing /
stopped / fault with its reason), who holds control, link health (samples
per second), the DRO in machine or part coordinates (switchable; part
coordinates through the alignment), and the probe: armed for manual hits,
triggered, the tip in use and its qualification. It is re-sent only when
its text changes. A tab with a page draws it from a subscription to the API's queries (:data:`STATUS_QUERIES`,
:mod:`cmm.ui.feed`), never by polling them.
"""

from __future__ import annotations

import html
import threading
import time
from types import SimpleNamespace
from typing import Any, Callable

from .frames import alignment_text
from .context import PanelContext
from .feed import Feed
from .model_view import reader

FRAMES = ("Machine", "Part")
# Keeps the status block on screen while the panel scrolls, in two layers that do not depend on one another:
# 1. CSS on Mantine's static class names (part of Mantine's styling API, not viser's generated ones): the
#    folder (Paper) that holds #cmm-status is sticky; the containers around it must not clip (a clipping
#    ancestor would become the sticky block's scroll box);
# 2. a script sent once per tab (viser's RunJavascriptMessage) that finds the block by layout alone: the
#    nearest scrolling ancestor of #cmm-status, and below it the largest ancestor of the bar that is not yet
#    as tall as the scrolled content. It marks that block data-cmm-sticky (and any clipping ancestor
#    data-cmm-unclip), and re-checks once a second (tabs change the content height; React may re-create nodes).
# 3. compact (room to work at 1280 x 800 and on a tablet): the block has no folder header (it cannot be folded
#    away), STOP and E-STOP share one row, Take control (or Release) and the DRO's frame share the next, and its
#    cover against the content scrolled under it reaches up only (a shadow all round painted over what follows).
STICKY_CSS = """<style>
[data-cmm-sticky] { position: sticky; top: 0; z-index: 20; background: var(--mantine-color-body, #fff);
  box-shadow: 0 -10px 0 0 var(--mantine-color-body, #fff); }
[data-cmm-unclip] { overflow: visible !important; }
.mantine-ScrollArea-content .mantine-Paper-root:has(#cmm-status) {
  position: sticky; top: 0; z-index: 20; background: var(--mantine-color-body, #fff);
  box-shadow: 0 -10px 0 0 var(--mantine-color-body, #fff); }
.mantine-Paper-root:has(#cmm-status) > .mantine-Paper-root:first-child { display: none; }
.mantine-Paper-root:has(#cmm-status) div:has(> div > #cmm-status) { display: flex; flex-wrap: wrap; column-gap: 6px; }
.mantine-Paper-root:has(#cmm-status) div:has(> div > #cmm-status) > div { flex: 1 1 100%; min-width: 0; }
.mantine-Paper-root:has(#cmm-status) div:has(> div > #cmm-status) > div:has(> button) { flex: 1 1 40%; }
.mantine-Paper-root:has(#cmm-status) div:has(> div > #cmm-status) > div:has(> .mantine-Flex-root button) { flex: 1 1 50%; }
.mantine-Paper-root:has(#cmm-status) div:has(> div > #cmm-status) > div > .mantine-Flex-root > div:first-child {
  width: auto !important; }
.mantine-ScrollArea-content div:has(.mantine-Paper-root #cmm-status) { overflow: visible !important; }
.cmm-status { font: 12.5px/1.35 system-ui, sans-serif; padding: 2px 0 4px; }
.cmm-status .mode { font-weight: 700; padding: 1px 6px; border-radius: 3px; color: #fff; }
.cmm-status .dro { font: 600 12.5px/1.3 ui-monospace, monospace; display: grid;
  grid-template-columns: 4.2em 1fr 1fr 1fr; gap: 0 6px; margin: 3px 0; white-space: nowrap; }
.cmm-status .muted { color: #777; }
.cmm-status .warn { color: #c62828; font-weight: 600; }
.cmm-status .mode { display: inline-block; min-width: 5.2em; text-align: center; }
.cmm-status .reason { min-height: 1.35em; }
.cmm-status .reason.one { white-space: nowrap; overflow: hidden; text-overflow: ellipsis; }
.cmm-status .pstate { display: inline-block; min-width: 9.5em; }
</style>"""
STICKY_JS = """
if (!window.__cmmSticky) {
  window.__cmmSticky = true;
  const pin = () => {
    const bar = document.getElementById("cmm-status");
    if (!bar) return;
    let box = bar.parentElement;
    while (box && !/(auto|scroll)/.test(getComputedStyle(box).overflowY)) box = box.parentElement;
    if (!box) return;
    const full = box.scrollHeight - 2;
    let block = bar;
    while (block.parentElement && block.parentElement !== box
           && block.parentElement.getBoundingClientRect().height < full) block = block.parentElement;
    if (!block.hasAttribute("data-cmm-sticky")) {
      document.querySelectorAll("[data-cmm-sticky]").forEach(e => e.removeAttribute("data-cmm-sticky"));
      block.setAttribute("data-cmm-sticky", "");
    }
    for (let e = block.parentElement; e && e !== box; e = e.parentElement) {
      if (!e.hasAttribute("data-cmm-unclip") && getComputedStyle(e).overflowY !== "visible") {
        e.setAttribute("data-cmm-unclip", "");
      }
    }
  };
  pin();
  setInterval(pin, 1000);
}
"""
MODE_COLOURS = {"idle": "#2e7d32", "moving": "#1565c0", "jogging": "#1565c0", "probing": "#6a1b9a",
                "homing": "#1565c0", "not homed": "#8d6e00", "stopped": "#8d6e00", "e-stopped": "#b71c1c",
                "fault": "#b71c1c", "no link": "#b71c1c", "running": "#1565c0", "paused": "#8d6e00"}
# the machine states a cycle (auto-measure of several hits) passes through between and during its moves:
# the bar says RUNNING for the whole cycle, so a pause between two hits does not look like the end
CYCLE_MODES = ("idle", "moving", "probing")


# the queries the status bar draws from, as it subscribes to them (cmm.api.subscriptions): the machine's state and
# last sample, the tip in part coordinates (None without a part), the part's alignment and the probe in use, the
# calibration's hold and qualification, the shop database's words, the tip radius and the link meter's samples
STATUS_QUERIES: dict[str, dict[str, Any]] = {
    "state": {}, "position": {"frame": "part"}, "part_alignment": {}, "calibration_state": {}, "upload_status": {},
    "tip_radius": {}, "samples": {}}
STATUS_RATE = 20.0  # Hz: the DRO follows a move at this rate (the bar is re-sent only when its text changes)


def machine_mode(cs: dict[str, Any]) -> tuple[str, str, bool]:
    """(mode, reason, link ok) from the control core's state (the ``state`` query as JSON: not homed / idle /
    moving / probing / fault ...)."""
    mode = str(getattr(cs["mode"], "value", cs["mode"]))  # in process the JSON keeps the Mode (a str enum)
    reason = cs["reason"] or (cs["activity"] if mode in ("moving", "probing", "homing") else "")
    return mode, str(reason or ""), bool(cs["link_ok"])


class LinkMeter:
    """Machine samples per second between read-out refreshes: the link's health."""

    def __init__(self) -> None:
        self._last: tuple[float, int] | None = None
        self.rate = 0.0

    def update(self, samples: int, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        if self._last is not None and now - self._last[0] >= 0.5:
            self.rate = (samples - self._last[1]) / (now - self._last[0])
            self._last = (now, samples)
        elif self._last is None:
            self._last = (now, samples)
        return self.rate


def status_snapshot(source: Any) -> dict[str, Any]:
    """One round of :data:`STATUS_QUERIES` of ``source`` (a query function or the command API), as JSON: what the
    bar's subscription delivers (a tab without a page, the tests, read it this way)."""
    from ..api import jsonable

    query = reader(source)
    return {name: jsonable(query(name, **params)) for name, params in STATUS_QUERIES.items()}


def status_html(source: Any, control_text: str, *, frame: str = "Machine", link_rate: float | None = None,
                armed: bool = False, cycle: str | None = None, cycle_paused: bool = False,
                run_stopped: str = "") -> str:
    """The status block's HTML (pure: what it shows comes from ``source`` and the arguments, so it is tested
    without a browser). ``source``: the snapshot of :data:`STATUS_QUERIES` (``{query: JSON value}``, as the
    subscription delivers it), or a query function or the command API to take one from (:func:`status_snapshot`).
    ``cycle``: the cycle running (an auto-measure, a routine run), shown as RUNNING while the machine is in it
    (PAUSED with ``cycle_paused``: a routine paused between hits)."""
    e = html.escape
    snap = source if isinstance(source, dict) else status_snapshot(source)
    cs = snap["state"]  # the control core's state and last sample (the observer's snapshot)
    frame_info = snap["part_alignment"]  # the part, the alignment in force, the probe's name
    mode, reason, link_ok = machine_mode(cs)
    if cycle and mode in CYCLE_MODES:
        mode, reason = ("paused", f"{cycle}: Resume goes on") if cycle_paused else ("running", cycle)
    elif run_stopped and mode == "idle":  # the last run was refused or stopped: not back to a plain IDLE
        mode, reason = "stopped", run_stopped
    calibration = snap["calibration_state"]
    if calibration["holding"]:  # the job stands in the machine loop
        mode, reason = "paused", f"{reason or 'calibration'}: Resume goes on"
    st = cs["machine"]
    colour = MODE_COLOURS.get(mode, "#555")
    out = [f"<div id='cmm-status' class='cmm-status'><span class='mode' style='background:{colour}'>{e(mode.upper())}</span>"]
    out.append(f" &middot; {e(control_text)}")
    warning = cs.get("link_warning", "")
    if warning:
        out.append(f" &middot; <span class='warn'>link warning: {e(warning)}</span>")
    if link_rate is not None:
        # no figure: a rate that changes every refresh would re-send the bar from an idle page. A paused run holds
        # the machine loop (no samples are taken while it stands): that is not a silent link
        if link_ok and link_rate <= 5.0 and mode == "paused":
            out.append(" &middot; link <span class='muted'>ok (paused: not sampling)</span>")
        else:
            ok = link_ok and link_rate > 5.0
            out.append(f" &middot; link <span class='{'' if ok else 'warn'}'>{'ok' if ok else 'SILENT: no samples'}</span>")
    offline = snap["upload_status"]  # the shop's session database: "database offline, N events waiting"
    if offline:
        out.append(f" &middot; <span class='warn'>{e(offline)}</span>")
    # the reason on a line of its own, always there: a move's words appearing and going never change the block's
    # height (the buttons below it stay under the operator's finger); one line while the machine moves (the whole
    # text in its tooltip), wrapped when it stands (a fault's reason is read in full)
    moving = mode in ("moving", "probing", "homing", "jogging", "running")
    out.append(f"<div class='reason{' warn' if reason else ''}{' one' if moving else ''}' title='{e(reason)}'>"
               f"{e(reason) if reason else '&nbsp;'}</div>")
    if st is not None:
        pos = [a["mm"] for a in st["axes"]]
        label = "machine"
        if frame == "Part" and snap["position"] is not None:  # None: part coordinates without a part
            pos, label = snap["position"], "part"
        model = SimpleNamespace(part=frame_info["part"], aligned=frame_info["aligned"],
                                alignment_name=frame_info["alignment"])
        frame_name = f"<span class='muted'>{e(alignment_text(model))}</span>" if label == "part" else ""
        out.append(f"<div class='dro' aria-label='DRO {label}'><span class='muted'>{e(label)}</span>"
                   + "".join(f"<span>{n} {v:.4f}</span>" for n, v in zip("XYZ", pos)) + frame_name + "</div>")
        if label == "part" and not frame_info["aligned"]:
            out.append("<div class='warn'>no alignment made: part coordinates of the nominal set-up</div>")
        radius = snap["tip_radius"]
        tip = "" if radius is None else f"tip r {radius:.4f} mm"
        probe_cal = calibration["probe"]
        qual = f"qualified {str(probe_cal.get('date', ''))[:10]}" if probe_cal else "not qualified"
        probe_state = "TRIGGERED" if st["probe_triggered"] else ("armed (manual hits)" if armed else "free")
        cls = "warn" if st["probe_triggered"] else ""
        out.append(f"probe {e(frame_info['probe'])} <span class='pstate {cls}'>{probe_state}</span> &middot; {tip}, {qual}")
    out.append("</div>")
    return "".join(out)


def run_script(gui: Any, source: str) -> bool:
    """Run ``source`` in this client's page through viser's own script message (it loads plotly that way).
    False when this viser version has no such message: the sticky CSS rule alone keeps the bar on screen."""
    try:
        from viser import _messages

        gui._websock_interface.queue_message(_messages.RunJavascriptMessage(source=source))
        return True
    except Exception:  # noqa: BLE001 - an internal of viser: its absence must not break the page
        return False


class StatusPanel:
    """The status block and the STOP / E-STOP buttons of one tab. A tab with a page subscribes to
    :data:`STATUS_QUERIES` (:meth:`subscribe`): each delivery redraws the bar from the snapshot; the refresher redraws
    it from the same snapshot for what is the page's own (who holds control, a cycle, manual hits armed, the link
    meter's clock). A tab without a page (tests, scripts) reads the queries when asked (:meth:`html`)."""

    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.frame = "Machine"
        self.link = LinkMeter()
        self.gui: dict[str, Any] = {}
        self.feed: Feed | None = None  # the subscription (a tab with a page)
        self._shown = ""
        self._lock = threading.Lock()  # the hub's deliveries and the refresher both redraw

    def subscribe(self, on_error: Callable[[str, str], None]) -> Feed:
        """Follow the station through the API's subscription, as this tab's client when it connected (the bar's
        queries are open to every client, an anonymous observer too: a log-in later changes nothing they answer);
        ``close()`` ends it."""
        self.feed = Feed(self.ctx.api, self.ctx.who(), STATUS_QUERIES, STATUS_RATE, lambda _snap: self.refresh(),
                         on_error)
        return self.feed

    def close(self) -> None:
        if self.feed is not None:
            self.feed.close()

    def build(self, gui: Any, controls: Callable[[Any], Any] | None = None) -> None:
        """The pinned block: STOP and E-STOP on one row at its top, the status lines, then ``controls(gui)`` (the
        tab's Take control / Release button) beside the DRO's frame. Nothing above the two buttons changes height: a
        status line that wraps as the mode or its reason changes never moves them from under the operator's finger
        (it did, and a press during a move landed on the status text)."""
        if self.feed is not None:
            self.feed.wait()  # the first snapshot: the bar opens showing the machine
        gui.add_html(STICKY_CSS)
        run_script(gui, STICKY_JS)
        with gui.add_folder("Status"):
            gui.add_button("STOP", color="orange").on_click(self._press(lambda: self.ctx.stop()))
            gui.add_button("E-STOP", color="red").on_click(self._press(lambda: self.ctx.emergency_stop()))
            with self._lock:
                self._shown = self.html()
                self.gui["status"] = gui.add_html(self._shown)
            if controls is not None:
                controls(gui)
            frame = gui.add_button_group("DRO", FRAMES)
            frame.on_click(lambda e: self.set_frame(e.target.value))

    @staticmethod
    def _press(fn: Callable[[], Any]) -> Callable[[Any], Any]:
        """A STOP / E-STOP click that came over viser's socket (the page's hold refresher sends it first when its
        own socket is open, web/hold_worker.js): a coroutine, so viser runs it as the message arrives, not behind
        its thread pool's queue; the press runs on a thread of its own (it answers when every axis stands)."""
        async def pressed(_event: Any) -> None:
            threading.Thread(target=fn, name="page-stop", daemon=True).start()
        return pressed

    def set_frame(self, frame: str) -> None:
        if frame in FRAMES:
            self.frame = frame
            self.ctx.frame_shown(frame)  # the DRO's frame is the Go to fields' default
            self.refresh()

    def html(self) -> str:
        """The bar now: from the subscription's last snapshot (a tab with a page), else from the queries."""
        snap = status_snapshot(self.ctx.query) if self.feed is None else self.feed.snapshot()
        if snap is None:  # no whole snapshot yet (a query failing: told once, see Feed)
            return (f"<div id='cmm-status' class='cmm-status'><span class='mode' style='background:#555'>"
                    f"&hellip;</span> &middot; {html.escape(self.ctx.control_text().replace('*', ''))}"
                    "<div class='reason'>&nbsp;</div></div>")
        rate = self.link.update(int(snap["samples"]))
        return status_html(snap, self.ctx.control_text().replace("*", ""), frame=self.frame, link_rate=rate,
                           armed=self.ctx.manual_probe, cycle=getattr(self.ctx.shared, "cycle", None),
                           cycle_paused=bool(getattr(self.ctx.shared, "cycle_paused", False)),
                           run_stopped=str(getattr(self.ctx.shared, "run_stopped", "") or ""))

    def refresh(self) -> None:
        """Redraw the bar (re-sent only when its text changed): on a delivery, and from the refresher."""
        if "status" not in self.gui:
            return
        with self._lock:
            text = self.html()
            if text != self._shown:
                self._shown = text
                self.gui["status"].content = text
