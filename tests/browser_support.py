"""Launch the system's headless chromium through Playwright (no browser download, no sandbox, no network).

Playwright is used only as a CDP driver: the browser is Debian's /usr/bin/chromium
(``apt-get install chromium``), never one fetched by ``playwright install``.
Set CMM_CHROMIUM to use another binary.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator


CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync",
]
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"
# The one wait (ms) for anything a page is to show: its first paint, a panel, a toast, a screenshot's frame. It is
# a bound, not a pause (every wait ends as soon as its condition holds), and generous: chromium renders WebGL in
# software here, and on a loaded 2-core machine (CPU hogs, the other test worker) its first paint of the viser
# page alone has taken over 30 s.
PAGE_WAIT_MS = 120_000
# Device pixels per CSS pixel. Layout, clicks and sizes are in CSS pixels whatever this is; it sets how many
# pixels chromium draws. Software WebGL costs in proportion: at 0.5 (a quarter of the pixels) the colour-map
# test's chromium used 30 CPU s instead of 116, and the browser tests were three quarters of the suite's CPU.
# CMM_TEST_DPR=1 draws (and screenshots) at full resolution.
DEVICE_SCALE = float(os.environ.get("CMM_TEST_DPR", "0.5"))
# Device pixels per CSS pixel of viser's 3-D view alone (its ``fixedDpr``; viser never goes under 1 by itself):
# software WebGL's cost is the pixels it shades, and no test reads the view's pixels (picks are rays from CSS
# coordinates). CMM_TEST_VIEW_DPR=1 for sharp screenshots of the view.
VIEW_SCALE = float(os.environ.get("CMM_TEST_VIEW_DPR", "0.25"))  # 0.1 cut an idle page's GPU process only from
# 0.08 to 0.06 of a core (with the environment map off, station_app's shadows=False: most of the gain)


# The 3-D view's frames at most every FRAME_MS ms when nothing came from the station (requestAnimationFrame held
# back; viser draws on demand, and its timers, jog holds and GUI-only messages do not wait for frames): 2 a second.
# Chromium's software WebGL (SwiftShader) costs about 50 CPU ms a frame of the station's scene whatever the view's
# size (its worker threads, not the pixels), and viser draws continuously for 250 ms after each scene update, so a
# page whose probe moved drew as fast as it was let: 10 frames a second were half a core per page, 2 a second a
# tenth. CMM_TEST_FRAME_MS=0: uncapped.
FRAME_MS = float(os.environ.get("CMM_TEST_FRAME_MS", "500"))
# viser applies the station's messages in a frame (a GUI-only batch waits too when a scene message is queued before
# it), so a page that had a message since its last frame gets its next one MESSAGE_FRAME_MS after that frame: a
# click's answer shows in a fifth of a second instead of up to FRAME_MS, while the frames a moving probe asks for
# stay five a second at most. The page's websocket runs in a worker: its messages are seen as the worker's. A batch
# that only moves scene nodes (the probe, 25 a second while it moves) waits for the next FRAME_MS frame: a moving
# probe made the page draw five frames a second, each ~50 ms of the GPU process's CPU.
MESSAGE_FRAME_MS = float(os.environ.get("CMM_TEST_MESSAGE_FRAME_MS", "200"))
# A GUI element updated again within STREAM_MS of its last update is a stream (the status bar's DRO 20 times a
# second while the axes move, the read-outs and the following-error plot 5 times): like the probe's moves, it waits
# for the next FRAME_MS frame. A moving machine's streams let five frames a second through, each ~50 ms of the GPU
# process's CPU and as much of the renderer's; an element's first update after a quiet spell (a click's answer, the
# mode the STOP changed) is still shown MESSAGE_FRAME_MS after the last frame.
STREAM_MS = float(os.environ.get("CMM_TEST_STREAM_MS", "300"))
# Every callback waiting when a frame is let through runs in it (callbacks of one frame share its time stamp), so
# no requester (the 3-D view, a panel's opening transition) is starved by another. A test may space the frames
# further for a while: ``page.evaluate("window.__cmmFrameMs = 5000")`` (messages then wait as long too).
# ``window.__cmmPage`` keeps what a failed wait reports (page_diagnosis): the frames let through and when the last
# was, the callbacks waiting, and the page's longest main-thread tasks.
FRAME_CAP = """(() => { const raf = window.requestAnimationFrame.bind(window);
  const caf = window.cancelAnimationFrame.bind(window), ids = new Map(); let open = -1, due = 0, soon = 0, next = 1;
  let heard = false; const MOVES = new Set(["SetPositionMessage", "SetOrientationMessage"]), updated = new Map();
  const stats = window.__cmmPage = { frames: 0, lastFrame: -1, waiting: () => ids.size, longTasks: [] };
  const streaming = (m) => { if (m.type !== "GuiUpdateMessage") return false;
    const now = performance.now(), last = updated.get(m.uuid); updated.set(m.uuid, now);
    return last !== undefined && now - last < %g; };
  const Worker0 = window.Worker;
  if (Worker0) window.Worker = class extends Worker0 { constructor(...args) { super(...args);
    this.addEventListener("message", (e) => { const d = e.data;
      if (!(d && d.type === "message_batch")) { heard = true; return; }
      for (const m of d.messages) if (!MOVES.has(m.type) && !streaming(m)) heard = true; }); } };
  window.requestAnimationFrame = (cb) => { const id = next++;
    const go = (t) => { if (t === open || t >= due || (heard && t >= soon && !window.__cmmFrameMs)) {
                          if (t !== open) { open = t; due = t + (window.__cmmFrameMs || %g); soon = t + %g;
                                            heard = false; stats.frames++; stats.lastFrame = t; }
                          ids.delete(id); cb(t); } else { ids.set(id, raf(go)); } };
    ids.set(id, raf(go)); return id; };
  window.cancelAnimationFrame = (id) => { const r = ids.get(id); if (r !== undefined) { caf(r); ids.delete(id); } };
  try { new PerformanceObserver((list) => { for (const e of list.getEntries()) { stats.longTasks.push([e.startTime, e.duration]);
          stats.longTasks.sort((a, b) => b[1] - a[1]); stats.longTasks.length = Math.min(stats.longTasks.length, 5); } })
        .observe({ type: "longtask", buffered: true }); } catch (e) { /* no long-task timing here */ }
})();"""


def chromium_path() -> str | None:
    for candidate in (os.environ.get("CMM_CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                      shutil.which("chromium-browser")):
        if candidate and os.path.isfile(candidate) and os.access(candidate, os.X_OK):
            return candidate
    return None


def unavailable_reason() -> str | None:
    """Why browser tests cannot run here, or None when they can."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install playwright; the browser comes from apt: chromium)"
    if chromium_path() is None:
        return "chromium is not installed (apt-get install -y chromium) or CMM_CHROMIUM does not point to it"
    return None


@dataclass
class PageLog:
    """Console errors, uncaught exceptions and failed requests seen by a page."""

    console_errors: list[str] = field(default_factory=list)
    page_errors: list[str] = field(default_factory=list)
    failed_requests: list[str] = field(default_factory=list)

    def attach(self, page: Any) -> None:
        page.on("console", lambda m: self.console_errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: self.page_errors.append(str(e)))
        page.on("requestfailed", lambda r: self.failed_requests.append(f"{r.url}: {r.failure}"))

    @property
    def problems(self) -> list[str]:
        return self.console_errors + self.page_errors + self.failed_requests


@contextlib.contextmanager
def browser_context(viewport: tuple[int, int] = (480, 860), **options: Any) -> Iterator[Any]:
    """A Playwright browser context in a fresh profile directory, closed (and deleted) afterwards."""
    from playwright.sync_api import sync_playwright

    profile = tempfile.mkdtemp(prefix="cmm-chromium-")
    try:
        with sync_playwright() as p:
            context = p.chromium.launch_persistent_context(
                profile, executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS,
                viewport={"width": viewport[0], "height": viewport[1]}, timeout=PAGE_WAIT_MS,
                **{"device_scale_factor": DEVICE_SCALE, **options})
            context.set_default_timeout(PAGE_WAIT_MS)
            context.set_default_navigation_timeout(PAGE_WAIT_MS)
            if FRAME_MS:
                context.add_init_script(FRAME_CAP % (STREAM_MS, FRAME_MS, MESSAGE_FRAME_MS))
            try:
                yield context
            finally:
                context.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def page_diagnosis(page: Any) -> str:
    """What a page was doing, for a failed wait's message: its frames (a page whose frames stopped applies no more
    scene messages, nor GUI messages queued behind them), its longest main-thread tasks, and its clock."""
    try:
        d = page.evaluate("""() => { const s = window.__cmmPage; const now = performance.now();
            return s ? { now, frames: s.frames, sinceFrame: s.lastFrame < 0 ? null : now - s.lastFrame,
                         waiting: s.waiting(), longTasks: s.longTasks } : { now }; }""")
    except Exception as exc:  # noqa: BLE001 - a diagnosis never hides the failure it explains
        return f"the page did not answer ({type(exc).__name__}: {str(exc).splitlines()[0]})"
    if "frames" not in d:
        return f"page clock {d['now'] / 1000:.1f} s (no frame statistics)" + station_side(page)
    since = "none yet" if d["sinceFrame"] is None else f"the last {d['sinceFrame'] / 1000:.1f} s ago"
    tasks = ", ".join(f"{dur / 1000:.2f} s at {at / 1000:.1f} s" for at, dur in d["longTasks"]) or "none"
    return (f"page clock {d['now'] / 1000:.1f} s; {d['frames']} frames, {since}; {d['waiting']} frame callbacks "
            f"waiting; longest main-thread tasks: {tasks}" + station_side(page))


def station_side(page: Any) -> str:
    """The station's side of a page, for a failed wait's message: is the tab's client still connected, and is the
    refresher that copies the read-outs into it going (its rounds, read twice a second apart, and its failures)."""
    capp = getattr(page, "capp", None)
    app = getattr(capp, "app", None)
    if app is None:
        return ""
    before = app.refreshes
    time.sleep(1.0)
    return (f"; station: the tab's client {'is connected' if page.cid in app.clients else 'is gone'}, the refresher "
            f"did {app.refreshes - before} read-out rounds in 1 s ({app.refreshes} in all, {app.refresh_errors} "
            "failed)")


def shows(page: Any, text: str, station_has: Any = None, timeout: float = PAGE_WAIT_MS / 1000) -> None:
    """Wait until the page shows ``text``; if it does not, say whether the station had it to show
    (``station_has()``: what the station's widget holds) and what the page was doing. Every text wait in the
    tests looks among the visible matches only (``.filter(visible=True).first``): the hidden tabs hold the same
    words (the routine's DONE also matched a hidden "accel done" cell of the Diagnostics table, and ``.first``
    waited on that one in vain). The match ignores case and takes any visible text containing ``text``: give words
    that nothing else on the page says ("Alignment computed" was met at once by "no alignment computed")."""
    try:
        page.get_by_text(text).filter(visible=True).first.wait_for(timeout=timeout * 1000)
    except Exception as exc:  # noqa: BLE001 - Playwright's timeout, re-raised with the diagnosis
        had = "" if station_has is None else f"; the station's widget holds {str(station_has())[-300:]!r}"
        raise AssertionError(f"the page did not show {text!r} within {timeout:g} s{had}; "
                             f"{page_diagnosis(page)}") from exc


def screenshot(page: Any, name: str, **options: Any) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    options.setdefault("timeout", PAGE_WAIT_MS)  # waits for fonts and a WebGL frame
    page.screenshot(path=str(path), **options)
    return path


from netutil import SIM, free_port  # noqa: E402,F401 - free_port re-exported for the browser tests


def sim_station(tmp_path_factory: Any, session: str) -> Iterator[Any]:
    """A homed station on the simulator recording ``session``; a module fixture's body:
    ``yield from bs.sim_station(tmp_path_factory, "walk")`` (closed after the module)."""
    from stations import Stations

    with Stations(lambda: tmp_path_factory.mktemp(f"{session}-sessions")) as built:
        yield built.station(session)


def station_app(station: Any, **options: Any) -> Iterator[Any]:
    """The station's web UI on a free 127.0.0.1 port (``options``: StationApp's, e.g. ``pendant=False``);
    a module fixture's body: ``yield from bs.station_app(station, ...)`` (closed after the module)."""
    from stations import station_page

    options.setdefault("ask_name", False)  # no start dialog over the page unless the test is about it
    options.setdefault("shadows", False)  # software WebGL: the shadow maps and the environment map were most of
    # chromium's CPU (see app_url): an idle page's GPU process 0.18 of a core with the map, 0.08 without
    ui = station_page(station, host="127.0.0.1", port=free_port(), **options)
    yield ui
    ui.close()


# A fake standard-mapping gamepad whose state the test changes through window.__pad.
FAKE_GAMEPAD = """
(() => {
  window.__pad = { axes: [0, 0, 0, 0], buttons: new Array(17).fill(0) };
  const snapshot = () => ({
    id: "Test gamepad (STANDARD GAMEPAD)", index: 0, connected: true, mapping: "standard",
    timestamp: performance.now(), axes: window.__pad.axes.slice(),
    buttons: window.__pad.buttons.map(v => ({ pressed: v > 0.5, touched: v > 0, value: v })),
  });
  Object.defineProperty(navigator, "getGamepads", { configurable: true, value: () => [snapshot(), null, null, null] });
})();
"""


def viser_ready(page: Any) -> None:
    """Wait (up to PAGE_WAIT_MS) until the station's viser page has painted its scene canvas and the GUI its
    viser client sent over the socket (the status bar's E-STOP button)."""
    try:
        page.wait_for_selector("canvas", timeout=PAGE_WAIT_MS)
        page.get_by_role("button", name="E-STOP").wait_for(timeout=PAGE_WAIT_MS)
    except Exception as exc:  # noqa: BLE001 - Playwright's timeout, re-raised with what the page had
        try:
            had = page.evaluate("() => [document.readyState, document.querySelectorAll('canvas').length, "
                                "document.body ? document.body.innerText.slice(0, 200) : '']")
        except Exception as inner:  # noqa: BLE001
            had = f"no answer ({type(inner).__name__})"
        raise AssertionError(f"the station page was not ready within {PAGE_WAIT_MS / 1000:g} s (ready state, "
                             f"canvases, text: {had}); {page_diagnosis(page)}") from exc


COUNT_PASSES = """() => { const m = window.__passes = new Map(); let now = 0;
  const raf = window.requestAnimationFrame;
  window.requestAnimationFrame = (cb) => raf((t) => { now = t; cb(t); });
  for (const P of [WebGLRenderingContext.prototype, WebGL2RenderingContext.prototype]) {
    const clear = P.clear;
    P.clear = function (...a) { m.set(now, (m.get(now) || 0) + 1); return clear.apply(this, a); }; } }"""


def render_passes(page: Any, wait_ms: int = 3000) -> int:
    """The most render passes (WebGL clears) the page's 3-D view drew in one frame over ``wait_ms`` (viser redraws
    an idle scene about once a second): 1 without shadows, one more per shadow-casting light with them."""
    page.evaluate(COUNT_PASSES)
    page.wait_for_timeout(wait_ms)
    waited = wait_ms
    while not page.evaluate("window.__passes.size") and waited < PAGE_WAIT_MS:  # a loaded machine drew no frame yet
        page.wait_for_timeout(500)
        waited += 500
    return int(page.evaluate("Math.max(0, ...window.__passes.values())"))


def app_url(app: Any) -> str:
    """The station page's address for a test page: viser's 3-D view drawn at VIEW_SCALE device pixels per CSS
    pixel. With the shadows off too (``station_app``), an idle page's software WebGL went from 0.54 of a core to
    0.11 at 0.5 pixels."""
    return f"{app.url}?fixedDpr={VIEW_SCALE:g}"


def open_page(context: Any, app: Any, viewport: tuple[int, int] | None = None) -> Any:
    """A new page on the station app with its viser client: ``page.capp`` is the tab's ClientApp, ``page.cid`` its
    client id, ``page.log`` the console errors and failed requests it saw. ``viewport`` (width, height): the page's
    size from the start, instead of the context's (a page resized once loaded lays out and re-renders its
    software-rendered scene again: seconds on a loaded machine)."""
    before = set(app.clients)
    page = context.new_page()
    if viewport is not None:
        page.set_viewport_size({"width": viewport[0], "height": viewport[1]})
    page.log = PageLog()
    page.log.attach(page)
    page.goto(app_url(app))
    cid = new_client(page, app, before)
    page.cid = cid
    page.capp = app.clients[cid]
    return page


def new_client(page: Any, app: Any, before: set) -> Any:
    """The id of the viser client a page just opened on ``app`` (``before``: the clients before it): once the page
    shows its GUI, the newest client that was not there before (a socket that dropped and came back under load is
    a new client, the old one gone)."""
    viser_ready(page)
    wait_until(lambda: set(app.clients) - before, PAGE_WAIT_MS / 1000, "the page's viser client",
               why=lambda: f"clients {sorted(app.clients)} (before {sorted(before)}); {page_diagnosis(page)}")
    return max(set(app.clients) - before)


def focus_view(page: Any) -> None:
    """Click the 3-D view left of the middle (clear of the notifications in its corners and of the panel): the
    view takes the keyboard (its jog keys, Esc and Space for STOP)."""
    wait_until(lambda: page.evaluate("() => !!document.querySelector('canvas.cmm-keys')"), 30.0, "the 3-D view")
    left, top, width, height = page.evaluate("() => { const r = document.querySelector('canvas.cmm-keys')"
                                             ".getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; }")
    page.mouse.click(left + 0.25 * width, top + 0.5 * height)
    wait_until(lambda: page.evaluate("() => document.activeElement && document.activeElement.matches("
                                     "'canvas[data-engine]')"), 10.0, "the 3-D view taking the focus")


def typed(page: Any, label: str, value: Any, timeout: float = 30.0) -> None:
    """Wait until the station holds ``value`` in this page's field ``label`` (typed and Enter pressed): a button
    pressed before the value arrived would act on the old one (a fixed pause is a race on a loaded machine)."""
    handles = page.capp.ctx.client.gui._gui_input_handle_from_uuid

    def arrived() -> bool:
        found = [h for h in list(handles.values()) if getattr(h, "label", None) == label]
        if not found:
            raise AssertionError(f"this page has no field {label!r}")
        return any(h.value == value or (isinstance(value, float) and isinstance(h.value, (int, float))
                                        and abs(h.value - value) < 1e-9) for h in found)

    wait_until(arrived, timeout, f"{value!r} typed into {label!r} at the station")


def text_field(page: Any, label: str) -> Any:
    """A viser text field by its label (viser's text inputs are not linked to their labels, so get_by_label
    cannot find them)."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class, "
                        "'mantine-Flex-root')][1]//input").first


# The side panel's tabs, grouped for the operator's day (cmm/ui/panels.py, ClientApp.build): each top tab and the
# sub-tabs it holds (none: the tab holds its panel itself).
TABS = {
    "Machine": ("Home", "Jog", "Go to", "Probe"),
    "Align": (),
    "Measure": ("Auto-measure", "Features", "Colour map"),
    "Routine": (),
    "Report": ("Sessions", "Trends"),
    "Setup": ("Part", "Calibration", "Diagnostics"),
}


# A tab activated in the page itself, without Playwright's actionability waits (they wait for animation frames, which
# a software-rendered WebGL page on a loaded machine gives few): scrolled into view, focused, then Enter (viser's
# dock tabs activate on it) and a click (the Mantine tabs of viser's narrow layout activate on that).
ACTIVATE_TAB_JS = """t => {
  t.scrollIntoView({ block: "nearest" });
  t.focus();
  t.dispatchEvent(new KeyboardEvent("keydown", { key: "Enter", code: "Enter", bubbles: true, cancelable: true }));
  if (t.tagName === "BUTTON") t.click();
}"""


def open_tab(page: Any, top: str, sub: str | None = None, timeout: float = PAGE_WAIT_MS / 1000) -> None:
    """Open the side panel's tab ``top`` and, in it, the sub-tab ``sub``: ``open_tab(page, "Measure", "Auto-measure")``.

    Each tab is activated with the keyboard (focus, Enter) as an operator may: unlike a mouse click this cannot
    land on the sticky status bar over a scrolled panel; it is repeated until the tab reports itself selected
    (aria-selected), so a tab still being laid out on a busy machine is pressed again."""
    if top not in TABS:
        raise ValueError(f"no top tab {top!r}; the tabs are {', '.join(TABS)}")
    if sub is not None and sub not in TABS[top]:
        raise ValueError(f"the {top} tab has no sub-tab {sub!r}; it has {', '.join(TABS[top]) or 'none'}")
    end = time.monotonic() + timeout
    for name in (top, sub) if sub is not None else (top,):
        tab = page.get_by_role("tab", name=name, exact=True).first
        while True:
            try:
                if tab.get_attribute("aria-selected", timeout=5_000) == "true":
                    break
                tab.evaluate(ACTIVATE_TAB_JS, timeout=5_000)
                selected = time.monotonic() + 5.0
                while tab.get_attribute("aria-selected") != "true" and time.monotonic() < selected:
                    time.sleep(0.05)
            except Exception:  # noqa: BLE001 - playwright's TimeoutError on a busy page: try again until the deadline
                pass
            if time.monotonic() > end:
                raise AssertionError(f"the {name} tab did not open within {timeout:g} s")


# Any of the elements shown, as Playwright's is_visible judges one (a non-empty box, not hidden by style).
VISIBLE_ANY_JS = """es => es.some(e => {
  const r = e.getBoundingClientRect();
  return r.width > 0 && r.height > 0 && e.checkVisibility({ visibilityProperty: true });
})"""


def open_folder(page: Any, folder: str, field: str, timeout: float = PAGE_WAIT_MS / 1000) -> None:
    """Open the side panel's folder ``folder`` until its field labelled ``field`` (or its button ``field``) is
    visible. A panel redrawn just before (a feature chosen, a result arriving) replaces its folders, closed again; a
    click on the old one, or one on a panel that re-flowed under it, is lost, so the title is clicked again while
    the field stays hidden (never twice in 3 s: a click toggles the folder)."""
    targets = (page.get_by_label(field, exact=True), text_field(page, field),
               page.get_by_role("button", name=field, exact=True))
    shown = lambda: any(t.evaluate_all(VISIBLE_ANY_JS) for t in targets)  # noqa: E731
    end = time.monotonic() + timeout
    while not shown():
        if time.monotonic() > end:
            raise AssertionError(f"the {folder!r} folder did not show {field!r} within {timeout:g} s")
        page.get_by_text(folder, exact=True).first.evaluate("e => e.click()")
        again = time.monotonic() + 3.0
        while not shown() and time.monotonic() < again:
            time.sleep(0.05)


def top_tab_rows(page: Any) -> list[list[str]]:
    """The side panel's top tabs as laid out, one list of names per row of the tab bar: all read in one go, once
    every tab is there and two readings a quarter second apart agree (a layout still settling, read tab by tab,
    split the bar into rows it never had; a start dialog hides the tabs from the accessibility tree, not from this)."""
    def reading() -> list[list[str]] | None:
        tops = page.evaluate("""names => Object.fromEntries([...document.querySelectorAll('[role=tab]')]
            .filter(t => names.includes(t.textContent.trim()) && t.getClientRects().length)
            .map(t => [t.textContent.trim(), t.getBoundingClientRect().top]))""", list(TABS))
        if any(name not in tops for name in TABS):
            return None
        rows: dict[int, list[str]] = {}
        for name in TABS:
            rows.setdefault(round(tops[name] / 8), []).append(name)
        return [rows[k] for k in sorted(rows)]

    last, end = reading(), time.monotonic() + PAGE_WAIT_MS / 1000
    while time.monotonic() < end:
        page.wait_for_timeout(250)
        now = reading()
        if now is not None and now == last:
            return now
        last = now
    raise AssertionError("the top tabs " + ("are not all on the page" if last is None else
                                            f"did not settle (the last reading {last})") + f" in {PAGE_WAIT_MS} ms")


def press(page: Any, name: str) -> None:
    """Press the visible button ``name`` as a person would, without Playwright's wait for animation frames (a
    software-rendered WebGL page on a loaded machine gives few)."""
    button = page.get_by_role("button", name=name, exact=True)
    button.wait_for()
    button.evaluate("b => b.click()")


def press_until(page: Any, name: str, done: Any, what: str, timeout: float = 60.0, every: float = 10.0,
                press_with: Any = None) -> None:
    """Press the button ``name`` until ``done()`` holds (for idempotent actions): a press on a panel that is being
    re-drawn (a result arriving) can reach a button that is replaced a moment later and be lost. ``press_with``:
    how to press (default ``press``; ``press_on_screen`` for a tablet operator's reach)."""
    end = time.monotonic() + timeout
    while not done():
        if time.monotonic() > end:
            raise AssertionError(f"{what} did not happen within {timeout:g} s of pressing {name}")
        (press_with or press)(page, name)
        again = time.monotonic() + every
        while not done() and time.monotonic() < again:
            time.sleep(0.05)


def checkbox(page: Any, label: str) -> Any:
    """The checkbox input of the viser checkbox labelled ``label``."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class, "
                        "'mantine-Flex-root')][1]//input[@type='checkbox']").first


def tick_until(page: Any, label: str, want: bool, done: Any, what: str, timeout: float = 60.0,
               every: float = 5.0) -> None:
    """Set the checkbox ``label`` to ``want`` until ``done()`` holds at the station. A tick is a toggle, so it is
    clicked again only while the page's own box still shows the other state (a click on a panel that re-flowed, or
    one the page had not yet applied, is then repeated; one still on its way to the station is not undone)."""
    box = checkbox(page, label)
    end = time.monotonic() + timeout
    while not done():
        if time.monotonic() > end:
            raise AssertionError(f"{what} did not happen within {timeout:g} s of ticking {label!r}")
        if box.evaluate("e => e.checked") != want:
            box.evaluate("e => e.click()")
        again = time.monotonic() + every
        while not done() and time.monotonic() < again:
            time.sleep(0.05)


def start_as(page: Any, name: str, real_click: bool = False, timeout: float = 60.0) -> None:
    """Answer the start dialog ("Who is operating?") with ``name`` and Start; the station hears the name. Start is
    pressed again while the dialog still shows it and the station has not heard the name (a press during the
    dialog's opening transition was lost under load). ``real_click``: a mouse click at the button (the operator's
    reach on a tablet), not one in the page."""
    page.get_by_text("Who is operating?").filter(visible=True).first.wait_for(timeout=90_000)
    field = page.locator(".mantine-Modal-content input").first  # the dialog's one field, "Your name"
    field.wait_for(state="visible", timeout=90_000)
    wait_until(lambda: _typed(field, name), 60.0, "the name typed into the start dialog")
    start = page.get_by_role("dialog").get_by_role("button", name="Start", exact=True)
    heard = lambda: page.capp.operator == name  # noqa: E731
    end = time.monotonic() + timeout
    while not heard():
        if time.monotonic() > end:
            raise AssertionError(f"the operator's name {name!r} did not reach the station within {timeout:g} s of "
                                 f"pressing Start; {page_diagnosis(page)}")
        try:
            if start.is_visible():
                start.click(timeout=10_000) if real_click else start.evaluate("b => b.click()", timeout=10_000)
        except Exception:  # noqa: BLE001 - Playwright's error: the dialog closed between the look and the press
            pass
        again = time.monotonic() + 10.0
        while not heard() and time.monotonic() < again:
            time.sleep(0.05)
    page.get_by_text("Who is operating?").wait_for(state="hidden")


def _typed(field: Any, text: str) -> bool:
    try:
        field.fill(text, timeout=5_000)
        return field.input_value(timeout=5_000) == text
    except Exception:  # noqa: BLE001 - the dialog's opening transition on a busy page: type again
        return False


def enter_sphere_certificate(page: Any, diameter: float, serial: str, uncertainty_um: float) -> None:
    """Setup > Calibration: the reference sphere's certificate typed in its folder and saved."""
    open_tab(page, "Setup", "Calibration")
    open_folder(page, "Reference sphere certificate", "Diameter (mm)")
    panel = page.capp.calibration.gui

    def at_station() -> bool:
        return (round(panel["cert_diameter"].value, 6), panel["cert_serial"].value,
                round(panel["cert_uncertainty"].value, 6)) == (diameter, serial, uncertainty_um)
    end = time.monotonic() + 90.0
    while not at_station():  # typed again while the station has not heard it (a field still being laid out)
        if time.monotonic() > end:
            raise AssertionError("the typed certificate did not reach the station within 90 s")
        page.get_by_label("Diameter (mm)", exact=True).fill(f"{diameter}")
        page.get_by_label("Diameter (mm)", exact=True).press("Enter")
        text_field(page, "Serial").fill(serial)
        text_field(page, "Serial").press("Enter")
        page.get_by_label("U k=2 (um)", exact=True).fill(f"{uncertainty_um}")
        page.get_by_label("U k=2 (um)", exact=True).press("Enter")
        again = time.monotonic() + 15.0
        while not at_station() and time.monotonic() < again:
            time.sleep(0.05)
    press(page, "Save certificate")
    shows(page, serial)



def stop_time(station, since: float, what: str, limit: float = 2.0) -> float:
    """Simulated seconds from ``since`` (the station's clock, ``station.machine.state.time``) until every axis stands still.

    The station runs on the simulator's paced virtual clock, so a busy test machine slows the simulated
    machine down with everything else instead of making a stop look late.
    """
    wall_end = time.monotonic() + 60
    while time.monotonic() < wall_end:
        state = station.machine.state
        if max(abs(a.velocity) for a in state.axes) < 1e-9:
            return state.time - since
        if state.time - since > limit:
            break
        time.sleep(0.005)
    raise AssertionError(f"{what} did not happen within {limit} s of machine time")


def wait_until(predicate, timeout: float, what: str, poll: float = 0.005, why=None) -> float:
    """Seconds until ``predicate()`` holds (asked every ``poll`` s); AssertionError naming ``what`` (and what
    ``why()`` says then) after ``timeout`` s."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what} did not happen within {timeout} s" + (f": {why()}" if why else ""))
        time.sleep(poll)
    return time.monotonic() - start


# the check so a re-layout cannot come between. Returns why it could not be pressed, or "" once pressed.
PRESS_ON_SCREEN_JS = """b => {
  let why = "";
  for (const block of ["nearest", "center"]) {
    b.scrollIntoView({ block, inline: "nearest" });
    const r = b.getBoundingClientRect();
    if (r.width < 1 || r.height < 1) { why = "it has no size"; continue; }
    if (r.left < 0 || r.top < 0 || r.right > window.innerWidth + 0.5 || r.bottom > window.innerHeight + 0.5) {
      why = `off-screen at (${r.left.toFixed(0)}, ${r.top.toFixed(0)})-(${r.right.toFixed(0)}, ${r.bottom.toFixed(0)}) `
        + `in a ${window.innerWidth} x ${window.innerHeight} viewport`;
      continue;
    }
    const top = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
    if (!top || !(top === b || b.contains(top))) {
      why = `covered at its centre by ${top ? top.outerHTML.slice(0, 160) : "nothing"}`;
      continue;
    }
    b.click();
    return "";
  }
  return why;
}"""


def press_on_screen(page: Any, name: str, timeout: float = 60.0) -> None:
    """Press the button ``name`` as an operator at this page's size can: scrolled into view, inside the viewport and
    not covered (see PRESS_ON_SCREEN_JS); tried again while it is not (a toast over it, a panel being laid out) and
    AssertionError with the reason after ``timeout`` s. Unlike ``press`` this fails on a button out of reach."""
    button = page.get_by_role("button", name=name, exact=True)
    button.wait_for(timeout=PAGE_WAIT_MS)
    end = time.monotonic() + timeout
    while True:
        try:
            why = button.evaluate(PRESS_ON_SCREEN_JS, timeout=10_000)
        except Exception as e:  # noqa: BLE001 - the button replaced while the panel was re-drawn: try again
            why = f"not pressed ({type(e).__name__})"
        if not why:
            return
        if time.monotonic() > end:
            raise AssertionError(f"the {name!r} button is out of the operator's reach: {why}")
        time.sleep(0.25)




# Where a finger on button ``b`` goes: its centre, scrolled into view if it is not, when it is inside the viewport and
# on top there (not under the status bar, a toast or another panel); null while it is not.
ON_TOP_CENTRE_JS = """b => {
  b.scrollIntoView({ block: "nearest", inline: "nearest" });
  const r = b.getBoundingClientRect();
  if (r.width < 1 || r.height < 1 || r.left < 0 || r.top < 0 || r.right > window.innerWidth + 0.5
      || r.bottom > window.innerHeight + 0.5) return null;
  const x = r.left + r.width / 2, y = r.top + r.height / 2;
  const top = document.elementFromPoint(x, y);
  return top && (top === b || b.contains(top)) ? [x, y] : null;
}"""


def finger_over(page: Any, name: str, timeout: float = 60.0, steady_s: float = 0.3) -> tuple[float, float]:
    """The mouse moved over the centre of the button ``name`` once it is on top there and has stayed at that place
    for ``steady_s`` s: a panel that is still being laid out (a status line that grows, the armed jog's note, a
    toast) moves a button from under a pointer placed on its first box, and the press then lands on nothing.
    Returns the point; AssertionError with the last reason after ``timeout`` s."""
    button = page.get_by_role("button", name=name, exact=True)
    button.wait_for(timeout=PAGE_WAIT_MS)
    end, last = time.monotonic() + timeout, None
    while True:
        try:
            at = button.evaluate(ON_TOP_CENTRE_JS, timeout=10_000)
        except Exception:  # noqa: BLE001 - the button replaced while its panel was re-drawn: look again
            at = None
        if at is not None and last is not None and max(abs(at[0] - last[0]), abs(at[1] - last[1])) < 0.5:
            page.mouse.move(at[0], at[1])
            return float(at[0]), float(at[1])
        if time.monotonic() > end:
            raise AssertionError(f"the {name!r} button never stood still on top of the page: {last} then {at}")
        last = at
        time.sleep(steady_s)
