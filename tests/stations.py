"""The kinds of simulated station the tests build, made by one builder (see tests/README.md, "Stations").

``tests/conftest.py`` hands a test a :class:`Stations` as the fixture ``stations`` (what it builds is closed after
the test; sessions in the test's ``tmp_path``) or ``module_stations`` (closed after the module; each station's
sessions in a fresh temporary folder). A file's own fixture picks the kind and its arguments::

    @pytest.fixture(scope="module")
    def station(module_stations):
        return module_stations.station("subs")  # homed, session "subs", on the virtual clock

Kinds: :meth:`~Stations.station` (started, homed unless ``home=False``; paced, qualified, NIST travel ... by keyword),
:meth:`~Stations.probing` (homed in the caller's thread with the simulator's pre-travel, the part placed),
:meth:`~Stations.app` (a station's viser app), :meth:`~Stations.ipp` (a station served over TCP by I++ DME),
:meth:`~Stations.machine` (simulator, connected machine and prober, no station) and :meth:`~Stations.controller`
(a control core on the simulator with home switches and a breakable link, no station).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable

from netutil import SIM, free_port


def _close_once(obj: Any) -> Any:
    """``obj.close`` made safe to call again: a test may close what it built itself (to read its journal after,
    or to close it before something else); the builder's own close afterwards does nothing."""
    close = obj.close
    done: list[bool] = []

    @functools.wraps(close)
    def once() -> None:
        if not done:
            done.append(True)
            close()

    obj.close = once
    return obj


def station_page(station: Any, **ui: Any) -> Any:
    """The station's page (StationApp, options ``ui``) on its command API, which is all the page gets; the station
    is kept beside it as ``.station`` for the test, which reads the simulated machine and model there."""
    from cmm.ui.app import StationApp

    app = StationApp(station.controller.commands, **ui)
    app.station = station
    return app


class Stations:
    """Builds stations and their front ends; :meth:`close` closes everything it built, the last built first."""

    def __init__(self, session_dir: Callable[[], Path] | None = None) -> None:
        self._session_dir = session_dir or (lambda: "sessions")  # the default session folder of the next station
        self._built: list[Any] = []

    def _keep(self, obj: Any) -> Any:
        self._built.append(_close_once(obj))
        return obj

    def close(self) -> None:
        """Close everything built, the last built first (what the test closed itself is not closed again)."""
        failed = None
        while self._built:
            try:
                self._built.pop().close()
            except Exception as exc:  # noqa: BLE001 - the rest is still closed; the first failure is raised after
                failed = failed or exc
        if failed is not None:
            raise failed

    def __enter__(self) -> "Stations":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # --- stations ---------------------------------------------------------------------------------------

    def station(self, session: str | None = None, *, home: bool = True, start: bool = True, port: str = SIM,
                pace: float | None = None, qualified: bool = False, empty_world: bool = False,
                poll_pause: float | None = None, config: Any = None, session_dir: Any = None,
                **options: Any) -> Any:
        """A station on the in-process simulator (``port``; netutil's SIM: the uncapped virtual clock), started
        with a session ``session`` open and homed (``home=False``: not homed; ``start=False``: built only).

        ``pace``: after the start (and the homing, on the uncapped clock) the simulator's clock capped at
        ``pace`` machine s per wall s, for tests whose wall-time input meets the dead-man. ``qualified``: the
        probe's pre-travel the simulator's own (as a qualification finds it). ``empty_world``: no table, part or
        sphere in the simulator nor part in the model (the NIST programs move there). ``poll_pause``: the
        machine loop's machine-time pause between samples. ``options``: more Station arguments
        (``calibration_dir``, ``part_path``, ``sim_settings`` ...)."""
        from cmm.station import Station

        args = () if config is None else (config,)
        st = self._keep(Station(*args, port=port, session_dir=self._session_dir() if session_dir is None
                                else session_dir, **options))
        if empty_world:
            from cmm.sim.probe_world import PlaneObstacle

            st.sim.world.obstacles[:] = [PlaneObstacle(-1000.0)]  # the table far below the travel, nothing else
            st.measurement.part = None  # no part for the motion rails either
        if poll_pause is not None:
            st.machine.poll_pause = poll_pause
        if not start:
            return st
        st.start(session, home=home)
        if pace is not None:
            st.sim.network.set_pace(pace)
        if qualified:
            from session_support import matched_pretravel

            st.prober.settings.pretravel = matched_pretravel(st.sim)
        return st

    def nist(self, **kw: Any) -> Any:
        """A station of the NIST travel (ippdme_support.nist_config: around the origin, no home switches) on the I++
        tests' clock, not homed; ``kw`` as :meth:`station`'s."""
        from ippdme_support import POLL_PAUSE, SIM_URL, nist_config

        kw.setdefault("poll_pause", POLL_PAUSE)
        return self.station(config=nist_config(), port=SIM_URL, home=False, **kw)

    def probing(self, session: str, *, placed: Any = None, session_dir: Any = None, **options: Any) -> Any:
        """A station ready to probe from the caller's thread: modules connected and homed without the machine loop,
        the probe's pre-travel the simulator's, the sample part placed at ``placed`` (part -> machine) if given,
        then the session ``session`` opened. ``options``: more Station arguments."""
        from cmm.station import Station
        from session_support import matched_pretravel

        st = self._keep(Station(port="sim://?cmm=1", session_dir=self._session_dir() if session_dir is None
                                else session_dir, **options))
        st.controller.connect()
        st.controller.home(None)
        st.prober.settings.pretravel = matched_pretravel(st.sim)
        if placed is not None:
            st.sim.place_part(placed)
        st.measurement.new_session(session)
        return st

    # --- front ends -------------------------------------------------------------------------------------

    def app(self, station: Any, **ui: Any) -> Any:
        """``station``'s viser app (StationApp with options ``ui``) on a free 127.0.0.1 port, closed before it."""
        return self._keep(station_page(station, host="127.0.0.1", port=free_port(), **ui))

    def ipp(self, config: Any = None, *, empty_world: bool = False, **server: Any) -> tuple[Any, Any]:
        """(server, station): a started, unhomed station (``config``: the shipped one by default) on the I++ tests'
        clock, served by an I++ DME server on a free loopback port (``server``: IppServer's options)."""
        from cmm.ippdme.backend import StationBackend
        from cmm.ippdme.server import IppServer
        from cmm.machine.config import load
        from ippdme_support import POLL_PAUSE, SIM_URL

        station = self.station(config=config or load(), port=SIM_URL, home=False, empty_world=empty_world,
                               poll_pause=POLL_PAUSE)
        server = IppServer(StationBackend(station.controller.commands), "127.0.0.1", 0, **server).start()
        return self._keep(server), station

    # --- below the station --------------------------------------------------------------------------------

    def machine(self, config: Any = None, *, settings: Any = None, link: Callable[[Any], Any] | None = None,
                home_switches: bool = False, **sim: Any) -> tuple[Any, Any, Any]:
        """(simulator, connected machine, prober), no station: the machine polls only when the test waits.
        ``settings``: CmmSimSettings; ``link``: wraps the simulator's port (a fault-injecting transport);
        ``home_switches``: the simulated home switches fitted; ``sim``: more SimulatedCMM arguments."""
        from cmm.machine.config import load
        from cmm.machine.motion import Machine
        from cmm.machine.probing import Prober
        from cmm.sim.cmm_sim import SimulatedCMM

        config = config or load()
        simulator = SimulatedCMM(config, settings, **sim) if settings is not None else SimulatedCMM(config, **sim)
        if home_switches:
            from cmm.sim.home_switches import HomeSwitches

            HomeSwitches(simulator)
        port = simulator.transport()
        machine = self._keep(Machine(config, port if link is None else link(port)))
        machine.connect()
        return simulator, machine, Prober(machine)

    def controller(self, config: Any = None, *, start_at: Any = None) -> tuple[Any, Any, Any]:
        """(simulator, control core, breakable port): control_support.make_controller's, closed after the test."""
        from control_support import make_controller

        sim, ctl, port = make_controller(config, start_at=start_at)
        return sim, self._keep(ctl), port
