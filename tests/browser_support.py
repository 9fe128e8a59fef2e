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
                viewport={"width": viewport[0], "height": viewport[1]}, timeout=30_000, **options)
            context.set_default_timeout(30_000)  # software WebGL on a loaded 2-core machine is slow
            try:
                yield context
            finally:
                context.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def screenshot(page: Any, name: str, **options: Any) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    options.setdefault("timeout", 60_000)  # waits for fonts and a WebGL frame: slow when the machine is busy
    page.screenshot(path=str(path), **options)
    return path


from netutil import SIM, free_port  # noqa: E402,F401 - free_port re-exported for the browser tests


def sim_station(tmp_path_factory: Any, session: str) -> Iterator[Any]:
    """A homed station on the simulator recording ``session``; a module fixture's body:
    ``yield from bs.sim_station(tmp_path_factory, "walk")`` (closed after the module)."""
    from cmm.station import Station

    st = Station(port=SIM, session_dir=tmp_path_factory.mktemp(f"{session}-sessions")).start(session, home=True)
    yield st
    st.close()


def station_app(station: Any, **options: Any) -> Iterator[Any]:
    """The station's web UI on a free 127.0.0.1 port (``options``: StationApp's, e.g. ``pendant=False``);
    a module fixture's body: ``yield from bs.station_app(station, ...)`` (closed after the module)."""
    from cmm.ui.app import StationApp

    options.setdefault("ask_name", False)  # no start dialog over the page unless the test is about it
    ui = StationApp(station, host="127.0.0.1", port=free_port(), **options)
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


def open_page(context: Any, app: Any) -> Any:
    """A new page on the station app with its viser client: ``page.capp`` is the tab's ClientApp, ``page.log``
    the console errors and failed requests it saw."""
    before = set(app.clients)
    page = context.new_page()
    page.log = PageLog()
    page.log.attach(page)
    page.goto(app.url)
    page.get_by_role("button", name="E-STOP").wait_for(timeout=30_000)
    wait_until(lambda: set(app.clients) - before, 10.0, "the page's viser client")
    (cid,) = set(app.clients) - before
    page.capp = app.clients[cid]
    return page


def text_field(page: Any, label: str) -> Any:
    """A viser text field by its label (viser's text inputs are not linked to their labels, so get_by_label
    cannot find them)."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class, "
                        "'mantine-Flex-root')][1]//input").first


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


def wait_until(predicate, timeout: float, what: str) -> float:
    """Seconds until ``predicate()`` holds; AssertionError naming ``what`` after ``timeout`` s."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what} did not happen within {timeout} s")
        time.sleep(0.005)
    return time.monotonic() - start
