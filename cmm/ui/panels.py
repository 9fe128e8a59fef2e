"""One client's GUI: panels built declaratively, short callbacks, state kept outside the widgets.

:class:`ClientApp` is one browser tab: it builds the tab's panels (each a class of its own with its state and its
actions as plain methods: the machine's commands, Go to and pick in :mod:`.panel_machine`, the jog in
:mod:`.panel_jog`, the operator and the control in :mod:`.panel_operator`, the Diagnostics in
:mod:`.panel_diagnostics`, the Align, Measure, Routine, Report and Setup tabs in theirs), lays them out in the
side panel's tabs (``build()``), subscribes to the API's queries its status bar and its plain read-outs draw from
(``subscribe()``: each delivery redraws them; ``close()`` when the tab goes) and copies what the other queries say
into their read-outs a few times a second (``refresh()``). The tab's actions stay reachable on the tab (``go_to``, ``jog_hold``, ``pick``, ``take_control``
...), so the tests drive exactly what a button does without a browser.

Machine commands go to the command API (:mod:`cmm.api`) as this client
(:meth:`~cmm.ui.context.PanelContext.who`): the core checks the access policy (the shared
:class:`~cmm.control.access.Control`, STOP and E-stop by its one :meth:`~cmm.control.access.Control.may_stop`
policy) and the machine state once, and refuses with a sentence that is shown here. Measurement changes (hits,
features, sessions) ask :meth:`~cmm.ui.context.PanelContext.allowed` first (a server-side check: hiding buttons is
not security). Jog buttons feed the core's jog-hold pipeline (:mod:`cmm.control.jog`).
"""

from __future__ import annotations

from typing import Any, Callable

from .context import PanelContext
from .feed import Feed
from .panel_align import AlignPanel
from .panel_calibration import CalibrationPanel
from .panel_colour_map import ColourMapPanel
from .panel_diagnostics import DiagnosticsPanel
from .panel_features import FeaturesPanel
from .panel_jog import JogPanel, hold_worker_script
from .panel_machine import MachinePanel, machine_markdown, probe_markdown, send_verb
from .panel_measure import MeasurePanel
from .panel_operator import OperatorPanel
from .panel_part import PartPanel
from .panel_routine import RoutinePanel
from .panel_sessions import SessionsPanel
from .panel_status import StatusPanel
from .panel_trends import TrendsPanel

__all__ = ["ClientApp", "hold_worker_script", "machine_markdown", "probe_markdown"]

# the read-outs that are plain snapshots, on a subscription of their own at the read-outs' rate: Machine > Probe's
# data and Setup > Part's text (the part and, on the simulator, where it truly lies)
READOUT_QUERIES: dict[str, dict[str, Any]] = {"probe_data": {}, "part": {}, "simulator": {}}
READOUT_RATE = 5.0

# The tab strips a little tighter than viser's (0.9em a side) so the six top tabs fit one row of the wide panel;
# dock tabs (laptop) and Mantine tabs (viser's narrow-screen layout) alike.
TABS_CSS = """<style>
[role=tablist] > [data-dock-tab] { padding: 0 0.6em !important; }
.mantine-Tabs-tab { padding-left: 0.6em !important; padding-right: 0.6em !important; }
</style>"""


def _on(panel: str, name: str, *, settable: bool = False) -> property:
    """An action or a state of one of the tab's panels, reached on the tab (``capp.go_to`` is the machine panel's)."""
    def get(self: Any) -> Any:
        return getattr(getattr(self, panel), name)

    def put(self: Any, value: Any) -> None:
        setattr(getattr(self, panel), name, value)

    def drop(self: Any) -> None:  # a wrapper set on the panel's instance goes: the class's method again
        delattr(getattr(self, panel), name)
    return property(get, put if settable else None, drop if settable else None, doc=f"The {panel} panel's ``{name}``.")


class ClientApp:
    """One browser client (or a test standing in for one)."""

    def __init__(self, app: Any, client: Any = None, *, client_id: str | None = None,
                 is_local: bool = False) -> None:
        self.app = app
        self.control = app.control
        self.client = client
        self.client_id = client_id or (f"viser-{client.client_id}" if client is not None else "test")
        self.is_local = is_local
        # what this tab's panels share (selection, messages, widgets, the control check); they get it, not the tab
        self.ctx = PanelContext(app.api, app.control, app.view, client, client_id=self.client_id,
                                is_local=is_local, deviations=app.deviations, shared=app.shared)
        self.messages = self.ctx.messages  # (level, title, body): what the operator was told
        self.gui = self.ctx.gui
        self.jog = JogPanel(self.ctx, app, client, lambda *a, **kw: send_verb(self.ctx, *a, **kw))
        self.machine = MachinePanel(self.ctx, app, client, self.jog)
        self.operator_panel = OperatorPanel(self.ctx, app, client, is_local=is_local, jog_release=self.jog.jog_release)
        self.diagnostics = DiagnosticsPanel(self.ctx, app)
        self.ctx.stop, self.ctx.emergency_stop = self.machine.stop, self.machine.emergency_stop
        self.ctx.select_feature = self.select_feature
        self.ctx.clear_pick = self.machine.clear_pick
        self.sessions = SessionsPanel(self.ctx)
        self.calibration = CalibrationPanel(self.ctx)
        self.status = StatusPanel(self.ctx)
        self.features = FeaturesPanel(self.ctx)
        self.align = AlignPanel(self.ctx)
        self.measure = MeasurePanel(self.ctx)
        self.part = PartPanel(self.ctx)
        self.routine = RoutinePanel(self.ctx)
        self.routine.align = self.align  # a routine's manual alignment is prompted by the Align tab's wizard
        self.colour_map = ColourMapPanel(self.ctx)
        self.trends = TrendsPanel(self.ctx)
        self.ctx.show_frame = self.status.set_frame
        self.ctx.frame_shown = self.machine.set_goto_frame
        self._closed = False  # the tab went: its subscriptions are closed (and none is opened any more)

    @property
    def api(self) -> Any:
        """The command API: every machine command goes there with this client's id."""
        return self.ctx.api

    # the machine's commands, Go to, pick and hits (Machine > Home, Go to, Probe)
    stop = _on("machine", "stop")
    emergency_stop = _on("machine", "emergency_stop")
    reset = _on("machine", "reset")
    reconnect = _on("machine", "reconnect")
    home = _on("machine", "home")
    zero = _on("machine", "zero")
    go_to = _on("machine", "go_to")
    set_goto_frame = _on("machine", "set_goto_frame")
    target_label = _on("machine", "target_label")
    goto_frame_text = _on("machine", "goto_frame_text")
    cancel = _on("machine", "cancel")
    pick = _on("machine", "pick")
    clear_pick = _on("machine", "clear_pick")
    on_scene_click = _on("machine", "on_scene_click")
    move_above = _on("machine", "move_above")
    probe_here = _on("machine", "probe_here")
    delete_hit = _on("machine", "delete_hit")
    undo = _on("machine", "undo")
    goto_frame = _on("machine", "goto_frame", settable=True)
    move_status = _on("machine", "move_status", settable=True)
    # the jog (Machine > Jog)
    jog_velocity = _on("jog", "jog_velocity")
    jog_hold = _on("jog", "jog_hold")
    hold_velocity = _on("jog", "hold_velocity")
    keys_velocity = _on("jog", "keys_velocity")
    jog_release = _on("jog", "jog_release", settable=True)  # a test may wrap it to see the page's release
    step = _on("jog", "step")
    set_manual_probe = _on("jog", "set_manual_probe")
    station_probing_speed = _on("jog", "station_probing_speed")
    speed_mode = _on("jog", "speed_mode", settable=True)
    step_size = _on("jog", "step_size", settable=True)
    _jogging = _on("jog", "_jogging", settable=True)
    pendant_token = _on("jog", "pendant_token", settable=True)
    hold_token = _on("jog", "hold_token", settable=True)
    # the operator and the control
    peer = _on("operator_panel", "peer")
    take_control = _on("operator_panel", "take_control")
    operator = _on("operator_panel", "operator")
    set_operator = _on("operator_panel", "set_operator")
    log_in = _on("operator_panel", "log_in")
    users_action = _on("operator_panel", "users_action")
    set_lan_stop = _on("operator_panel", "set_lan_stop")
    release_control = _on("operator_panel", "release_control")
    watch_control = _on("operator_panel", "watch_control")
    # Setup > Diagnostics
    live_trace = _on("diagnostics", "live_trace", settable=True)
    _show_trace = _on("diagnostics", "show_trace")

    def select_feature(self, fid: int) -> None:
        """Select a feature in every panel of this tab and in the 3-D view."""
        self.ctx.selected_feature = fid
        self.app.view.select_feature(fid)
        self.refresh()

    # --- GUI ---------------------------------------------------------------------------------------

    def subscribe(self) -> None:
        """Follow the station through the API's subscriptions as this tab: the status bar and the DRO at 20 Hz, the
        read-outs that are plain snapshots (the probe's data, the part) at 5 Hz; ``close()`` ends them."""
        if self._closed:  # the tab went while it was being built
            return

        def failed(what: str) -> Callable[[str, str], None]:
            return lambda query, message: self.app.refresh_failed(f"tab {self.client_id} {what} ({query})", message)
        self.status.subscribe(failed("status bar"))
        self.ctx.readouts = Feed(self.ctx.api, self.ctx.who(), READOUT_QUERIES, READOUT_RATE, self._readouts,
                                 failed("read-outs"))

    def _readouts(self, snapshot: dict[str, Any]) -> None:
        self.machine.show_probe(snapshot)
        self.part.show(snapshot)

    def close(self) -> None:
        """The tab went (or the page closes): its subscriptions end."""
        self._closed = True
        self.status.close()
        if self.ctx.readouts is not None:
            self.ctx.readouts.close()

    def build(self) -> None:
        """Create this client's widgets: each panel builds its own, here they are laid out in the tabs."""
        gui = self.client.gui
        self.subscribe()
        # first, and sticky: state, holder, DRO, link, probe, STOP / E-STOP, Take control / Release always on screen
        self.status.build(gui, controls=self.operator_panel.control_buttons)
        if getattr(self.app, "ask_name", False):
            self.operator_panel.start_dialog(gui)
        self.operator_panel.build(gui)
        # Tabs named for the operator's day, in its order: the machine (home, jog, go to, probe), the part alignment,
        # measuring, the routine, the report, and the set-up done once in a while (probes, diagnostics). Each group's
        # sub-tabs hold what the flat list of 13 tabs held; tests reach them with browser_support.open_tab.
        gui.add_html(TABS_CSS)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Machine"):
            machine = gui.add_tab_group()
            with machine.add_tab("Home"):
                self.machine.build_home(gui)
            with machine.add_tab("Jog"):
                self.jog.build(gui, lambda hold=None: self.app.pendant_grant(self, hold=hold))
            with machine.add_tab("Go to"):
                self.machine.build_goto(gui)
            with machine.add_tab("Probe"):
                self.machine.build_probe(gui)
        with tabs.add_tab("Align"):
            self.align.build(gui)
        with tabs.add_tab("Measure"):
            measure = gui.add_tab_group()
            with measure.add_tab("Auto-measure"):
                self.measure.build(gui)
            with measure.add_tab("Features"):
                self.features.build(gui)
            with measure.add_tab("Colour map"):
                self.colour_map.build(gui)
        with tabs.add_tab("Routine"):
            self.routine.build(gui)
        with tabs.add_tab("Report"):
            report = gui.add_tab_group()
            with report.add_tab("Sessions"):
                self.sessions.build(gui)
            with report.add_tab("Trends"):
                self.trends.build(gui)
        with tabs.add_tab("Setup"):
            setup = gui.add_tab_group()
            with setup.add_tab("Part"):  # the part file, where it sits, the next part (on the simulator)
                self.part.build(gui)
            with setup.add_tab("Calibration"):
                self.calibration.build(gui)
            with setup.add_tab("Diagnostics"):
                self.diagnostics.build(gui)
        if self._closed:  # it went while it was being built: what it subscribed to meanwhile ends
            self.close()

    def refresh(self) -> None:
        """Copy the station's state (the API's queries) into this client's read-outs (only what changed)."""
        self.operator_panel.watch_control()
        self.machine.forget_stale_pick()
        self.jog.refresh()
        if not self.gui:
            return
        self.operator_panel.refresh()
        self.status.refresh()
        self.machine.refresh()
        self.features.refresh()
        self.align.refresh()
        self.part.refresh()
        self.colour_map.refresh()
        self.measure.refresh()
        self.routine.refresh()
        self.machine.refresh_pick()
        self.diagnostics.refresh()
        self.sessions.refresh()
        self.trends.refresh()
        self.calibration.refresh()

    def fast_refresh(self) -> None:
        """The status bar at the refresher's full rate from its subscription's last snapshot (no query): what is the
        page's own (control, a cycle, manual hits armed, the link meter's clock) shows as soon as a delivery would;
        idle it changes nothing."""
        if self.gui:
            self.status.refresh()
