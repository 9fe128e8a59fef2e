"""Jog release -> machine standing still, idle and under web load (issue 12 item 5: p99 <= 0.2 s).

The station runs the built-in simulated CMM in real time over TCP (``cmm serve``'s default) with the
viser UI and the pendant server. A pendant client jogs one axis at jog_fast through the pendant protocol
(a jog message every 50 ms, as pendant.js does) until it runs at speed, then either sends
{"type": "release"} or just goes silent (the dead-man path). The stop is timed on the simulator's own
clock: from the moment the release was sent to the first servo tick after which every module reports
zero velocity for 20 ms. So a station that is slow to *see* the stop does not hide a machine that is slow
to stop.

Load phase: 20 observer browsers (viser WebSocket clients that receive the scene and their panels) are
connected, and worker threads keep opening a 200,000-hit session journal and rendering its report in
the station process, as an observer opening a large session does.

    python benchmarks/bench_jog_release.py [--trials 30] [--observers 20] [--hits 200000]
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import tempfile
import threading
import time
from pathlib import Path

from websockets.sync.client import connect

from cmm.session.journal import encode_event
from cmm.session.report import render
from cmm.session.store import DirectoryStore, load_session
from cmm.station import Station
from cmm.ui.app import StationApp

ZERO_FOR_NS = 20_000_000  # every module at zero velocity this long = standing still


class SimStopWatch:
    """A tick hook on the simulated network: when, in simulated time, did every axis stop after ``arm()``."""

    def __init__(self, network) -> None:  # noqa: ANN001 - cmm.sim.network.SimNetwork
        self.net = network
        self.armed_ns: int | None = None
        self.zero_since: int | None = None
        self.stop_ns: int | None = None
        network.add_tick_hook(self)

    def arm(self) -> None:
        self.zero_since = self.stop_ns = None
        self.armed_ns = self.net.wall_ns()

    def __call__(self, net, tick) -> None:  # noqa: ANN001
        if self.armed_ns is None or self.stop_ns is not None or net.now_ns < self.armed_ns:
            return
        if all(m.velocity == 0 for m in net.modules[:3]):
            if self.zero_since is None:
                self.zero_since = net.now_ns
            elif net.now_ns - self.zero_since >= ZERO_FOR_NS:
                self.stop_ns = self.zero_since
        else:
            self.zero_since = None

    def wait(self, timeout: float = 5.0) -> float:
        end = time.monotonic() + timeout
        while self.stop_ns is None:
            z = self.zero_since  # idle ticks may be skipped once all is quiet
            if z is not None and self.net.wall_ns() - z > 2 * ZERO_FOR_NS:
                self.stop_ns = z
                break
            if time.monotonic() > end:
                raise RuntimeError("the machine did not stop")
            time.sleep(0.002)
        assert self.armed_ns is not None
        t = (self.stop_ns - self.armed_ns) / 1e9
        self.armed_ns = None
        return t


def open_ws(url: str, **kw):
    """A WebSocket whose incoming messages are drained in the background (a reading browser)."""
    ws = connect(url, **kw)

    def drain() -> None:
        try:
            for _ in ws:
                pass
        except Exception:  # noqa: BLE001 - closed
            pass

    threading.Thread(target=drain, daemon=True).start()
    return ws


def viser_observer(port: int):
    import msgspec
    import viser
    from viser import _messages

    ws = open_ws(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
    camera = _messages.ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, 0.01, 100.0, 600, 800,
                                           (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
    return ws


def write_big_session(root: Path, hits: int) -> str:
    """A session journal with ``hits`` hits (written without fsync: it only has to exist)."""
    rng = random.Random(1)
    name = f"big-{hits}"
    start = {"config": "default", "tip_radius": 1.0, "pretravel": {"const": 0.0}, "part": "p",
             "part_pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
             "axes": [{"name": n, "counts_per_mm": 500.0, "direction": 1, "home": h, "min": 0.0, "max": 500.0}
                      for n, h in (("x", 0.0), ("y", 0.0), ("z", 300.0))]}
    with open(root / f"{name}.jsonl", "w") as f:
        f.write(encode_event({"seq": 1, "time": time.time(), "kind": "start", **start}) + "\n")
        for k in range(1, hits + 1):
            c = [rng.randint(0, 250000), rng.randint(0, 200000), rng.randint(-150000, 0)]
            m = [c[0] / 500, c[1] / 500, 300 + c[2] / 500]
            f.write(encode_event({"seq": k + 1, "time": time.time(), "kind": "hit", "id": k, "counts": c,
                                  "machine": m, "approach": [0.0, 0.0, -1.0], "speed": 2.0, "hit_time": time.time(),
                                  "point": [m[0], m[1], m[2] - 1.0], "mode": "programmed", "normal": None}) + "\n")
    return name


def jog(ws, v: list[float], seconds: float = 0.3) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ws.send(json.dumps({"type": "jog", "v": v}))
        time.sleep(0.05)
    ws.send(json.dumps({"type": "jog", "v": v}))


def run_trials(ws, station: Station, watch: SimStopWatch, trials: int) -> dict[str, list[float]]:
    fast = station.config.speeds.jog_fast
    out: dict[str, list[float]] = {"release": [], "silent (dead-man)": []}
    for i in range(trials):
        for kind in out:
            sign = 1 if (i + len(out[kind])) % 2 == 0 else -1  # back and forth inside the travel
            jog(ws, [sign * fast, 0.0, 0.0])
            watch.arm()
            if kind == "release":
                ws.send(json.dumps({"type": "release"}))
            out[kind].append(watch.wait())
            time.sleep(0.1)
    return out


def line(name: str, values: list[float]) -> str:
    ms = sorted(v * 1000 for v in values)
    p99 = ms[min(len(ms) - 1, int(round(0.99 * (len(ms) - 1))))]
    return (f"{name:34s} n={len(ms):3d}  median {statistics.median(ms):6.1f} ms  p99 {p99:6.1f} ms  "
            f"max {ms[-1]:6.1f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--observers", type=int, default=20)
    ap.add_argument("--hits", type=int, default=200_000)
    ap.add_argument("--loaders", type=int, default=2, help="threads opening + reporting the big session")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        big = write_big_session(root, args.hits)
        print(f"{args.hits:,}-hit session written in {time.perf_counter() - t0:.1f} s "
              f"({(root / f'{big}.jsonl').stat().st_size / 1e6:.0f} MB)")
        station = Station(session_dir=root).start(home=True)
        app = StationApp(station, port=0, pendant_port=0)
        cfg = station.config
        print(f"machine: jog_fast {cfg.speeds.jog_fast:g} mm/s, jog mode {cfg.jog.mode} "
              f"(horizon {cfg.jog.horizon * 1000:.0f} ms of travel), dead-man {cfg.deadman_timeout * 1000:.0f} ms, "
              f"accelerations jog {cfg.accelerations.jog:g} / stop {cfg.accelerations.stop:g} mm/s^2")
        watch = SimStopWatch(station.sim.network)
        stop_load = threading.Event()
        loads = {"opened": 0, "reported": 0}
        try:
            station.move_to([250.0, 200.0, 150.0]).wait(60)
            ws = open_ws(app.pendant.ws_url)
            ws.send(json.dumps({"type": "take"}))
            time.sleep(0.3)
            idle = run_trials(ws, station, watch, args.trials)
            print("release -> every axis standing still (simulated machine time), idle:")
            for k, v in idle.items():
                print("  " + line(k, v))

            observers = [viser_observer(app.port) for _ in range(args.observers)]

            def loader() -> None:
                store = DirectoryStore(root)
                while not stop_load.is_set():
                    session = load_session(store, big)
                    loads["opened"] += 1
                    render(session)
                    loads["reported"] += 1

            threads = [threading.Thread(target=loader, daemon=True) for _ in range(args.loaders)]
            for t in threads:
                t.start()
            time.sleep(3.0)  # let the observers' pages build and the loaders get going
            t_load = time.perf_counter()
            loaded = run_trials(ws, station, watch, args.trials)
            dt = time.perf_counter() - t_load
            print(f"under load: {len(app.clients)} viser clients connected, {args.loaders} threads opening + "
                  f"reporting the {args.hits:,}-hit session ({loads['opened']} opened, {loads['reported']} reported "
                  f"during the whole phase, {dt:.0f} s):")
            for k, v in loaded.items():
                print("  " + line(k, v))
            allv = loaded["release"] + loaded["silent (dead-man)"]
            p99 = sorted(allv)[min(len(allv) - 1, int(round(0.99 * (len(allv) - 1))))]
            print(f"target: p99 <= 200 ms under load -> {p99 * 1000:.1f} ms "
                  f"({'met' if p99 <= 0.2 else 'NOT met'})")
            for o in observers:
                o.close()
            ws.close()
        finally:
            stop_load.set()
            app.close()
            station.close()


if __name__ == "__main__":
    main()
