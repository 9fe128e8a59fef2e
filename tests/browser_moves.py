"""The operator's hands on the machine through the page, for the browser tests: picks on the part, Go to, a
jog held until the probe touches, a routine's manual 3-2-1 hits taken by jog, and ``JogRecord`` (what a held jog
did, judged on the machine's own clock). The page itself (opening it, tabs, buttons, waits) is browser_support's.
"""

from __future__ import annotations

import bisect
import time
from typing import Any

import numpy as np

from browser_support import finger_over, open_tab, press, screenshot, shows, text_field, tick_until, wait_until


def part_point(station: Any, local: Any) -> Any:
    """A point of the part (part coordinates) in machine coordinates, where the station believes the part is."""
    import numpy as np

    pose = station.measurement.part.pose
    return pose[:3, :3] @ np.asarray(local, float) + pose[:3, 3]


def pick_ray(page: Any, station: Any, origin: Any, direction: Any) -> None:
    """The pick a click on the part sends: a ray (part coordinates) from ``origin`` along ``direction``."""
    import numpy as np

    pose = station.measurement.part.pose
    assert page.capp.pick(part_point(station, origin), pose[:3, :3] @ np.asarray(direction, float)) is not None


def pick_face(page: Any, station: Any, local_point: Any, outward: Any) -> None:
    """The pick a click on the face at ``local_point`` sends (a ray from outside along the face normal)."""
    import numpy as np

    n = np.asarray(outward, float)
    pick_ray(page, station, np.asarray(local_point, float) + 40 * n, -n)


def automeasure_in_page(page: Any, station: Any, hits_per_ring: int, proposal: str | None = None,
                        name: str | None = None, shot: str | None = None) -> tuple[Any, Any]:
    """Auto-measure what was picked, through Measure > Auto-measure: the hits per ring typed, Plan (the proposal
    and its path shown), the feature's name typed, Run (measured and fitted against its CAD nominal)."""
    open_tab(page, "Measure", "Auto-measure")
    page.get_by_label("Hits (per ring)", exact=True).fill(str(hits_per_ring))
    page.get_by_label("Hits (per ring)", exact=True).press("Enter")
    wait_until(lambda: page.capp.measure.gui["hits"].value == hits_per_ring, 30.0, "the typed hits per ring")
    before_plan = page.capp.measure.plan
    press(page, "Plan")
    wait_until(lambda: page.capp.measure.plan is not None and page.capp.measure.plan is not before_plan, 60.0,
               f"the plan ({page.capp.messages[-1:]})")
    if proposal:
        shows(page, proposal)  # the proposed feature and its pattern of hits
    plan = page.capp.measure.plan
    shows(page, f"{len(plan)} hits · clearance plane")
    if name:
        text_field(page, "Feature name").fill(name)
        wait_until(lambda: page.capp.measure.gui["name"].value == name, 30.0, "the typed name at the station")
    if shot:
        screenshot(page, shot)
    before = set(station.measurement.features)
    press(page, "Run")
    wait_until(lambda: set(station.measurement.features) - before, 180.0, f"the auto-measured {name or proposal}")
    (fid,) = set(station.measurement.features) - before
    feature = station.measurement.features[fid]
    assert len(feature.hit_ids) == len(plan)
    if name:
        assert feature.name == name
    return plan, feature


# The sample part's manual 3-2-1 hits (part coordinates: point, approach direction): 3 on the top face (TOP),
# 2 on the front face (FRONT), 1 on the left face (LEFT), as a routine taught on those planes prompts for them.
SAMPLE_321_HITS = [((15.0, 10.0, 40.0), (0, 0, -1)), ((105.0, 12.0, 40.0), (0, 0, -1)), ((50.0, 70.0, 40.0), (0, 0, -1)),
                   ((15.0, 0.0, 15.0), (0, 1, 0)), ((105.0, 0.0, 15.0), (0, 1, 0)), ((0.0, 20.0, 15.0), (1, 0, 0))]


AXES = "XYZ"
JOG_GAP_MM = 0.8  # how far from the surface (probe tip to surface) the operator starts a hand hit's jog (each mm
# is half a second of machine time at the probing speed, 1.25 s of wall time at HAND_PACE)


def go_to_in_page(page: Any, station: Any, target: Any, timeout: float = 120.0) -> None:
    """Machine > Go to: the Machine frame chosen, ``target`` (machine mm) typed into "Target, machine (mm)" and Go
    pressed, as an operator positions the probe; returns once the machine stands there."""
    target = np.asarray(target, float)
    open_tab(page, "Machine", "Go to")
    panel = page.capp
    end = time.monotonic() + 60.0
    while panel.goto_frame != "Machine":  # the Frame buttons' "Machine" (the status bar's DRO has one too)
        if time.monotonic() > end:
            raise AssertionError("the Go to tab's frame did not become Machine within 60 s")
        page.get_by_role("button", name="Machine", exact=True).last.evaluate("b => b.click()")
        time.sleep(0.5)
    fields = page.locator("xpath=//label[normalize-space()='Target, machine (mm)']/ancestor::div[contains(@class, "
                          "'mantine-Flex-root')][1]//input")
    fields.nth(2).wait_for()

    def typed() -> bool:
        return np.allclose(np.asarray(panel.gui["target"].value, float), target, atol=5e-4)
    end = time.monotonic() + 60.0
    while not typed():  # typed again while the station has not heard it (a field being laid out, redrawn)
        if time.monotonic() > end:
            raise AssertionError(f"the typed target {target.round(3).tolist()} did not reach the station "
                                 f"(it has {panel.gui['target'].value})")
        for i in range(3):  # only the coordinates that differ from the field's (each typed costs the page a redraw)
            if abs(float(panel.gui["target"].value[i]) - target[i]) > 5e-4:
                fields.nth(i).fill(f"{target[i]:.3f}")
                fields.nth(i).press("Tab")
        again = time.monotonic() + 5.0
        while not typed() and time.monotonic() < again:
            time.sleep(0.05)
    wait_until(lambda: station.controller.state.mode.value == "idle", 60.0, "the machine idle before Go")
    press(page, "Go")
    wait_until(lambda: (np.allclose(station.machine.state.position, target, atol=0.01)
                        and station.controller.state.mode.value == "idle"), timeout,
               f"the move to {target.round(3).tolist()}", poll=0.02,
               why=lambda: f"at {station.machine.state.position.round(3).tolist()}, {page.capp.messages[-2:]}")


HAND_PACE = 0.4  # simulated s per wall s while the page holds a jog button: the page's hold events, late on a
# loaded machine, still come within the dead-man (0.15 s of machine time), so the jog is rarely cut short


def jog_to_touch(page: Any, station: Any, axis: int, sign: int, timeout: float = 120.0,
                 beyond: float | None = None) -> int:
    """Machine > Jog (the armed jog ticked): the page's jog button for ``axis`` toward ``sign`` held with the mouse
    until the probe touches and the station records a manual hit (its id). The simulator's clock runs at HAND_PACE
    only while a button is held, and at its previous pace again after. A jog the dead-man ended (a late hold on a
    loaded machine) is held again, as an operator presses again; a touch while such a jog braked is a contact, not
    a hit, and the station refuses a jog on into the part ("jog away from the part"): the operator jogs off the
    surface first (the opposite button, until the probe is free), then on again. ``beyond`` (machine mm along the
    axis): where the probe is past the surface without a touch; the helper lets go there and fails (a real machine
    would crash)."""
    model = station.measurement
    before = max(model.hits, default=0)
    open_tab(page, "Machine", "Jog")
    network = station.sim.network
    pace = network.pace
    end = time.monotonic() + timeout

    def hold(way: int, until: Any) -> None:
        """Hold the button toward ``way`` until ``until()`` or the jog stood still a machine second (dead-man)."""
        finger_over(page, f"hold {AXES[axis]} {'+' if way > 0 else '−'}")
        network.set_pace(HAND_PACE)
        try:
            page.mouse.down()
            try:
                started, still_since = time.monotonic(), None
                while not until() and time.monotonic() < end:
                    if beyond is not None and sign * (station.machine.state.position[axis] - beyond) > 0:
                        raise AssertionError(
                            f"the probe passed the surface ({AXES[axis]} {beyond:.3f}) without a touch, at "
                            f"{station.machine.state.position.round(3).tolist()} (told {page.capp.messages[-3:]})")
                    state = station.machine.state
                    if state.jogging or max(abs(a.velocity) for a in state.axes) > 1e-9:
                        still_since = None
                    elif time.monotonic() - started > 5.0:
                        still_since = still_since or time.monotonic()
                        if time.monotonic() - still_since > 1.0:
                            break
                    time.sleep(0.02)
            finally:
                page.mouse.up()
        finally:
            network.set_pace(pace)

    touched = lambda: max(model.hits, default=0) > before  # noqa: E731
    while not touched():
        if time.monotonic() > end:
            raise AssertionError(f"no manual hit within {timeout:g} s of holding {AXES[axis]} "
                                 f"{'+' if sign > 0 else '-'} (at {station.machine.state.position.round(3).tolist()}; "
                                 f"told {page.capp.messages[-3:]})")
        if station.machine.state.probe_triggered:  # a contact without a hit: off the surface first
            wait_until(lambda: not station.machine.state.jogging, 60.0, "the jog's end at the contact")
            hold(-sign, lambda: not station.machine.state.probe_triggered)
            continue
        hold(sign, touched)
    # the touch's hit: the first after ``before`` (the routine may go on probing by itself after the last one)
    hit = min(h for h in model.hits if h > before)
    wait_until(lambda: not station.machine.state.jogging, 60.0, "the jog's end at the touch")
    return hit


def manual_321_by_jog(page: Any, station: Any, pose: Any, hits: list[tuple[Any, Any]],
                      prompts: dict[int, str]) -> list[int]:
    """The operator's hands at a routine's manual 3-2-1, through the page only: Machine > Jog, "Manual probing
    (armed jog)" ticked; for each prompted hit (part coordinates ``hits``: point, approach direction, where the part
    really stands: ``pose``), after the prompt ``prompts[k]`` shows in the Routine tab, the probe brought
    ``JOG_GAP_MM`` from the surface with Go to (typed machine target) and the jog button of the machine axis
    closest to the approach held until the probe touches: the station's manual hit, which the routine takes. The
    probe starts on that axis's line through the prompted point, so the jog touches the surface there (on a face
    not square to the axis, within the stylus radius times the tilt). Then the jog unarmed and the Routine tab
    shown again. The ids of the hits taken."""
    model = station.measurement
    radius = station.controller.probe_settings.tip_radius
    taken: list[int] = []
    for k, (p, u) in enumerate(hits):
        if k in prompts:
            open_tab(page, "Routine")
            page.get_by_text(prompts[k]).filter(visible=True).first.wait_for(timeout=120_000)
        if not page.capp.ctx.manual_probe:
            open_tab(page, "Machine", "Jog")
            tick_until(page, "Manual probing (armed jog)", True, lambda: page.capp.ctx.manual_probe,
                       "the armed jog ticked")
        point = (pose @ np.array([*p, 1.0]))[:3]
        approach = pose[:3, :3] @ np.array(u, float)
        axis = int(np.argmax(np.abs(approach)))
        sign = 1 if approach[axis] > 0 else -1
        along = np.zeros(3)
        along[axis] = sign
        go_to_in_page(page, station, point - (radius + JOG_GAP_MM) * along)
        hit = jog_to_touch(page, station, axis, sign, beyond=point[axis] + sign * 1.0)
        assert model.hits[hit].mode == "manual", model.hits[hit]
        taken.append(hit)
    tick_until(page, "Manual probing (armed jog)", False, lambda: not page.capp.ctx.manual_probe,
               "the armed jog unticked")  # the jog unarmed again (still on the Jog tab)
    open_tab(page, "Routine")  # back to the routine, which runs on by itself
    return taken


def assert_taken_by_jog(station: Any, session: Any, taken: list[int]) -> None:
    """The routine's manual 3-2-1 in ``session``'s journal was made from the hits ``taken`` (manual_321_by_jog's):
    each recorded as a manual hit, approached along one machine axis (the page's jog, not a programmed probe along
    the face normal) at the qualified probing speed (the armed jog's clamp)."""
    from cmm.journal.writer import read_events

    events = read_events(session).events
    aligned = [e for e in events if e["kind"] == "alignment" and e.get("method") == "3-2-1 manual"]
    assert len(aligned) == 1 and list(aligned[0]["hit_ids"]) == list(taken), (aligned, taken)
    recorded = {e["id"]: e for e in events if e["kind"] == "hit"}
    qualified = float(station.calibration.qualified_probing_speed)
    for h in taken:
        hit = station.measurement.hits[h]
        assert recorded[h].get("mode") == "manual" and hit.mode == "manual", recorded[h]
        assert np.count_nonzero(np.round(hit.approach, 9)) == 1, hit.approach  # along one machine axis: the jog
        assert abs(hit.speed - qualified) < 1e-9 * qualified, (hit.speed, qualified)



WINDOW = 0.2  # s of machine time over which a held jog's speed is judged (position over the machine's clock)


class JogRecord:
    """What the machine did while the page held a jog, on the machine's own clock: every state its loop polled
    (time, X, Y, Z, largest axis speed), the machine time of each jog refresh the machine took (``Machine.jog``,
    what restarts its dead-man: a hold the pipeline passed on), of each release that reached the station's jog
    pipeline, and of each dead-man stop. Nothing here depends on when this test's thread runs: the events are
    stamped as they arrive, the states as the machine loop reads them."""

    def __init__(self, station, capp=None):
        self.station = station
        self.trace: list[tuple[float, float, float, float, float]] = []
        self.holds: list[float] = []
        self.heard: list[float] = []  # each of those holds' own stamp: when its front end heard it (the dead-man's start)
        self.velocities: list[np.ndarray] = []  # and the velocity each asked for (mm/s)
        self.releases: list[float] = []
        self.deadman: list[float] = []
        self.clicks: list[float] = []  # the page's own release (viser's click event on the button)
        self.stops: list[float] = []  # each STOP that reached the control core
        self.live = True
        jogs = station.controller.jogs
        machine = station.machine
        self._jogs, self._machine, self._jog, self._release = jogs, machine, machine.jog, jogs.release
        now = lambda: machine.state.time  # noqa: E731
        machine.jog = lambda v, **kw: (self._took(now(), v, kw.get("heard")), self._jog(v, **kw))[1]
        jogs.release = lambda *a, **kw: (self.releases.append(now()), self._release(*a, **kw))[1]
        # every STOP goes through the core's press (the stop verb, and the pendant's own thread as the press arrives)
        self._controller, self._press = station.controller, station.controller.press
        station.controller.press = lambda client, verb, *a, **kw: (
            self.stops.append(now()) if verb == "stop" else None, self._press(client, verb, *a, **kw))[1]
        self._capp = capp
        if capp is not None:
            click = capp.jog_release
            capp.jog_release = lambda: (self.clicks.append(now()), click())[1]
        station.measurement.subscribe(
            lambda kind, info: self.deadman.append(now()) if kind == "deadman" and self.live else None)
        self._unsubscribe = station.machine.subscribe(
            lambda s: self.trace.append((s.time, *s.position, max(abs(a.velocity) for a in s.axes))))

    def _took(self, t: float, v: Any, heard: float | None) -> None:
        self.holds.append(t)
        self.heard.append(t if heard is None else min(float(heard), t))
        self.velocities.append(np.array(v, dtype=float))

    def first_hold(self, asks: Any) -> float | None:
        """Machine time the machine first took a hold whose velocity (mm/s) ``asks(v)`` is true of, if it has yet."""
        return next((t for t, v in zip(self.holds, self.velocities) if asks(v)), None)

    def close(self) -> None:
        self.live = False
        del self._machine.jog  # the class's method again
        self._jogs.release = self._release
        del self._controller.press  # the class's method again
        if self._capp is not None:
            del self._capp.jog_release  # the class's method again
        self._unsubscribe()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(machine times, positions (n x 3), largest axis speed) of the polled states so far."""
        a = np.array(self.trace)
        return a[:, 0], a[:, 1:4], a[:, 4]

    def bridged(self, a: float, b: float) -> bool:
        """The page's holds kept the jog live from 0.3 s before ``a`` (its acceleration) to ``b``: every gap between
        hold arrivals (and to ``b``) shorter than the dead-man, and no dead-man stop or release since (the page's
        hold refresher lets go by itself when the page's main thread is frozen for a second)."""
        holds = np.sort(np.array(self.holds))
        before = holds[holds <= a - 0.3]
        if not len(before) or any(before[-1] <= e <= b for e in self.deadman + self.releases):
            return False
        chain = np.concatenate([[before[-1]], holds[(holds > a - 0.3) & (holds < b)], [b]])
        return bool(np.diff(chain).max() < self.station.config.deadman_timeout - 0.02)

    def live_speeds(self, axis: int, since: float, until: float | None = None) -> list[float]:
        """Speeds (mm/s, position over machine time) of ``axis`` in the WINDOW-long windows from ``since`` to
        ``until`` (the last polled state) in which the page's holds kept the jog live."""
        t, pos, _v = self.arrays()
        end = t[-1] if until is None else until
        return [abs(np.interp(w + WINDOW, t, pos[:, axis]) - np.interp(w, t, pos[:, axis])) / WINDOW
                for w in np.arange(since, end - WINDOW, WINDOW / 2) if self.bridged(w, w + WINDOW)]

    def summary(self) -> str:
        """What the page sent and the machine did, for a failure's message."""
        holds = np.diff(np.sort(np.array(self.holds))) if len(self.holds) > 1 else np.array([0.0])
        span = (self.trace[-1][0] - self.trace[0][0]) if self.trace else 0.0
        return (f"{len(self.holds)} holds in {span:.2f} s of machine time (gaps: median {np.median(holds):.3f} s, "
                f"largest {holds.max():.3f} s), dead-man stops at {np.round(self.deadman, 2).tolist()}, releases at "
                f"{np.round(self.releases, 2).tolist()}")

    def _standstill(self, since: float) -> float | None:
        """Machine time of the first polled state at or after ``since`` with every axis at rest, if any yet."""
        first = bisect.bisect_left(self.trace, since, key=lambda row: row[0])
        return next((row[0] for row in self.trace[first:] if row[4] < 1e-9), None)

    def standstill_after(self, since: float, what: str) -> float:
        """Machine seconds from ``since`` (machine time) to the first polled state at or after it with every axis at
        rest (waits for it)."""
        wait_until(lambda: self._standstill(since) is not None, 60.0, f"the stop after {what}")
        return self._standstill(since) - since

    def stop_after_release(self, since: float, what: str) -> tuple[float, float, float]:
        """After the button was let go at machine time ``since``: (machine time the first release reached the
        pipeline, machine seconds from it to zero velocity, machine time of the standstill after the last release).
        With ``capp`` (a viser page's ClientApp) waits for the page's own release (viser's click event): the hold
        refresher's release may come first."""
        wait_until(lambda: (self.clicks or self._capp is None) and any(r >= since for r in self.releases), 60.0,
                      f"the page's release ({what}) reaching the station")
        released = min(r for r in self.releases if r >= since)
        wait_until(lambda: self._standstill(max(self.releases)) is not None, 60.0, f"the stop after {what}")
        return released, self._standstill(released) - released, self._standstill(max(self.releases))


# A button pressed only where an operator could press it: scrolled into view (first as little as needed, then to the
# middle of its scroll box, as a hand scrolls a button out from under the sticky status bar), inside the viewport
# and on top at its centre (not under the status bar, a toast or another panel); then clicked, in the same task as
