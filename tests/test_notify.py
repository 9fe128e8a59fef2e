"""Notifications (cmm.session.notify): a run's end, an out-of-tolerance result and a machine fault reach a webhook
receiver the test starts on 127.0.0.1 and an MQTT broker the test starts (Debian's mosquitto; skipped with the
reason when it is not installed), with the part, the program, the verdict and the report's link."""

from __future__ import annotations

import json
import os
import queue
import shutil
import socket
import subprocess
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from netutil import free_port

from cmm.session.notify import NotifyConfig, NotifyError, Notifier, load_config

SAMPLE = Path(__file__).resolve().parents[1] / "cmm" / "data" / "sample_part.dmi"
MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if os.path.exists("/usr/sbin/mosquitto") else None)


@pytest.fixture
def webhook():
    """An HTTP receiver on 127.0.0.1: every POSTed JSON body lands in the queue."""
    got: queue.Queue = queue.Queue()

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802 - http.server's name
            body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
            got.put((self.headers.get("Content-Type"), json.loads(body)))
            self.send_response(204)
            self.end_headers()

        def log_message(self, *args):  # quiet
            pass

    server = ThreadingHTTPServer(("127.0.0.1", free_port()), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    server.got = got
    server.url = f"http://127.0.0.1:{server.server_address[1]}/hooks/cmm"
    yield server
    server.shutdown()
    server.server_close()


@pytest.fixture
def broker(tmp_path):
    """A mosquitto broker on 127.0.0.1 and a subscriber to every topic: (broker URL, queue of (topic, message))."""
    if MOSQUITTO is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto): MQTT notifications not tested")
    import paho.mqtt.client as mqtt

    port = free_port()
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        end = time.monotonic() + 20
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > end:
                    pytest.skip(f"mosquitto did not start: {proc.stderr.read().decode()[-300:]}")
                time.sleep(0.05)
        got: queue.Queue = queue.Queue()
        subscribed = threading.Event()
        sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-subscriber")
        sub.on_message = lambda c, u, m: got.put((m.topic, json.loads(m.payload)))
        sub.on_subscribe = lambda *a: subscribed.set()
        sub.on_connect = lambda c, u, f, rc, p=None: c.subscribe("#", qos=1)
        sub.connect("127.0.0.1", port)
        sub.loop_start()
        assert subscribed.wait(20), "the test's subscriber could not subscribe"
        yield f"mqtt://127.0.0.1:{port}", got
        sub.loop_stop()
        sub.disconnect()
    finally:
        proc.terminate()
        proc.wait(10)


def _take(q: queue.Queue, n: int, timeout: float = 30.0) -> list:
    out = []
    end = time.monotonic() + timeout
    while len(out) < n:
        left = end - time.monotonic()
        assert left > 0, f"only {len(out)} of {n} messages arrived: {out}"
        out.append(q.get(timeout=left))
    return out


def _bore_program(tmp_path: Path) -> Path:
    """The sample part's bore (6 hits), its diameter toleranced +0.05/+0.06 mm: measured 30.010, out of tolerance."""
    lines = SAMPLE.read_text().splitlines()
    head = [ln for ln in lines[:lines.index("MODE/AUTO, PROG, MAN") + 1] if "DID(REPORT)" not in ln]
    start = lines.index("$$ --- datum B: the bore, two rings of three points")
    bore = lines[start:lines.index("ENDMES", start) + 1]
    program = tmp_path / "bore.dmi"
    program.write_text("\n".join(head + bore + ["GOTO/30, 40, 70", "T(DIAM_B) = TOL/DIAM, 0.050, 0.060",
                                                "OUTPUT/FA(BORE), TA(DIAM_B)", "ENDFIL", ""]))
    return program


def test_a_dmis_run_out_of_tolerance_is_notified_to_the_webhook_and_over_mqtt(tmp_path, monkeypatch, webhook,
                                                                               broker):
    from cmm.cli import main

    mqtt_url, got = broker
    monkeypatch.chdir(tmp_path)
    program = _bore_program(tmp_path)
    assert main(["run", str(program), "--sessions", str(tmp_path / "sessions"), "--station", "bench 7",
                 "--notify-webhook", webhook.url, "--notify-mqtt", mqtt_url]) == 0
    posted = _take(webhook.got, 2)
    assert all(ctype == "application/json" for ctype, _ in posted)
    run_end, oot = (m for _, m in posted)
    assert run_end["event"] == "run_end" and oot["event"] == "out_of_tolerance"
    for m in (run_end, oot):
        assert m["verdict"] == "FAIL" and m["program"] == "bore.dmi" and m["station"] == "bench 7"
        assert m["part"] == "sample part" and m["session"] and m["failed"] and "DIAM_B" in m["failed"][0]
        assert m["report"] == (tmp_path / "bore_report.html").resolve().as_uri()  # the report cmm run writes
        assert "out of tolerance" in m["message"]
    assert (tmp_path / "bore_report.html").exists()
    published = dict(_take(got, 2))
    assert set(published) == {"cmm/bench_7/run_end", "cmm/bench_7/out_of_tolerance"}
    assert published["cmm/bench_7/run_end"] == run_end and published["cmm/bench_7/out_of_tolerance"] == oot


def test_a_machine_fault_on_the_station_is_notified(stations, tmp_path, webhook, broker):
    """An emergency stop on a running station: a fault message, with the station's session and report link."""
    mqtt_url, got = broker
    cfg = NotifyConfig(webhook=webhook.url, mqtt=f"{mqtt_url}/shop/cmm", station="bench-8",
                       report_url="http://quality.example/reports/{station}/{session}")
    st = stations.station("faulty", session_dir=tmp_path / "sessions")
    notifier = Notifier(cfg).attach(st.measurement)
    try:
        st.controller.commands.invoke(None, "estop")
        (_, m), = _take(webhook.got, 1)
        ((topic, published),) = _take(got, 1)
    finally:
        notifier.close()
        st.close()
    assert m["event"] == "fault" and m["verdict"] == "FAULT" and m["station"] == "bench-8"
    assert m["session"] == "faulty" and m["report"] == "http://quality.example/reports/bench-8/faulty"
    assert "mergency stop" in m["message"]
    assert topic == "shop/cmm/bench-8/fault" and published == m


def test_a_receiver_that_is_down_never_holds_up_the_run_and_is_reported(tmp_path):
    """Nobody listening: the message is tried three times in the background, then dropped with the reason."""
    from types import SimpleNamespace

    from cmm.session.trends import Measured

    logged = []
    n = Notifier(NotifyConfig(webhook=f"http://127.0.0.1:{free_port()}/x", events=("run_end",), timeout=1.0),
                 log=lambda kind, text: logged.append(text))
    model = SimpleNamespace(journal=None, part=None, info={"part_number": "P-1"})
    n.run_end(model, "prog", [Measured("d", 1.0, 1.0, -0.1, 0.1)])  # returns at once
    assert n.wait(30.0)
    assert n.sent == 0 and len(n.errors) == 1 and "could not be sent to the webhook" in n.errors[0]
    assert logged == n.errors
    n.close()


def test_settings_come_from_the_station_toml_and_the_flags_win(tmp_path):
    from cmm.machine.config import default_text, load

    toml = tmp_path / "machine.toml"
    toml.write_text(default_text() + '\n[notify]\nwebhook = "http://127.0.0.1:9/x"\nmqtt = "mqtt://127.0.0.1:1883"\n'
                    'events = ["fault"]\nstation = "cell 2"\n')
    cfg = load_config(toml)
    assert (cfg.webhook, cfg.mqtt, cfg.events, cfg.station) == ("http://127.0.0.1:9/x", "mqtt://127.0.0.1:1883",
                                                                 ("fault",), "cell 2")
    assert load_config(toml, webhook="http://127.0.0.1:10/y").webhook == "http://127.0.0.1:10/y"
    load(toml)  # the machine configuration accepts the [notify] section
    with pytest.raises(NotifyError, match="not an http"):
        load_config(None, webhook="ftp://x")
    with pytest.raises(NotifyError, match="unknown notification event 'finish'"):
        NotifyConfig(events=("finish",)).check()
    toml.write_text('[notify]\nwebhok = "http://x"\n')
    with pytest.raises(NotifyError, match=r"\[notify\] webhok is not a known setting"):
        load_config(toml)


def test_a_dmis_run_without_tolerances_still_tells_its_end(tmp_path, monkeypatch, webhook):
    """A program that only measures (no TOL/): its end is a run_end with the verdict DONE, nothing out of tolerance."""
    from cmm.cli import main

    monkeypatch.chdir(tmp_path)
    program = _bore_program(tmp_path)
    text = program.read_text().replace("T(DIAM_B) = TOL/DIAM, 0.050, 0.060\n", "").replace(", TA(DIAM_B)", "")
    program.write_text(text)
    assert main(["run", str(program), "--sessions", str(tmp_path / "sessions"), "--station", "bench 9",
                 "--notify-webhook", webhook.url]) == 0
    ((_, m),) = _take(webhook.got, 1)
    assert m["event"] == "run_end" and m["verdict"] == "DONE" and m["program"] == "bore.dmi"
    assert m["characteristics"] == 0 and m["failed"] == [] and m["part"] == "sample part" and m["session"]
    assert m["report"] == (tmp_path / "bore_report.html").resolve().as_uri()
    assert webhook.got.empty()


def test_a_dmis_run_that_stops_midway_tells_it_stopped_and_why(tmp_path, monkeypatch, webhook):
    """The bore measured, then a GOTO straight into the part: the run stops there (``cmm run`` fails) and its end
    is a run_end with the verdict STOPPED naming the line and the reason, not a PASS of what was measured."""
    from cmm.cli import main

    monkeypatch.chdir(tmp_path)
    program = _bore_program(tmp_path)
    text = program.read_text()
    assert "ENDMES\nGOTO/30, 40, 70\n" in text  # after the bore's hits, up out of it
    program.write_text(text.replace("ENDMES\nGOTO/30, 40, 70\n", "ENDMES\nGOTO/30, 40, 70\nGOTO/60, 40, 20\n"))
    assert main(["run", str(program), "--sessions", str(tmp_path / "sessions"), "--station", "bench 8",
                 "--notify-webhook", webhook.url]) == 1
    ((_, m),) = _take(webhook.got, 1)
    assert m["event"] == "run_end" and m["verdict"] == "STOPPED" and m["program"] == "bore.dmi"
    assert m["station"] == "bench 8" and m["part"] == "sample part" and m["failed"] == []
    assert "STOPPED" in m["message"] and "GOTO" in m["message"] and "straight line" in m["message"], m["message"]
    assert webhook.got.empty()  # no second end, no out-of-tolerance for a run that did not finish
    (journal,) = (tmp_path / "sessions").rglob("*.jsonl")
    assert journal.read_text().count('"kind": "hit"') == 6  # the bore was measured before the stop


def test_a_routine_run_tells_its_end_and_a_cancelled_one_that_it_stopped(stations, tmp_path, webhook, broker):
    """A routine on the station without trends: its end (part, routine, verdict, report link) to the webhook and
    over MQTT; the same routine cancelled: run_end with the verdict STOPPED and the reason."""
    import session_support as sup

    from cmm.journal.store import open_session
    from cmm.measurement.routine import teach_routine
    from cmm.measurement.routine_host import StationRoutineHost
    from cmm.measurement.routine_run import RoutineCancelled, RoutineRun

    mqtt_url, got = broker
    st = stations.station("teach", session_dir=tmp_path / "sessions")
    notifier = None
    try:
        model = st.measurement
        sup.teach_block(model, sup.BLOCK_FACES[:3])  # the datum planes: a routine with characteristics, kept short
        routine = teach_routine(open_session(model.journal.path), name="block", part_mesh=model.part.mesh,
                                part_nominals=model.part.nominal_features)
        routine.steps[0]["manual"] = None  # the part is aligned: the datums are measured automatically
        assert model.trends is None
        notifier = Notifier(NotifyConfig(webhook=webhook.url, mqtt=mqtt_url, station="bench-10",
                                         events=("run_end",))).attach(model)
        progress = RoutineRun(routine, StationRoutineHost(model, st.controller), part_name="P-17").run()
        assert progress.state == "done"
        ((_, m),) = _take(webhook.got, 1)
        ((topic, published),) = _take(got, 1)
        assert m["event"] == "run_end" and m["program"] == "block" and m["serial"] == "P-17"
        assert m["verdict"] in ("PASS", "FAIL", "INCOMPLETE") and m["characteristics"] > 0
        assert m["part"] == model.part.name and m["session"] == Path(str(progress.session)).stem
        assert m["report"] == (tmp_path / "sessions" / f"{m['session']}-report.html").resolve().as_uri()
        assert topic == "cmm/bench-10/run_end" and published == m
        cancelled = RoutineRun(routine, StationRoutineHost(model, st.controller), part_name="P-18")
        cancelled.cancel()  # the operator cancels before the first hit
        with pytest.raises(RoutineCancelled):
            cancelled.run()
        ((_, s),) = _take(webhook.got, 1)
        assert s["event"] == "run_end" and s["verdict"] == "STOPPED" and s["program"] == "block"
        assert s["serial"] == "P-18" and "cancelled by the operator" in s["message"]
    finally:
        if notifier is not None:
            notifier.close()
        st.close()
