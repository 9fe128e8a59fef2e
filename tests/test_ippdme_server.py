"""The I++ DME server on the simulated station: robustness, the error model, queues, measuring, the journal."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from cmm.cli import main
from cmm.ippdme.client import IppClient
from cmm.ippdme.executor import Dme
from cmm.ippdme.protocol import parse_response
from cmm.ippdme.server import parse_address
from cmm.journal.store import DirectoryStore, load_session
from cmm.ui.panels import machine_markdown

import session_support as sup
from ippdme_support import connected, ipp_station

FAR = "GoTo(X(400), Y(300), Z(250))"  # from home (0, 0, 300): 500 mm, 100 s at 5 mm/s


def wait_until(predicate, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "condition not reached"
        time.sleep(0.01)


def ready(c: IppClient, speed: float = 5.0) -> None:
    for cmd in ("StartSession()", "Home()", 'ChangeTool("Probe1")', f"SetProp(Tool.GoToPar.Speed({speed}))"):
        assert c.call(cmd).ok, cmd


@pytest.fixture
def served(tmp_path):
    with ipp_station(tmp_path) as (server, station):
        yield server, station


def test_malformed_lines_and_unknown_commands_get_errors_and_the_server_carries_on(served):
    server, station = served
    with connected(server) as c:
        c.call("StartSession()")
        c.send_line("12 Home()")  # illegal tag: answered as an unsolicited error (severity 2: error state)
        c.wait("E0000", "!")
        assert c.call("GetErrStatusE()").data == ["ErrStatus(1)"]
        assert c.call("ClearAllErrors()").ok
        t = c.call("Frobnicate(X(1))")
        assert [(r.kind, r.error_number, r.severity) for r in t.responses] == [("&", None, None), ("!", 501, 3),
                                                                               ("%", None, None)]
        assert c.call("Get(X())").errors[0].error_number == 514  # error state until ClearAllErrors
        assert c.call("GetErrStatusE()").data == ["ErrStatus(1)"]
        assert c.call("ClearAllErrors()").ok
        c.send_line("00077 GoTo(X(1)")
        c.wait("00077", "%")
        assert [r.error_number for r in c.received if r.tag == "00077" and r.kind == "!"] == [502]
        c.call("ClearAllErrors()")
        c.sock.sendall(b"00078 Get(X(\xff))\r\n")
        c.wait("00078", "%")
        assert [r.error_number for r in c.received if r.tag == "00078" and r.kind == "!"] == [7]
        c.call("ClearAllErrors()")
        assert c.call("GetDMEVersion()").data == ['DMEVersion("1.4.3")']
        assert c.call("GetErrStatusE()").data == ["ErrStatus(0)"]
        assert parse_response(f"{c.received[0].tag} {c.received[0].kind}").tag == "00001"
        before = len([r for r in c.received if r.tag == "E0000"])
        c.sock.sendall(b"00079 Get(X(" + b"1" * 70000)  # over the 65,536-character line limit, no terminator yet
        wait_until(lambda: len([r for r in c.received if r.tag == "E0000"]) > before)
        assert [r.error_number for r in c.received if r.tag == "E0000"][before:] == [8]
        c.sock.sendall(b"))\r\n")  # the rest of the dropped line is one more malformed line; then on as before
        c.call("ClearAllErrors()")
        assert c.call("GetDMEVersion()").data == ['DMEVersion("1.4.3")']


def test_a_fast_query_is_answered_during_a_move_and_a_reused_tag_is_refused(served):
    server, station = served
    with connected(server) as c:
        ready(c)
        c.send(FAR, tag="00100")
        c.wait("00100", "&")
        wait_until(lambda: station.machine.busy)
        c.send_line("00100 Get(X())")  # the tag is still in use
        c.wait("E0000", "!")
        assert [r.error_number for r in c.received if r.tag == "E0000"] == [1]
        t = c.call("GetErrStatusE()")
        assert t.data == ["ErrStatus(1)"] and station.machine.busy  # answered while the move runs
        assert not any(r.tag == "00100" and r.kind == "%" for r in c.received)
        abort = c.send("AbortE()")
        c.wait(abort, "%")
        mine = [(r.tag, r.kind, r.error_number) for r in c.received if r.tag in ("00100", abort)]
        assert mine == [("00100", "&", None), (abort, "&", None), ("00100", "!", 6), ("00100", "%", None),
                        (abort, "%", None)]
        assert not station.machine.busy
        assert c.call("Get(X())").errors[0].error_number == 514  # AbortE: ClearAllErrors comes next
        assert c.call("ClearAllErrors()").ok
        sup.standing(station, "the axes after the abort's stop")  # its servo settles for a few samples
        # after the stop, a move that leaves Y and Z where they are still arrives
        assert c.call("SetProp(Tool.GoToPar.Speed(50))").ok
        here = c.call("Get(X(), Y(), Z())").values()
        assert c.call(f"GoTo(X({here['X'][0] + 20:.4f}))").ok  # I++ numbers have at most 16 digits
        there = c.call("Get(X(), Y(), Z())").values()
        assert there["X"][0] == pytest.approx(here["X"][0] + 20, abs=0.005)
        # Y and Z stay (up to the few counts the servo had left to settle when the abort stopped it)
        assert (there["Y"], there["Z"]) == (pytest.approx(here["Y"], abs=0.01), pytest.approx(here["Z"], abs=0.01))


def test_an_error_aborts_the_pending_commands(served):
    server, station = served
    with connected(server) as c:
        ready(c, speed=50)
        first = c.send(FAR)
        second = c.send("GoTo(X(1e6))")  # queued behind the move; out of the volume
        third = c.send("Get(X())")  # queued: aborted by the error
        c.wait(third, "%")
        errors = {tag: [(r.severity, r.error_number) for r in c.received if r.tag == tag and r.kind == "!"]
                  for tag in (first, second, third)}
        assert errors == {first: [], second: [(3, 1008)], third: [(2, 6)]}
        assert c.call("ClearAllErrors()").ok and c.call("Get(X())").ok


def test_a_command_sent_as_soon_as_the_error_arrives_meets_the_error_state_not_the_abort(served):
    """Only the commands waiting when the error happened get 0006; the client's answer to the error is its own.

    The executor is driven directly so the "client" answers the error from inside ``send``, before
    the server has done anything else: the quickest client there can be, every time.
    """
    server, station = served
    backend = server.backend.for_client("127.0.0.1:9")
    assert backend.acquire() is None
    lines: list[str] = []
    done = threading.Event()

    def send(line: str) -> None:
        lines.append(line)
        if line.startswith("00012 ! "):  # the client has read the error: it answers at once
            dme.receive("00013 Get(X())")
            dme.receive("00014 ClearAllErrors()")
            dme.receive("00015 Get(X())")
        if line == "00015 %":
            done.set()

    def complete(tag: str) -> None:
        wait_until(lambda: f"{tag} %" in lines)

    dme = Dme(backend, send, client="quick")
    try:
        for tag, cmd in (("00001", "StartSession()"), ("00002", "Home()"), ("00003", 'ChangeTool("Probe1")'),
                         ("00004", "SetProp(Tool.GoToPar.Speed(50))")):
            dme.receive(f"{tag} {cmd}")
            complete(tag)
        dme.receive(f"00011 {FAR}")  # runs a while: the next two wait behind it
        dme.receive("00012 GoTo(X(1e6))")  # out of the volume: error 1008, severity 3
        dme.receive("00016 Get(Y())")  # waiting when the error happens: aborted
        assert done.wait(60), lines
        errors = {tag: [ln.split("Error(")[1][:7] for ln in lines if ln.startswith(f"{tag} ! ")]
                  for tag in ("00011", "00012", "00013", "00014", "00015", "00016")}
        assert errors == {"00011": [], "00012": ["3, 1008"], "00013": ["2, 0514"], "00014": [], "00015": [],
                          "00016": ["2, 0006"]}
        assert not dme.error_state
    finally:
        dme.close()
        backend.release()


def test_a_client_that_disconnects_during_a_move_leaves_the_machine_stopped(served):
    server, station = served
    c = IppClient("127.0.0.1", server.port)
    ready(c)
    tag = c.send(FAR)
    c.wait(tag, "&")
    wait_until(lambda: station.machine.busy and station.machine.position[0] > 1.0)
    c.close()
    # stopped: no count changed for 0.2 s of the machine's clock (one sample of zero velocity is not enough: the
    # end of the deceleration creeps below a count per tick)
    since = [station.machine.state.time, station.machine.state.position.copy()]

    def stood() -> bool:
        s = station.machine.state
        if station.machine.busy or not np.array_equal(s.position, since[1]):
            since[:] = [s.time, s.position.copy()]
            return False
        return s.time - since[0] >= 0.2
    wait_until(stood)
    stopped, t = station.machine.position.copy(), station.machine.state.time
    wait_until(lambda: station.machine.state.time > t + 5.0)  # five seconds of machine time
    assert np.allclose(station.machine.position, stopped, atol=0.005)  # it stays where it stopped
    assert np.linalg.norm(stopped - [400.0, 300.0, 250.0]) > 1.0  # stopped short of the target, not finished
    wait_until(lambda: server.client is None)
    assert "disconnected during a move" in open(station.measurement.journal.path).read()
    with connected(server) as again:  # the next client gets the machine
        assert again.call("StartSession()").ok


def test_a_second_client_is_refused_while_the_first_keeps_the_machine(served):
    server, station = served
    with connected(server) as first:
        assert first.call("StartSession()").ok
        second = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        reply = b""
        while not reply.endswith(b"\r\n"):
            chunk = second.recv(1000)
            assert chunk, "closed without saying why"
            reply += chunk
        r = parse_response(reply.decode().strip())
        assert (r.tag, r.kind, r.error_number) == ("E0000", "!", 508)
        assert second.recv(1000) == b""  # and closed
        second.close()
        assert first.call("IsHomed()").ok
        assert server.status.snapshot()["client"] == server.client
        station.ippdme = server.status  # as cmm serve --ippdme does: the browser's status panel shows the client
        assert f"I++ DME client {server.client} has control" in machine_markdown(station.controller.commands)
    wait_until(lambda: server.client is None)
    assert "no client" in machine_markdown(station.controller.commands)


def test_a_client_that_ends_its_session_and_connects_again_at_once_is_served(served):
    """A client that closes right after EndSession and connects again is not refused as "another client" while
    the server's threads have not yet seen the first connection end (half of such reconnections were)."""
    server, station = served
    for i in range(20):
        with connected(server) as c:
            assert c.call("StartSession()").ok, f"reconnection {i} refused: {c.received[-3:]}"
            assert c.call("EndSession()").ok
    with connected(server) as first:  # a client that keeps its connection still keeps the machine
        assert first.call("StartSession()").ok
        with pytest.raises(Exception, match="closed the connection"):
            with connected(server) as second:
                second.call("StartSession()")


def test_a_client_that_never_reads_is_dropped_and_the_machine_stops(tmp_path):
    with ipp_station(tmp_path, send_timeout=0.5, send_buffer=4096) as (server, station):
        c = socket.socket()
        c.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # small buffers: the backlog shows at once
        c.connect(("127.0.0.1", server.port))
        c.settimeout(10)
        for line in ("00001 StartSession()", "00002 Home()", '00003 ChangeTool("Probe1")',
                     "00004 SetProp(Tool.GoToPar.Speed(5))", f"00005 {FAR}"):
            c.sendall(line.encode() + b"\r\n")
        wait_until(lambda: station.machine.busy)
        filler = b"".join(b"E%04d GetErrStatusE()\r\n" % (i % 9999 + 1) for i in range(500))
        try:
            for _ in range(20):  # the responses back up: the server gives up on this client
                c.sendall(filler)
                if server.client is None:
                    break
        except OSError:
            pass
        wait_until(lambda: server.client is None)
        wait_until(lambda: not station.machine.busy)
        assert station.machine.position[0] < 300.0
        c.close()
        with connected(server) as again:
            assert again.call("StartSession()").ok


def test_ptmeas_reports_the_tip_centre_and_the_session_is_recorded(served, tmp_path):
    server, station = served
    part = station.measurement.part
    top = (part.pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]  # the sample part's top face (part coordinates)
    with connected(server) as c:
        ready(c, speed=50)
        assert c.call(f"GoTo(X({top[0]:.4f}), Y({top[1]:.4f}), Z(70))").ok
        assert c.call("OnPtMeasReport(X(), Y(), Z(), IJK(), ER())").ok
        t = c.call(f"PtMeas(X({top[0]:.4f}), Y({top[1]:.4f}), Z({top[2]:.4f}), IJK(0, 0, 1))")
        assert t.ok, t.responses
        v = t.values()
        assert v["IJK"] == [0, 0, 1] and v["ER"] == [pytest.approx(station.prober.settings.tip_radius)]
        # the sample part is where the station believes it, up to the simulator's set-up error
        assert v["Z"][0] == pytest.approx(top[2] + 1.0, abs=0.05)
        assert (v["X"][0], v["Y"][0]) == (pytest.approx(top[0], abs=0.002), pytest.approx(top[1], abs=0.002))
        snap = server.status.snapshot()
        assert snap["points"] == [tuple(pytest.approx(x, abs=0.001) for x in (v["X"][0], v["Y"][0], v["Z"][0]))]
        beside = (part.pose @ np.array([-30.0, 15.0, 20.0, 1.0]))[:3]  # off the part, above the table
        assert c.call(f"GoTo(Z(70))").ok and c.call(f"GoTo(X({beside[0]:.4f}), Y({beside[1]:.4f}))").ok
        t = c.call(f"PtMeas(X({beside[0]:.4f}), Y({beside[1]:.4f}), Z({beside[2]:.4f}), IJK(0, 0, 1))")
        assert [e.error_number for e in t.errors] == [1006]  # surface not found
        c.call("EndSession()")
    journal = station.measurement.journal.path
    session = load_session(DirectoryStore(journal.parent), journal.stem)
    assert journal.stem.startswith("ippdme-") and len(session.hits) == 1
    (hit,) = session.hits.values()
    assert hit.machine == pytest.approx([v["X"][0], v["Y"][0], v["Z"][0]], abs=0.001)
    text = journal.read_text()
    assert "I++ DME session started" in text and "I++ DME session ended" in text
    assert "I++ DME error" in text and "1006 Surface not found" in text  # why a point is missing


def test_move_reports_come_at_most_ten_a_second_along_the_path(served):
    server, station = served
    with connected(server) as c:
        ready(c, speed=20)
        start = station.machine.clock.now()
        d = c.send("OnMoveReportE(Time(0.1), Dis(0.01), X(), Y(), Z())")  # as often as allowed
        c.wait(d, "%")
        assert c.call("GoTo(X(60), Y(0), Z(300))").ok
        assert c.call(f"StopDaemon({d})").ok
        elapsed = station.machine.clock.now() - start
        reports = [r for r in c.received if r.tag == d and r.kind == "#"]
        assert 15 <= len(reports) <= 10 * elapsed + 1  # 3 s of travel: at most 10 a second
        xs = [float(r.body.split("X(")[1].split(")")[0]) for r in reports]
        assert xs == sorted(xs) and xs[-1] > 50
        n = len(c.received)
        time.sleep(0.3)
        assert not [r for r in c.received[n:] if r.tag == d]  # none after StopDaemon


def test_the_command_line_client_runs_commands_and_nist_programs(served, capsys, tmp_path):
    server, station = served
    assert main(["ippdme-client", server.address, "--session", "-c", "GetDMEVersion()", "-c", "IsHomed()"]) == 0
    out = capsys.readouterr().out
    assert '# DMEVersion("1.4.3")' in out and "# IsHomed(" in out
    wait_until(lambda: server.client is None)  # the first run has let go of the machine
    prg = tmp_path / "p.prg"
    prg.write_bytes(b"00001 StartSession()\r\n\\\\\r\n00002 Foo()\r\n\\\\\r\n00003 EndSession()\r\n\\\\\r\n:\r\n:\r\n")
    assert main(["ippdme-client", server.address, "-f", str(prg)]) == 1  # an error: exit status 1
    assert "00002 ! Error(3, 0501" in capsys.readouterr().out
    wait_until(lambda: server.client is None)
    with connected(server):  # a second client while one holds the machine: told why
        assert main(["ippdme-client", server.address, "-c", "IsHomed()"]) == 1
    assert "0508" in (err := capsys.readouterr().err) and "another I++ DME client holds the machine" in err
    assert main(["ippdme-client", "nohost:notaport"]) == 2


def test_an_estop_from_a_browser_is_error_0500_on_the_move_and_unsolicited(served):
    from cmm.control import Client

    server, station = served
    with connected(server) as c:
        ready(c, speed=20)
        tag = c.send(FAR)
        c.wait(tag, "&")
        wait_until(lambda: station.machine.busy)
        assert station.controller.emergency_stop(Client("tab-1", local=True)).ok
        c.wait(tag, "%")
        assert [r.error_number for r in c.received if r.tag == tag and r.kind == "!"] == [500]
        wait_until(lambda: any(r.tag == "E0000" and r.error_number == 500 for r in c.received))
        assert c.call("GetErrStatusE()").data == ["ErrStatus(1)"]  # severity 3: the client must clear it
        assert c.call("GoTo(X(1))").errors[0].error_number == 514
        station.controller.reset(None)  # the operator releases the latch at the station
        assert c.call("ClearAllErrors()").ok
        assert c.call("GoTo(X(10), Y(10), Z(290))").ok


def test_a_move_a_stop_cut_short_before_it_was_sent_is_0500_under_estop_and_1011_after(served):
    """The race the E-STOP test sometimes loses: the stop takes the link before the move's own command, and the
    control loop says so (CutShort, a ControlError). That is a stop, not 0503 "controller communications failure"."""
    from cmm.control import Client, CutShort
    from cmm.ippdme.errors import IppError

    server, station = served
    backend = server.backend.for_client("127.0.0.1:10")
    assert backend.acquire() is None
    dme = Dme(backend, lambda line: None, client="race")

    def cut_short():
        raise CutShort("move was cut short by a STOP (the link was taken)")

    try:
        assert station.controller.emergency_stop(Client("tab-1", local=True)).ok
        with pytest.raises(IppError) as estop:
            dme._motion(cut_short, "GoTo")
        station.controller.reset(None)
        with pytest.raises(IppError) as stop:
            dme._motion(cut_short, "GoTo")
        assert (estop.value.number, stop.value.number) == (500, 1011)
    finally:
        dme.close()
        backend.release()


def test_addresses():
    assert parse_address(None) == ("127.0.0.1", 1294)
    assert parse_address("0.0.0.0:1295") == ("0.0.0.0", 1295)
    assert parse_address("1300") == ("127.0.0.1", 1300)
    with pytest.raises(ValueError, match="ADDRESS:PORT"):
        parse_address("host:x")


def test_the_i_client_holds_the_control_browsers_observe_and_may_stop(served):
    from cmm.control import Client, Refused
    from cmm.control.access import Control

    server, station = served
    tab = Client("tab-1", local=True)  # a browser on the station's own screen
    control = Control()  # the browser station's single-holder control, as cmm serve wires it
    station.controller.use_policy_of(control)
    assert control.take(tab.id, is_local=True)  # a browser held the machine
    with connected(server) as c:
        ready(c, speed=20)
        assert control.holder == f"ippdme {server.client}"
        with pytest.raises(Refused, match="observes"):
            station.controller.move(tab, [10.0, 10.0, 290.0], frame="machine")
        tag = c.send(FAR)
        c.wait(tag, "&")
        wait_until(lambda: station.machine.busy)
        assert station.controller.stop(tab).ok  # the browser still stops it
        c.wait(tag, "%")
        assert [r.error_number for r in c.received if r.tag == tag and r.kind == "!"] == [1011]
        assert not station.machine.busy
    wait_until(lambda: control.holder is None)  # released when the client goes


def test_cmm_serve_starts_the_server_on_the_station(stations, capsys):
    from cmm.cli import build_parser
    from cmm.ippdme.serve import start

    args = build_parser().parse_args(["serve", "--ippdme"])
    assert args.ippdme == "127.0.0.1:1294"  # loopback unless asked
    assert build_parser().parse_args(["serve", "--ippdme", "0.0.0.0:1300"]).ippdme == "0.0.0.0:1300"
    station = stations.station(home=False)
    try:
        server = start(station.controller.commands, "127.0.0.1:0")  # the server gets the API only
        station.serving_ippdme(server.status)  # as `cmm serve` does: the page shows the I++ client
        try:
            assert "I++ DME server on 127.0.0.1:" in capsys.readouterr().out
            with connected(server) as c:
                assert c.call("StartSession()").ok
                wait_until(lambda: station.ippdme.snapshot()["in_session"])
        finally:
            server.close()
        taken = socket.create_server(("127.0.0.1", 0))  # the port is in use: one sentence, no traceback
        try:
            with pytest.raises(OSError, match="cannot listen for I\\+\\+ DME clients"):
                start(station.controller.commands, f"127.0.0.1:{taken.getsockname()[1]}")
        finally:
            taken.close()
    finally:
        station.close()
