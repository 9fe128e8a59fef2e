"""The viser application: one shared scene, one GUI per client, everything through the command API.

:class:`StationApp` starts the viser server, draws the scene
(:mod:`cmm.ui.scene`), builds a :class:`~cmm.ui.panels.ClientApp` per browser
tab, and runs two light threads: the probe updater (the probe node at most 25 times a second, the
following-error plot sampled at 50 Hz) and the panel refresher (20 Hz status bar, 5 Hz read-outs). Each tab's
status bar and DRO, and its read-outs that are plain snapshots, follow the station through the API's subscriptions
(``api.subscribe``, one hub thread: only what changed is delivered); the refresher redraws the bar from their last
snapshot and the other read-outs from their queries. It reads the station only through the command API's
queries (the model's events too: the ``watch_model`` query) and changes it only through its verbs. Who may move
the machine is decided by the access :class:`~cmm.control.access.Control`, shared with the pendant page (the
``use_policy`` verb).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..control.access import Control, OriginPolicy, forwarded_peer, is_local_connection, is_loopback_host
from .origin import guard_viser
from .panels import ClientApp
from .scene import DEFAULT_TOLERANCE, ProbeUpdater, SceneView

REFRESH_HZ = 20.0
READOUT_EVERY = 4  # refresher ticks between read-out refreshes (5 Hz)
PLOT_SECONDS = 10.0
log = logging.getLogger(__name__)


class StationApp:
    """The page of the station behind ``api`` (the command API, :class:`cmm.api.CommandAPI`)."""

    def __init__(self, api: Any, *, host: str = "127.0.0.1", port: int = 8080, lan: bool = False,
                 control: Control | None = None, pendant: bool = True, pendant_port: int | None = None,
                 tolerance: float = DEFAULT_TOLERANCE, verbose: bool = False,
                 allow_hosts: tuple[str, ...] = (), ask_name: bool = True, shadows: bool = True,
                 users: Any = None, tls: Any = None) -> None:
        import viser

        self.api = api  # all the page gets: every panel reads with its queries and changes with its verbs
        self.ask_name = ask_name  # each new tab opens with the "Who is operating?" dialog
        self.users = users  # cmm.control.users.UserStore: each tab logs in (the start dialog); None: no login
        self.tls = tls  # cmm.control.tls.Certificate: the pendant serves https / wss with it
        self.host = host
        self.control = control or Control(lan=lan)
        if self.control.on_holder_lost is None:  # a holder that goes away must not leave its jog running
            self.control.on_holder_lost = lambda _cid: self._holder_lost()
        api.invoke(None, "use_policy", control=self.control)  # machine commands are checked there, once
        self.origins = OriginPolicy(lan=lan or not is_loopback_host(host), allow_hosts=allow_hosts)
        self.behind_tls_proxy = False  # cmm serve --tls: the page on loopback, its clients' addresses forwarded
        self.server = viser.ViserServer(host=host, port=port, label="CMM station", verbose=verbose)
        self._refused = guard_viser(self.server, self.origins)
        # the wide side panel: the six top tabs (Machine ... Setup) in one row, the DRO's three columns unwrapped
        self.server.gui.configure_theme(control_width="large")
        if not shadows:  # the probe's shadow on the part costs three shadow-map passes a frame: on a computer
            # without a GPU (software WebGL) a frame took 0.45 CPU s with them, 0.3 s without (``--no-shadows``);
            # the environment map's image-based lighting was half of what was left (0.18 -> 0.08 CPU s a frame)
            self.server.scene.configure_default_lights(True, cast_shadow=False)
            self.server.scene.configure_environment_map(None)
        self.port = self.server.get_port()
        self.origins.ports.add(self.port)  # the viser page's hold refresher talks to the pendant port
        self.clients: dict[int, ClientApp] = {}
        self._clients_lock = threading.Lock()
        self._fe: deque[tuple[float, float, float, float]] = deque(maxlen=int(PLOT_SECONDS * 50))
        self._t0 = time.monotonic()
        self._dirty = {"hits": True, "features": True, "part": False}
        self._deviations: dict[int, float] = {}
        self._redraw_lock = threading.Lock()
        self.shared = SimpleNamespace(calibration_job=None, cycle=None, cycle_paused=False, run_stopped="")  # state every tab's panels share
        # (a running calibration; the cycle running, e.g. an auto-measure, that the status bars show as RUNNING)
        self.view = SceneView(self.server.scene, api, tolerance=tolerance,
                              on_feature_click=self._feature_clicked)
        self.view.build()
        self.view.frame_camera(self.server.initial_camera)
        self.pendant = None
        self.pendant_url: str | None = None
        if pendant:
            self._start_pendant(pendant_port if pendant_port is not None else (port + 1 if port else 0))
        self._unwatch = api.invoke(None, "watch_model", on_event=self._on_model_event)
        self.server.scene.on_click()(self._scene_clicked)
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        self.updater = ProbeUpdater(api, self.view, extra=self._sample_plot).start()
        self._stop = threading.Event()
        self.refresh_errors = 0  # refreshes that failed (each distinct failure is logged once)
        self.refreshes = 0  # read-out rounds done (a refresher held up somewhere shows it here)
        self._refresh_failures: set[tuple[str, str, str]] = set()
        self._refresher = threading.Thread(target=self._refresh_loop, name="ui-refresh", daemon=True)
        self._refresher.start()

    # --- life cycle ------------------------------------------------------------

    @property
    def url(self) -> str:
        shown = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{shown}:{self.port}/"

    def _start_pendant(self, port: int) -> None:
        try:
            from .pendant import start_pendant_server
        except ImportError:
            return
        for p in dict.fromkeys((port, 0)):
            try:
                self.pendant = start_pendant_server(self.api, self.control, self.host, p, origins=self.origins,
                                                    ssl=None if self.tls is None else self.tls.ssl_context(),
                                                    users=self.users)
                self.pendant_url = self.pendant.url
                return
            except OSError:
                continue

    def close(self) -> None:
        self._stop.set()
        self._unwatch()  # a closed page hears the model no more
        self.updater.close()
        for capp in list(self.clients.values()):
            capp.close()  # the tabs' subscriptions
        for thread in (self._refresher,):
            if thread.is_alive():
                thread.join(timeout=2)
        if self.pendant is not None:
            self.pendant.close()
        self.server.stop()

    def _holder_lost(self) -> None:
        try:
            self.api.invoke(None, "jog_release")  # the station's own release
        except Exception:  # noqa: BLE001 - nothing was jogging
            pass

    # --- clients -------------------------------------------------------------------

    def client_address(self, client_id: int) -> Any:
        """Remote address of a viser client's WebSocket (viser keeps it on the live connection); behind the
        station's TLS proxy, the address the proxy forwarded (``behind_tls_proxy``, set by ``cmm serve --tls``)."""
        try:
            connection = self.server._websock_server._live_connections[client_id]
        except Exception:  # noqa: BLE001 - unknown: treat as remote
            return None
        request = getattr(connection, "request", None)
        return forwarded_peer(connection.remote_address, getattr(request, "headers", None), self.behind_tls_proxy)

    def client_is_local(self, client_id: int) -> bool:
        """Local = at the station PC: a loopback peer that also asked for a loopback host name."""
        try:
            host = self.server._websock_server._live_connections[client_id].request.headers.get("Host", "")
        except Exception:  # noqa: BLE001 - no handshake known: remote
            return False
        return is_local_connection(self.client_address(client_id), host)

    def pendant_src(self, client_id: int | None) -> str | None:
        """The pendant URL as this browser can reach it: the host it used for the viser page, the pendant's port."""
        if self.pendant is None:
            return None
        try:
            host = self.server._websock_server._live_connections[client_id].request.headers["Host"]
            host = host.rsplit(":", 1)[0] if not host.endswith("]") else host
            return f"http://{host}:{self.pendant.port}/"
        except Exception:  # noqa: BLE001 - fall back to the address the pendant reports
            return self.pendant_url

    def pendant_grant(self, capp: ClientApp, hold: Any = None) -> str | None:
        """A grant for ``capp``'s embedded pendant (or, with ``hold``, its jog buttons' hold refresher): it then
        acts as that client (see cmm.ui.pendant_grants)."""
        grants = getattr(self.pendant, "grants", None)
        return None if grants is None else grants.issue(capp.ctx.who, capp.peer(), hold=hold)

    def add_client(self, client: Any = None, *, client_id: str | None = None, is_local: bool | None = None) -> ClientApp:
        """A ClientApp for a connected viser client (builds its GUI), or a headless one for scripts/tests."""
        if is_local is None:
            is_local = client is not None and self.client_is_local(client.client_id)
        capp = ClientApp(self, client, client_id=client_id, is_local=is_local)
        key = client.client_id if client is not None else -len(self.clients) - 1
        with self._clients_lock:
            self.clients[key] = capp
        if client is not None:
            capp.build()
            self._fit_start_view(client)
        return capp

    def _fit_start_view(self, client: Any) -> None:
        """Once the client shows the start view (its first reports come before it has applied viser's initial
        camera) and has told its view's size: an upright view starts further back (SceneView.fit_portrait). A
        camera the operator has moved by then is left alone (after 50 reports without the start view: given up)."""
        start = np.asarray(self.server.initial_camera.position, float)
        seen: list[int] = []

        def update(camera: Any) -> None:
            if len(seen) > 50:
                return
            seen.append(1)
            if getattr(camera, "image_height", 0) > 0 and np.allclose(np.asarray(camera.position, float), start,
                                                                       atol=1e-5):
                seen.extend([1] * 51)  # once
                self.view.fit_portrait(camera)
        client.camera.on_update(update)
        update(client.camera)  # its reports may have come while its panels were built

    def _connect(self, client: Any) -> None:
        if client.client_id in self._refused:  # closed by the origin guard before it could send anything
            return
        self.add_client(client)

    def _disconnect(self, client: Any) -> None:
        with self._clients_lock:
            capp = self.clients.pop(client.client_id, None)
        if capp is not None:
            capp.close()  # its subscriptions end
            for token in (capp.pendant_token, capp.hold_token):
                if token and self.pendant is not None:
                    self.pendant.revoke(token)
            capp.jog_release()
            self.api.invoke(capp.ctx.who(), "release_control")  # a holder gone gives it up

    def _scene_clicked(self, event: Any) -> None:
        capp = self.clients.get(event.client_id)
        if capp is not None:
            capp.on_scene_click(event.ray_origin, event.ray_direction)

    def _feature_clicked(self, fid: int, client: Any) -> None:
        capp = self.clients.get(client.client_id) if client is not None else None
        if capp is not None:
            capp.select_feature(fid)

    def link_info(self) -> str:
        link = self.api.invoke(None, "link_info")
        mods = ", ".join(f"{a} (type {t}, v{v})" for a, t, v in link["modules"]) or "-"  # found at start-up
        kind = "simulator over TCP" if self.api.invoke(None, "simulator") is not None else "serial"
        return (f"port `{link['port']}` ({kind}) · {link['baud']} baud · firmware {link['firmware']}\n\nmodules: {mods}")

    # --- the model's and the machine's events ---------------------------------------------------

    def _on_model_event(self, kind: str, info: Any) -> None:
        # runs in the machine's thread: only mark what to redraw
        if kind in ("hit", "hits"):
            self._dirty["hits"] = True
        elif kind in ("feature", "features"):
            self._dirty["features"] = True
        elif kind == "part":
            self._dirty["part"] = True
        elif kind in ("deadman", "limit", "contact", "error", "estop", "fault", "homed", "reset", "reconnect") or \
                (kind == "stop" and isinstance(info, dict) and not info.get("ok", True)):
            from ..journal.wording import event_text, event_title

            # toasts in words: "Unexpected probe contact at X ... Y ... Z ...", not "contact {'position': [...]}"
            text = event_text(kind, info)
            level = "error" if kind in ("contact", "error", "estop", "fault", "stop") else "info"
            title = event_title(kind)
            if kind == "estop" and isinstance(info, dict) and info.get("ok") is False:
                title = "E-STOP NOT CONFIRMED"  # a module did not acknowledge: said in the title too
            for capp in list(self.clients.values()):
                capp.ctx.notify(title, text, level)

    def deviations(self) -> dict[int, float]:
        return self._deviations

    def _sample_plot(self, state: Any) -> None:
        fe = [float("nan") if a.following_error is None else float(a.following_error) for a in state.axes]
        self._fe.append((time.monotonic() - self._t0, *fe))

    def following_error_series(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        data = np.array(self._fe, dtype=np.float64).reshape(-1, 4)
        if len(data) < 2:
            data = np.zeros((2, 4))
        return data[:, 0], (data[:, 1], data[:, 2], data[:, 3])

    def redraw(self) -> None:
        """Redraw whatever the model's events marked dirty (refresher thread; tests may call it)."""
        with self._redraw_lock:  # a second caller waits for a redraw in progress instead of seeing stale data
            self._redraw()

    def _redraw(self) -> None:
        if self._dirty["part"]:
            self._dirty["part"] = False
            self.view.draw_part()
            self._dirty["hits"] = True
        if self._dirty["hits"]:
            self._dirty["hits"] = False
            try:
                self._deviations = self.api.invoke(None, "hit_deviations")
            except Exception:  # noqa: BLE001
                self._deviations = {}
            self.view.draw_hits(self._deviations)
            if self.view.map_on:
                self.view.request_colour_map(self._deviations)
        if self._dirty["features"]:
            self._dirty["features"] = False
            self.view.draw_features()

    def _refresh_loop(self) -> None:
        """Refresh every tab and the scene; a refresh that fails is logged (each distinct failure once, with its
        traceback; ``refresh_errors`` counts them all) and the loop goes on: one broken tab never freezes the
        others' DRO."""
        tick = 0
        while not self._stop.wait(1.0 / REFRESH_HZ):
            tick += 1
            clients = list(self.clients.items())
            for cid, capp in clients:
                # the bar's own state from its subscription's last snapshot (the DRO itself follows the deliveries)
                self._guarded(f"tab {cid} status bar", capp.fast_refresh)
            self._guarded("scene", self.redraw)
            if tick % READOUT_EVERY == 0:
                for cid, capp in clients:
                    self._guarded(f"tab {cid} read-outs", capp.refresh)
                self.refreshes += 1

    def _guarded(self, what: str, fn: Any) -> None:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - logged; the refresher keeps every other tab alive
            self.refresh_errors += 1
            key = (what, type(exc).__name__, str(exc))
            if key not in self._refresh_failures:
                self._refresh_failures.add(key)
                log.exception("refreshing the %s failed (logged once; the refresher goes on)", what)

    def refresh_failed(self, what: str, message: str) -> None:
        """A query a tab subscribes to failed (delivered once as its error): counted and logged as a refresh that
        failed; the tab keeps showing the last good value."""
        self.refresh_errors += 1
        key = (what, "subscription", message)
        if key not in self._refresh_failures:
            self._refresh_failures.add(key)
            log.error("refreshing the %s failed: %s (logged once; the subscription goes on)", what, message)
