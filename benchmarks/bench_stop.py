"""STOP and E-STOP during a Go to at the fastest speed -> deceleration and standstill, per front end, under load.

Target: press-to-standstill p99 <= 0.3 s (the deceleration itself included) on the page and the pendant,
with 2 CPU hogs per core and 20 observer tabs.

The machinery is bench_jog_release.py's (reused from it): four processes as in use, the simulated CMM (real time,
served over TCP; it keeps the stop-watch on its own servo ticks), the station (``Station`` on ``socket://...`` with
the viser UI and the pendant server, at the priority ``cmm serve`` gives it), the observer browsers (viser
WebSocket clients at normal priority) and this script, which plays the operator.

Each trial: a Go to along X at the fastest speed (``speeds.positioning``, through the command API's ``move`` verb),
and once the simulator sees X at >= 90 % of that speed the operator presses:

- **page**: the station page's STOP / E-STOP button as the page sends it now: its hold refresher
  (web/hold_worker.js, a Web Worker) sends ``{"type": "stop"}`` / ``{"type": "estop"}`` over its own WebSocket to
  the pendant port with the page's grant, on pointer-down;
- **page (viser click)**: the same button's click over viser's own WebSocket (the fallback when the refresher's
  socket is not open; what every press took before);
- **pendant**: the pendant page's STOP / E-STOP (``{"type": "stop"}`` / ``{"type": "estop"}``).

Timed on the simulator's clock from the press (CLOCK_MONOTONIC, shared by the processes): **press-to-deceleration**,
the first servo tick after which X runs below 90 % of its speed at the press; **press-to-standstill**, the first
tick after which no axis moves more than 2 counts (4 um) in 10 ms; **travel**, mm of X from the press to standstill.
After an E-STOP the operator presses Reset before the next Go to.

    python benchmarks/bench_stop.py [--presses 10] [--observers 20] [--hogs 4] [--fronts page,pendant,viser]
                                    [--idle] [--link-process same]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_jog_release as jr  # noqa: E402 - the shared machinery (processes, observers, hogs, viser page)
from cmm.sim.network import TICK_NS  # noqa: E402

FRONTS = {"page": "page", "pendant": "pendant", "viser": "page (viser click)"}


# --- the simulator process ---------------------------------------------------------------------------------

class PressWatch:
    """A tick hook: X speed now, and after ``arm(ns)`` when X slowed below 90 % and when every axis stood still."""

    def __init__(self, network, counts_per_mm: float) -> None:  # noqa: ANN001
        self.net = network
        self.cpm = counts_per_mm
        self.history: collections.deque = collections.deque(maxlen=400)  # (ns, X count), ~0.2 s
        self.armed_ns: int | None = None
        self.after: list[tuple[int, tuple[int, int, int]]] = []
        network.add_tick_hook(self)

    def speed(self) -> float:
        """X speed (mm/s) over the last 20 ms of ticks."""
        h = [x for x in self.history]
        if len(h) < 2:
            return 0.0
        end = h[-1]
        start = next(((t, c) for t, c in h if t >= end[0] - 20_000_000), h[0])
        return 0.0 if end[0] == start[0] else abs(end[1] - start[1]) / self.cpm / ((end[0] - start[0]) / 1e9)

    def arm(self, ns: int) -> float:
        self.after = []
        at = self.speed()
        self.armed_ns = ns
        return at

    def __call__(self, net, tick) -> None:  # noqa: ANN001
        now = (tick + 1) * TICK_NS
        self.history.append((now, net.plants[0].count))
        if self.armed_ns is not None and now >= self.armed_ns - 20_000_000 and len(self.after) < 20_000:
            self.after.append((now, tuple(p.count for p in net.plants[:3])))

    def result(self, v0: float) -> tuple[float, float, float] | None:
        """(press-to-deceleration s, press-to-standstill s, X travel mm) or None when it has not stood still yet."""
        a, t0 = self.after, self.armed_ns
        if not a or a[-1][0] - t0 < 60_000_000:
            return None
        decel = None
        for i, (t, c) in enumerate(a):  # X speed over 5 ms windows ending after the press
            if t < t0:
                continue
            j = next((k for k in range(i, -1, -1) if t - a[k][0] >= 5_000_000), None)
            if j is None:
                continue
            v = abs(c[0] - a[j][1][0]) / self.cpm / ((t - a[j][0]) / 1e9)
            if v < 0.9 * v0:
                decel = (a[j][0] + t) / 2 - t0
                break
        still = None
        for i, (t, c) in enumerate(a):
            if t < t0:
                continue
            window = [x for x in a[i:] if x[0] - t <= jr.STILL_NS]
            if window[-1][0] - t < jr.STILL_NS - 1_000_000:
                return None  # not enough ticks yet
            if all(max(x[1][k] for x in window) - min(x[1][k] for x in window) <= jr.STILL_COUNTS for k in range(3)):
                still = t - t0
                break
        if still is None:
            return None
        x0 = next(c[0] for t, c in a if t >= t0)
        xs = next(c[0] for t, c in a if t >= t0 + still)
        return (max(decel if decel is not None else still, 0) / 1e9, max(still, 0) / 1e9, abs(xs - x0) / self.cpm)


def run_sim() -> None:
    from cmm.control.priority import raise_thread_priority
    from cmm.machine.config import load
    from cmm.sim.cmm_sim import SimulatedCMM
    from cmm.sim.home_switches import HomeSwitches
    from cmm.sim.serve import serve_tcp

    raised = raise_thread_priority()
    config = load()
    sim = SimulatedCMM(config, wire_time=True, realtime=True)
    HomeSwitches(sim, config.homing.input, config.homing.active_level == "high")
    served = serve_tcp(sim.network, "127.0.0.1", 0)
    watch = PressWatch(sim.network, config.axes[0].counts_per_mm)
    print("url", served.url, "raised" if raised else "normal", flush=True)

    def sync() -> None:
        with served.lock:
            sim.network.sync()
    for line in sys.stdin:
        cmd = line.split()
        if cmd and cmd[0] == "speed":
            sync()
            with served.lock:
                print("speed", f"{watch.speed():.3f}", flush=True)
        elif cmd and cmd[0] == "arm":  # the press instant, CLOCK_MONOTONIC ns in the operator's process
            with served.lock:
                v0 = watch.arm(sim.network.wall_ns() - (time.perf_counter_ns() - int(cmd[1])))
            end, got = time.monotonic() + 5.0, None
            while got is None and time.monotonic() < end:
                sync()
                with served.lock:
                    got = watch.result(v0)
                time.sleep(0.005)
            watch.armed_ns = None
            print("stop", "timeout" if got is None else " ".join(f"{x:.6f}" for x in got), f"{v0:.3f}", flush=True)
        elif cmd and cmd[0] == "quit":
            break
    served.close()


# --- the operator (this process) ----------------------------------------------------------------------------

class Proc(jr.Proc):
    def __init__(self, *args: str) -> None:  # noqa: D107 - this script's roles, bench_jog_release's pipes
        self.p = subprocess.Popen([sys.executable, "-u", __file__, *args], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)


class Caller:
    """A pendant-protocol socket that sends verbs (``call``) and waits for their answers."""

    def __init__(self, ws) -> None:  # noqa: ANN001
        self.ws = ws
        self.ids = iter(range(1, 10**9))

    def call(self, method: str, **params) -> dict:  # noqa: ANN003
        n = next(self.ids)
        self.ws.send(json.dumps({"type": "call", "id": n, "method": method, "params": params}))
        return {"id": n}


def reading_ws(url: str):
    """A WebSocket whose messages are read in the background; the last 'result' answers kept by id."""
    from websockets.sync.client import connect

    ws = connect(url)
    ws.results = {}  # type: ignore[attr-defined]

    def drain() -> None:
        try:
            for raw in ws:
                try:
                    msg = json.loads(raw)
                except (TypeError, ValueError):
                    continue
                if msg.get("type") == "result":
                    ws.results[msg.get("id")] = msg  # type: ignore[attr-defined]
        except Exception:  # noqa: BLE001 - closed
            pass
    threading.Thread(target=drain, daemon=True).start()
    return ws


class PendantFront:
    name = "pendant"

    def __init__(self, url: str) -> None:
        self.ws = reading_ws(url)
        self.ws.send(json.dumps({"type": "hello"}))

    def take(self) -> None:
        self.ws.send(json.dumps({"type": "take"}))
        time.sleep(0.5)

    def press(self, verb: str) -> None:
        self.ws.send(json.dumps({"type": verb}))


class PageFront:
    """The station page (bench_jog_release's ViserPage: viser's socket plus the hold refresher's): the press as the
    page sends it now (the refresher's socket), or as viser's click (``viser``)."""

    def __init__(self, port: int, viser: bool = False) -> None:
        self.page = jr.ViserPage(port)
        self.viser = viser
        self.name = FRONTS["viser" if viser else "page"]
        self.ws = self.page.refresher

    def take(self) -> None:
        self.page.take()

    def press(self, verb: str) -> None:
        if self.viser:
            self.page.click("STOP" if verb == "stop" else "E-STOP")
        else:
            self.ws.send(json.dumps({"type": verb}))


def ensure_labels(front) -> None:  # noqa: ANN001
    if isinstance(front, PageFront):
        end = time.monotonic() + 30
        while not {"STOP", "E-STOP"} <= set(front.page.uuids) and time.monotonic() < end:
            time.sleep(0.05)


def trials(front, sim: Proc, presses: int, fast: float, x_lo: float, x_hi: float) -> dict:  # noqa: ANN001
    """Per verb: [(press-to-deceleration s, press-to-standstill s, travel mm, speed at press mm/s)]."""
    out: dict[str, list] = {"stop": [], "estop": []}
    front.take()
    caller = Caller(front.ws)
    n = 0
    for i in range(presses):
        for verb in out:
            caller.call("reset")
            time.sleep(0.3)
            target = [x_hi if n % 2 == 0 else x_lo, 200.0, 250.0]
            n += 1
            caller.call("move", target=target, frame="machine", path="straight")
            end = time.monotonic() + 10
            while time.monotonic() < end:
                sim.send("speed")
                if float(sim.expect("speed")[0]) >= 0.9 * fast:
                    break
                time.sleep(0.01)
            else:
                print(f"  {front.name}: the Go to never reached speed; trial skipped")
                continue
            time.sleep(0.05)
            t = time.perf_counter_ns()
            front.press(verb)
            sim.send(f"arm {t}")
            got = sim.expect("stop")
            if got[0] == "timeout":
                out[verb].append((float("inf"), float("inf"), float("inf"), float(got[-1])))
            else:
                out[verb].append((float(got[0]), float(got[1]), float(got[2]), float(got[3])))
            time.sleep(0.2)
    caller.call("reset")
    time.sleep(0.3)
    return out


def summary(name: str, verb: str, rows: list) -> str:
    if not rows:
        return f"{name:20s} {verb.upper():6s} no trials"
    d = [r[0] * 1000 for r in rows]
    s = [r[1] * 1000 for r in rows]
    tr = [r[2] for r in rows]
    return (f"{name:20s} {verb.upper():6s} n={len(rows):3d}  press->decel p50 {statistics.median(d):6.1f} p99 "
            f"{jr.pct(d, 0.99):6.1f} ms | press->standstill p50 {statistics.median(s):6.1f} p99 {jr.pct(s, 0.99):6.1f}"
            f" max {max(s):6.1f} ms | travel p50 {statistics.median(tr):5.2f} max {max(tr):5.2f} mm "
            f"(speed at press {statistics.median(r[3] for r in rows):4.1f} mm/s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presses", type=int, default=10, help="presses per front end and verb")
    ap.add_argument("--observers", type=int, default=20)
    ap.add_argument("--hogs", type=int, default=2 * (os.cpu_count() or 1))
    ap.add_argument("--fronts", default="page,pendant,viser")
    ap.add_argument("--idle", action="store_true", help="also a round without hogs and observers first")
    ap.add_argument("--link-process", choices=("auto", "same"), default="auto")
    ap.add_argument("--role", choices=("sim", "station", "observers"), help=argparse.SUPPRESS)
    ap.add_argument("--url", help=argparse.SUPPRESS)
    ap.add_argument("--sessions", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role == "sim":
        return run_sim()
    if args.role == "station":
        return jr.run_station(args.url, args.sessions, "none", 0, args.link_process)
    if args.role == "observers":
        clients = [jr.viser_observer(int(args.url)) for _ in range(args.observers)]
        print("connected", len(clients), flush=True)
        for text in sys.stdin:
            if text.strip() == "quit":
                break
        for c in clients:
            c.close()
        return None
    from cmm.control.priority import raise_thread_priority
    from cmm.machine.config import load

    print(f"operator's front ends at {'raised' if raise_thread_priority() else 'normal'} priority")
    config = load()
    fast = float(config.speeds.positioning)
    x = config.axes[0]
    lo, hi = x.min + 40.0, x.max - 40.0
    with tempfile.TemporaryDirectory() as tmp:
        sim = Proc("--role", "sim")
        station = observers = None
        hogs: list = []
        try:
            url, sim_priority = sim.expect("url")
            print(f"simulator at {sim_priority} priority")
            station = Proc("--role", "station", "--url", url, "--sessions", tmp, "--link-process", args.link_process)
            viser_port, pendant_url = station.expect("ready")
            fronts = []
            for f in args.fronts.split(","):
                fronts.append(PendantFront(pendant_url) if f == "pendant" else PageFront(int(viser_port), f == "viser"))
            for f in fronts:
                ensure_labels(f)
            print(f"Go to along X at {fast:g} mm/s (positioning), pressed at >= 90 % of it; simulated machine time:")
            if args.idle:
                for f in fronts:
                    res = trials(f, sim, args.presses, fast, lo, hi)
                    for verb, rows in res.items():
                        print("  idle        " + summary(f.name, verb, rows))
            observers = Proc("--role", "observers", "--url", viser_port, "--observers", str(args.observers))
            observers.expect("connected")
            hogs = jr.start_hogs(args.hogs)
            time.sleep(3.0)
            loaded = {f.name: trials(f, sim, args.presses, fast, lo, hi) for f in fronts}
            load_avg = os.getloadavg()[0]
            jr.stop_hogs(hogs)
            hogs = []
            for name, res in loaded.items():
                for verb, rows in res.items():
                    print("  under load  " + summary(name, verb, rows))
            print(f"  load: {args.hogs} CPU hogs, {args.observers} observer tabs; host load average {load_avg:.1f} "
                  f"on {os.cpu_count()} cores")
            for name, res in loaded.items():
                if name == FRONTS["viser"]:
                    continue
                worst = max((jr.pct([r[1] for r in rows], 0.99) for rows in res.values() if rows), default=float("inf"))
                print(f"target {name}: press-to-standstill p99 <= 300 ms under load (STOP and E-STOP) -> "
                      f"{worst * 1000:.1f} ms ({'met' if worst <= 0.3 else 'NOT met'})")
        finally:
            if hogs:
                jr.stop_hogs(hogs)
            if observers is not None:
                observers.close()
            if station is not None:
                station.close()
            sim.close()


if __name__ == "__main__":
    main()
