"""A station on the simulator's virtual clock with an I++ DME server in front of it, for the ippdme tests."""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

from cmm.ippdme.client import IppClient
from cmm.ippdme.server import IppServer
from cmm.machine.config import load

# in-process simulated CMM on the virtual clock, at most 25 machine seconds per wall second: the poll
# thread then sleeps instead of spinning, so the server's threads (and the other tests) get the CPU
SIM_URL = "sim://?cmm=1&pace=25"
POLL_PAUSE = 0.01  # s of machine time between the station's samples in these tests (10 ms: moves end within it)


def nist_config():
    """Our machine with its travel around the origin: the NIST programs move near (0, 0, 0) and home there.

    Home switches sit at an end of the travel, so this machine has none: its
    counters are trusted from power-up (homed) and Home() goes to (0, 0, 0).
    """
    config = load()
    axes = tuple(replace(a, min=-100.0, max=300.0, home=0.0) for a in config.axes)
    return replace(config, axes=axes, homing=replace(config.homing, method="none"))


@contextmanager
def ipp_station(tmp_path, config=None, *, empty_world: bool = False, send_timeout: float = 10.0,
                send_buffer: int | None = None, trace=None):
    """(server, station): the simulated CMM in-process on its virtual clock, polled in the background.

    ``empty_world`` removes the table, the part and the reference sphere (the
    NIST programs move through the region they occupy); tests place their
    own artifacts with ``station.sim.place_artifacts``.
    """
    from stations import Stations  # the kind ``ipp`` (tests/stations.py)

    with Stations(lambda: tmp_path / "sessions") as built:
        yield built.ipp(config, empty_world=empty_world, send_timeout=send_timeout, send_buffer=send_buffer,
                        trace=trace)


@contextmanager
def connected(server: IppServer, timeout: float = 60.0):
    client = IppClient("127.0.0.1", server.port, timeout=timeout)
    try:
        yield client
    finally:
        client.close()
