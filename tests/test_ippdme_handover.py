"""Control hand-over to I++ clients: an I++ client that connects while the holder's machine moves gets an
I++ error naming the holder, and the motion goes on; once the holder stands still and releases, it connects.

The simulated station in-process on its virtual clock (paced), a real I++ client over TCP on 127.0.0.1.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from cmm.control import Client
from cmm.control.access import Control
from ippdme_support import connected, ipp_station


def wait_until(predicate, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "condition not reached"
        time.sleep(0.01)


@pytest.fixture
def served(tmp_path):
    with ipp_station(tmp_path) as (server, station):
        yield server, station


def test_an_i_client_does_not_take_control_from_a_holder_whose_machine_moves(served):
    server, station = served
    pendant = Client("pendant-1", local=True)
    control = Control()
    station.controller.use_policy_of(control)
    control.set_name(pendant.id, "Ahmed")
    assert control.take(pendant.id, is_local=True)
    station.controller.home(pendant)
    here = np.asarray(station.controller.frame_position("machine"), float)
    status = station.controller.move(pendant, here + [300.0, 200.0, -40.0], frame="machine", speed=5.0)
    wait_until(lambda: station.machine.busy)
    with connected(server) as c:
        wait_until(lambda: any(r.kind == "!" for r in c.received))
        err = next(r for r in c.received if r.kind == "!")
        assert err.error_number == 508, err.body
        assert "Ahmed holds the station's control" in err.body and "moving" in err.body, err.body
        assert "Release" in err.body
    assert control.holder == pendant.id  # the holder keeps control ...
    assert station.machine.busy and not status.done  # ... and the machine goes on moving
    assert station.controller.stop(pendant).ok
    wait_until(lambda: not station.machine.busy)
    assert control.release(pendant.id)  # handing over is explicit: the holder releases, the client connects
    with connected(server) as c:
        assert c.call("StartSession()").ok
        assert control.holder is not None and control.holder.startswith("ippdme")


def test_absurd_numbers_get_the_right_error_and_a_sentence_in_the_journal(served):
    """a PtMeas with X 1e308 got a bare error of the wrong kind; a 1e308 target was written as a
    300-digit number. Both GoTo and PtMeas get 1008 (target out of the machine volume) and the session journal
    says why, with the number formatted."""
    server, station = served
    with connected(server) as c:
        for cmd in ("StartSession()", "Home()", 'ChangeTool("Probe1")'):
            assert c.call(cmd).ok, cmd
        for cmd in ("PtMeas(X(1e308), Y(100), Z(50), IJK(0, 0, 1))", "GoTo(X(1e308), Y(100), Z(250))"):
            t = c.call(cmd)
            assert [r.error_number for r in t.errors] == [1008], (cmd, t.errors)
            assert c.call("ClearAllErrors()").ok
        assert c.call("EndSession()").ok
    journal = station.measurement.journal.path.read_text() if station.measurement.journal else ""
    notes = [line for line in journal.splitlines() if "1e+308" in line]
    assert len(notes) >= 2 and all("is outside the travel 0..500 mm" in n for n in notes), notes
    assert "000000000000000000000" not in journal


def test_one_error_for_one_oversized_line(served):
    """one 10 MB line without a newline got about 150 protocol errors; it gets one, and the client's
    next command is served."""
    server, station = served
    with connected(server) as c:
        assert c.call("StartSession()").ok
        start = len(c.received)
        c.sock.sendall(b"00009 GoTo(X(" + b"1" * (10 * 1024 * 1024))
        wait_until(lambda: any(r.kind == "!" for r in c.received[start:]))
        c.sock.sendall(b"))\r\n")
        assert c.call("ClearAllErrors()").ok  # the line's end went with it: the next command is served
        errors = [r for r in c.received[start:] if r.kind == "!"]
        assert len(errors) == 1 and errors[0].error_number == 8, errors
