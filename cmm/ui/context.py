"""What the panels of one browser tab share: :class:`PanelContext`.

Each tab (:class:`~cmm.ui.panels.ClientApp`) builds one context and hands it to its panels (status bar,
features, alignment, auto-measure, colour map, sessions, calibration) instead of itself. It holds the
command API (:class:`cmm.api.CommandAPI`, the page's one way to the station), the tab's viser client,
the shared 3-D view, the tab's selection (picked point, selected feature, manual probing armed), what the
operator was told, and the two ways a panel acts:

- :meth:`PanelContext.do`: a verb of the command API (measure, construct, align, auto-measure, cancel ...), sent
  as this tab's client: the core decides who may (the checks and answers every front end gets) and its refusal
  is shown to the operator in its words;
- :meth:`PanelContext.run`: an action of the page itself (a session renamed, a probe added to the list), asked of
  the core's access policy first (:meth:`PanelContext.allowed`; ``guarded=False`` for a function that sends
  verbs, which the core checks itself), an operator error shown as a notification;
- :meth:`PanelContext.set`: set a widget attribute only when the value changed (idle pages send nothing).

A panel reads with :meth:`PanelContext.query` (a query of the API, as this tab: snapshots, never the model's lock)
and :meth:`PanelContext.model` (the ``model`` query).

The few things only the tab can do (STOP and E-STOP with its held jog, selecting a feature across the
panels, forgetting the pick, switching the DRO's frame) are callables the tab installs (``stop``,
``emergency_stop``, ``select_feature``, ``clear_pick``, ``show_frame``).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any, Callable

from ..control import Client, MotionError
from ..measurement.errors import MeasurementError
from ..metrology.features import FitError
from .pick_highlight import PickDrawing

# what an action may raise that is the operator's to read (not a bug): shown as a notification
OPERATOR_ERRORS = (MotionError, MeasurementError, FitError, ValueError, OSError)


def _none(*_: Any) -> None:
    return None


class PanelContext:
    def __init__(self, api: Any, control: Any, view: Any, client: Any = None, *, client_id: str,
                 is_local: bool = False, deviations: Callable[[], dict[int, float]] = dict,
                 shared: Any = None) -> None:
        self.api = api  # the command API: every read (query) and every change (verb) of the page goes through it
        self.control = control  # the access holder shared with the pendant (cmm.control.access.Control)
        self.view = view  # the shared 3-D scene (cmm.ui.scene.SceneView)
        self.client = client  # the tab's viser client; None in tests standing in for a tab
        self.client_id = client_id
        self.is_local = is_local
        self.authenticated = is_local  # local, or gave the right access code on this connection
        self.user: str | None = None  # who logged in on this tab (a station with a user file), and their role
        self.role: str | None = None
        self.deviations = deviations  # hit id -> deviation from the part (mm), computed once for every tab
        self.shared = shared if shared is not None else SimpleNamespace(calibration_job=None)  # the app's, all tabs
        self.messages: list[tuple[str, str, str]] = []  # (level, title, body): what the operator was told
        self.gui: dict[str, Any] = {}  # the tab's own widgets by key
        self.picked: Any = None  # (PickResult, NominalFeature | None) of the last click on the part
        self.pick_drawing = PickDrawing()  # its marker and face highlight in the tab's 3-D view
        self.selected_feature: int | None = None
        self.manual_probe = False  # jogs are armed: a trigger takes a manual hit
        self._shown: dict[str, Any] = {}
        self.readouts: Any = None  # the tab's read-outs subscription (cmm.ui.feed.Feed; a tab with a page)
        # installed by the tab
        self.stop: Callable[[], Any] = _none
        self.emergency_stop: Callable[[], Any] = _none
        self.select_feature: Callable[[int], None] = _none
        self.clear_pick: Callable[[], None] = _none  # forget the last pick and remove its drawing
        self.show_frame: Callable[[str], None] = _none
        self.frame_shown: Callable[[str], None] = _none  # the DRO's frame changed (the Go to fields follow it)

    # --- telling the operator ---------------------------------------------------------

    def notify(self, title: str, body: str = "", level: str = "info") -> None:
        self.messages.append((level, title, body))
        del self.messages[:-50]
        if self.client is not None:
            try:
                self.client.add_notification(title, body, auto_close_seconds=6.0 if level != "error" else 10.0,
                                             color="red" if level == "error" else None)
            except Exception:  # noqa: BLE001 - the tab may have closed
                pass

    def error(self, exc: BaseException | str, title: str = "Refused") -> None:
        self.notify(title, str(exc), "error")

    def begin_cycle(self, description: str) -> str:
        """A cycle of several moves starts (an auto-measure, a routine or DMIS run): every tab's status bar reads
        RUNNING (``description``) until :meth:`end_cycle`, also between its moves, when the machine itself is
        idle. Called before the cycle's thread starts, so the bar says so from the first moment."""
        self.shared.cycle, self.shared.cycle_paused = description, False
        self.shared.run_stopped = ""  # a new run: the last one's stop is no longer the news
        return description

    def end_cycle(self, description: str, failure: BaseException | str | None = None) -> None:
        """The cycle ended; with ``failure`` it was refused or stopped: every tab's status bar says STOPPED with
        the run and the reason until the next run starts (a toast alone is seen in one tab, for seconds)."""
        if getattr(self.shared, "cycle", None) == description:
            self.shared.cycle, self.shared.cycle_paused = None, False
        if failure is not None:
            self.shared.run_stopped = f"{description} stopped: {failure}"

    # --- acting -------------------------------------------------------------------------

    def who(self) -> Client:
        """This browser as the control core's access policy sees it."""
        return Client(self.client_id, local=self.is_local, authenticated=bool(self.authenticated) or self.user is not None,
                      user=self.user, role=self.role)

    def allowed(self, action: str, command: str = "measure") -> bool:
        """Whether the core's access policy lets this tab send ``command`` (the control holder changes the
        measurement): asked before an action of the page that is no verb, or that changes what the page shows
        before its verb is sent; the core's refusal is shown in its words."""
        why = self.query("access", command=command)
        if why is not None:
            self.error(f"{action}: {why}", "Not in control")
            return False
        return True

    def run(self, action: str, fn: Callable[[], Any], *, guarded: bool = True) -> Any:
        """``fn()`` if the core lets this tab act (``guarded``); an operator error is shown and gives None."""
        if guarded and not self.allowed(action):
            return None
        try:
            return fn()
        except OPERATOR_ERRORS as exc:
            self.error(exc, f"{action} refused")
            return None

    @property
    def commands(self) -> Any:
        """The command API (:mod:`cmm.api`): the verbs every front end sends."""
        return self.api

    def query(self, name: str, /, **params: Any) -> Any:
        """A read-only query of the command API as this tab (``state``, ``position``, ``config``, ``probe_data``
        ...): a snapshot, taken without the page holding any lock of the station."""
        return self.api.invoke(self.who(), name, **params)

    def model(self) -> Any:
        """The measurement model now (:class:`cmm.measurement.queries.ModelSnapshot`): the API's ``model``
        query as this tab, so a panel never holds the model's lock while it draws."""
        return self.query("model")

    def do(self, action: str, method: str, /, *, guarded: bool = False, **params: Any) -> Any:
        """Send the verb ``method`` as this tab: the core checks it; its refusal or error is shown, giving None."""
        return self.run(action, lambda: self.commands.invoke(self.who(), method, **params), guarded=guarded)

    def control_text(self) -> str:
        holder = self.control.holder
        if holder == self.client_id:
            name = self.control.name(holder)
            return "**You control the machine.**" if name == holder else f"**{name} (you) controls the machine.**"
        if holder is None:
            return "Nobody controls the machine. You observe."
        return f"Observing; control is held by **{self.control.name(holder)}**."

    # --- widgets ------------------------------------------------------------------------

    def set(self, key: str, attr: str, value: Any, handle: Any = None) -> None:
        """Set a widget attribute only when the value changed (``handle`` for widgets of the sub-panels)."""
        widget = handle if handle is not None else self.gui.get(key)
        if widget is not None and self._shown.get(key) != value:
            self._shown[key] = value
            setattr(widget, attr, value)
