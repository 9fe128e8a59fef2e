"""Pendant jog release -> zero velocity, over the real WebSocket, against the real-time simulator.

For each trial: take control, jog one axis through the pendant protocol (a jog message every 50 ms,
as pendant.js does) until it runs at speed, then send {"type": "release"} and time until every
axis reports zero velocity (a station state subscriber timestamps the first all-zero sample).
The same for a pendant that just goes silent (the dead-man path) and for a closed connection.
Then the pendant's state update rate as a client sees it.

    python benchmarks/bench_jog_release.py [--trials 10]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import threading
import time

from websockets.sync.client import connect

from cmm.station import Station
from cmm.ui.access import Control
from cmm.ui.pendant import start_pendant_server


class StopWatch:
    """Timestamps (monotonic) the first state sample with all axes at zero velocity after ``arm()``."""

    def __init__(self, station: Station) -> None:
        self.event = threading.Event()
        self.armed_at: float | None = None
        self.stopped_at: float | None = None
        station.subscribe_state(self._on_state)

    def arm(self, at: float | None = None) -> float:
        self.stopped_at = None
        self.event.clear()
        self.armed_at = time.monotonic() if at is None else at
        return self.armed_at

    def _on_state(self, state) -> None:
        if self.armed_at is not None and self.stopped_at is None and all(a.velocity == 0 for a in state.axes):
            self.stopped_at = time.monotonic()
            self.event.set()

    def wait(self, timeout: float = 3.0) -> float:
        if not self.event.wait(timeout):
            raise RuntimeError("the machine did not stop")
        assert self.armed_at is not None and self.stopped_at is not None
        t = self.stopped_at - self.armed_at
        self.armed_at = None
        return t


def open_pendant(url: str):
    """A pendant connection whose incoming state messages are read (and dropped) in the background:
    a client that stops reading cannot answer the server's keepalive pings and is disconnected."""
    ws = connect(url)

    def drain() -> None:
        try:
            for _ in ws:
                pass
        except Exception:  # noqa: BLE001 - closed
            pass

    threading.Thread(target=drain, daemon=True).start()
    return ws


def jog_until_running(ws, station: Station, v: list[float], seconds: float = 0.3) -> float:
    """Jog for ``seconds`` with a message every 50 ms; returns the time of the last message."""
    end = time.monotonic() + seconds
    while True:
        ws.send(json.dumps({"type": "jog", "v": v}))
        last = time.monotonic()
        if last > end:
            return last
        time.sleep(0.05)


def summary(name: str, values: list[float]) -> None:
    ms = sorted(v * 1000 for v in values)
    print(f"{name:44s} n={len(ms):3d}  median {statistics.median(ms):6.1f} ms  max {ms[-1]:6.1f} ms  "
          f"min {ms[0]:6.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        station = Station(session_dir=tmp).start(home=True)
        control = Control(on_holder_lost=lambda _cid: station.jog_release())
        server = start_pendant_server(station, control)
        watch = StopWatch(station)
        station.move_to([250.0, 200.0, 150.0]).wait(60)  # mid-travel: room to jog both ways
        speeds = station.config.speeds
        print(f"machine: jog_fast {speeds.jog_fast:g} mm/s, jog_slow {speeds.jog_slow:g} mm/s, "
              f"stop deceleration {station.config.accelerations.stop:g} mm/s^2, "
              f"machine dead-man {station.config.deadman_timeout * 1000:.0f} ms, pendant dead-man "
              f"{server.deadman * 1000:.0f} ms")
        try:
            ws = open_pendant(server.ws_url)
            ws.send(json.dumps({"type": "take"}))
            results: dict[str, list[float]] = {}
            for speed_name in ("jog_fast", "jog_slow"):
                speed = getattr(speeds, speed_name)
                key = f"release at {speed_name} ({speed:g} mm/s)"
                for i in range(args.trials):
                    sign = 1 if i % 2 == 0 else -1  # back and forth, staying inside the travel
                    jog_until_running(ws, station, [sign * speed, sign * speed, 0])
                    watch.arm()
                    ws.send(json.dumps({"type": "release"}))
                    results.setdefault(key, []).append(watch.wait())
                    time.sleep(0.1)
            key = "silent pendant at jog_fast (dead-man)"
            for i in range(args.trials):
                sign = 1 if i % 2 == 0 else -1
                last = jog_until_running(ws, station, [sign * speeds.jog_fast, 0, 0])
                watch.arm(at=last)  # nothing more comes after the last jog message
                results.setdefault(key, []).append(watch.wait())
                time.sleep(0.1)
            ws.close()
            key = "closed connection at jog_fast"
            for i in range(max(3, args.trials // 2)):
                c = open_pendant(server.ws_url)
                c.send(json.dumps({"type": "take"}))
                sign = 1 if i % 2 == 0 else -1
                jog_until_running(c, station, [sign * speeds.jog_fast, 0, 0])
                watch.arm()
                c.close()
                results.setdefault(key, []).append(watch.wait())
                time.sleep(0.1)
            print("time from the last pendant message to zero velocity on every axis:")
            for name, values in results.items():
                summary(name, values)

            # state update rate as a pendant sees it, with two pendants connected
            clients = [connect(server.ws_url) for _ in range(2)]
            stamps: list[float] = []
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                try:
                    msg = json.loads(clients[0].recv(timeout=0.5))
                except TimeoutError:
                    continue
                if msg.get("type") == "state":
                    stamps.append(time.monotonic())
                try:
                    while True:
                        clients[1].recv(timeout=0)
                except TimeoutError:
                    pass
            gaps = [b - a for a, b in zip(stamps, stamps[1:])]
            rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
            print(f"pendant state updates: {rate:.1f} Hz (target {server.state_hz:g} Hz); interval median "
                  f"{statistics.median(gaps) * 1000:.1f} ms, max {max(gaps) * 1000:.1f} ms")
            for c in clients:
                c.close()
        finally:
            server.close()
            station.close()


if __name__ == "__main__":
    main()
