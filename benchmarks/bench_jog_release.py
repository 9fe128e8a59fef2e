"""Jog release and silent front end -> machine standing still, idle and under load, on the pendant and the viser page.

Targets (under load: CPU hogs, 20 observers, a 200k-hit report being built): release p99 <= 0.2 s, and a
front end that goes silent (no refresh, no release) stopped within 0.3 s p99, on both front ends.

Priorities: the station runs as `cmm serve` runs it: at raised priority (nice -10, see
cmm/control/priority.py; its session worker at nice 5). The simulator and this pendant client stand in for devices with processors of
their own (the modules, the operator's phone), so they run at that raised priority too; the observer
browsers run at normal priority on the same cores. Each run prints the host's load average.

Four processes, as in use: the simulated CMM (real time, served over TCP, with home switches; it
stands in for the hardware and keeps the stop-watch), the station (``Station`` on
``socket://...`` with the viser UI and the pendant server), the observer browsers, and this script,
which plays the operator's pendant. A pendant client jogs X at jog_fast through the pendant protocol (a jog message every
50 ms, as pendant.js does) until it runs at speed, then either sends {"type": "release"} or just
goes silent (the dead-man path). The stop is timed on the simulator's clock: from the moment the
release was sent (CLOCK_MONOTONIC, shared by the processes) to the first servo tick after which
no axis moves more than 2 counts (4 um) in 10 ms.

Two front ends play the operator in turn, both through the core's jog-hold pipeline: the pendant page
(its JSON WebSocket: a jog message every 50 ms) and the viser page (viser's own WebSocket: "Take control",
then the "hold X +" / "hold X −" button's hold events at 25 Hz, as the browser sends them while the button
is pressed, and the button's click event, which viser sends on release; beside them the page's hold
refresher, web/hold_worker.js, which the page runs in a Web Worker: "hold" messages every 40 ms on the
pendant port with the page's refresher grant, read from the script the station sends the page). A silent trial sends neither a
release nor any more refreshes: the stop is timed from the last refresh sent.

Load phase: ``--hogs`` CPU hogs (busy loops at normal priority; default 2 per core, as a shop-floor PC
running a CAD viewer and a virus scan beside the station) and 20 observer browsers (viser WebSocket clients that receive the scene and their panels)
are connected (each tab lists the sessions, with their hit counts), and one observer's Sessions tab
keeps opening the 200,000-hit session for replay and writing its report, through the tab's own
handlers (``SessionsPanel.open`` / ``.report``: the replay is built in the station process, the report
is rendered by the session worker process), as an observer opening a large session does. The trials go on
(up to 3 min) until a report is written; the load counts as applied when a report was written or one was being
built when the trials ended (beside the hogs the worker, at nice 5, can take longer than that).
Times are the simulator's: a tick's own time (index x 0.512 ms), not the served network's clock, which a batch
of ticks run at once to catch up with the wall clock reads as the batch's start for every tick of it.
The speed at the release is measured too (on the simulator's clock): a starved station that never gets
the jog up to speed stops "fast" for the wrong reason, so the p99 is also given over the releases made
at >= 90 % of jog_fast, and the target needs both (and at least half the jogs at full speed).

On ``socket://`` the station drives the link through its link process (cmm/nmc/link_process.py), as on
hardware; ``--link-process same`` keeps the bus in the station's process, to compare in one sitting.

    python benchmarks/bench_jog_release.py [--trials 30] [--observers 20] [--hits 200000] [--hogs 4]
                                          [--link-process same]
"""

from __future__ import annotations

import argparse
import collections
import json
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from websockets.sync.client import connect

from cmm.sim.network import TICK_NS

STILL_COUNTS = 2  # no axis moves more than this ...
STILL_NS = 10_000_000  # ... in this long: standing still
DEBUG = bool(__import__("os").environ.get("BENCH_DEBUG"))


# --- the simulator process ---------------------------------------------------------------------------------

class SimStopWatch:
    """A tick hook: when, in simulated time, was every axis standing still after ``arm(ns)``."""

    def __init__(self, network, counts_per_mm: float) -> None:  # noqa: ANN001 - cmm.sim.network.SimNetwork
        self.net = network
        self.counts_per_mm = counts_per_mm
        self.armed_ns: int | None = None
        self.window: collections.deque = collections.deque()
        self.history: collections.deque = collections.deque(maxlen=4000)  # (ns, X count), last ~2 s
        self.stop_ns: int | None = None
        self.last_tick_ns = 0
        network.add_tick_hook(self)

    def speed_at_release(self) -> float:
        """X speed (mm/s) over the 20 ms before the release: did the jog run at speed when it was released?"""
        before = [(t, c) for t, c in self.history if t <= self.armed_ns]
        if len(before) < 2:
            return float("nan")
        end = before[-1]
        start = next(((t, c) for t, c in before if t >= end[0] - 20_000_000), before[0])
        if end[0] == start[0]:
            return float("nan")
        return abs(end[1] - start[1]) / self.counts_per_mm / ((end[0] - start[0]) / 1e9)

    def arm(self, ns: int) -> None:
        self.trace = []
        self.window.clear()
        self.stop_ns = None
        self.armed_ns = ns

    def __call__(self, net, tick) -> None:  # noqa: ANN001
        now = (tick + 1) * TICK_NS  # this tick's end (net.now_ns is where the batch of ticks started)
        self.last_tick_ns = now
        self.history.append((now, net.plants[0].count))
        if self.armed_ns is None or self.stop_ns is not None:
            return
        w = self.window
        w.append((now, tuple(p.count for p in net.plants[:3])))
        if DEBUG:
            self.trace.append((now, net.plants[0].count))
        while w and now - w[0][0] > STILL_NS:
            w.popleft()
        if now - STILL_NS < self.armed_ns or now - w[0][0] < STILL_NS - 1_000_000:
            return
        for i in range(3):
            c = [s[1][i] for s in w]
            if max(c) - min(c) > STILL_COUNTS:
                return
        self.stop_ns = w[0][0]

    def wait(self, sync, timeout: float = 5.0) -> float | None:  # noqa: ANN001
        end = time.monotonic() + timeout
        while self.stop_ns is None:
            sync()  # the served network ticks in batches when the host talks: catch it up with the wall clock
            if time.monotonic() > end:
                return None
            time.sleep(0.001)
        assert self.armed_ns is not None
        return max(0, self.stop_ns - self.armed_ns) / 1e9


def run_sim() -> None:
    from cmm.control.priority import raise_thread_priority
    from cmm.machine.config import load
    from cmm.sim.cmm_sim import SimulatedCMM
    from cmm.sim.home_switches import HomeSwitches
    from cmm.sim.serve import serve_tcp

    # the simulator stands in for the modules, whose processors do not share the station's CPU: like the
    # machine loop it runs ahead of other work (its threads inherit this), so a busy PC does not delay the replies
    raised = raise_thread_priority()
    config = load()
    sim = SimulatedCMM(config, wire_time=True, realtime=True)
    HomeSwitches(sim, config.homing.input, config.homing.active_level == "high")
    served = serve_tcp(sim.network, "127.0.0.1", 0)
    watch = SimStopWatch(sim.network, config.axes[0].counts_per_mm)
    print("url", served.url, "raised" if raised else "normal", flush=True)
    for line in sys.stdin:
        cmd = line.split()
        if cmd and cmd[0] == "arm":  # the release instant, CLOCK_MONOTONIC ns in the client process
            with served.lock:
                watch.arm(sim.network.wall_ns() - (time.perf_counter_ns() - int(cmd[1])))

            def sync() -> None:
                with served.lock:
                    sim.network.sync()
            t = watch.wait(sync)
            if DEBUG and t is not None and t > 0.12:
                tr = watch.trace
                print("slow stop:", " ".join(f"{(ns - watch.armed_ns) / 1e6:.0f}:{c}" for ns, c in tr[::20]),
                      file=sys.stderr, flush=True)
            with served.lock:  # the served network ticks in its own thread
                speed = watch.speed_at_release()
            print("stop", "timeout" if t is None else f"{t:.6f}", f"{speed:.3f}", flush=True)
        elif cmd and cmd[0] == "quit":
            break
    served.close()


# --- the station process -------------------------------------------------------------------------------------

def watch_stalls(controller, stop: threading.Event, gap: float = 0.05) -> collections.Counter:  # noqa: ANN001
    """BENCH_DEBUG: when the machine loop has not stepped for ``gap`` s, what the other threads are doing."""
    seen: collections.Counter = collections.Counter()
    last = [time.perf_counter()]
    step = controller.poll

    def poll():  # noqa: ANN202
        now = time.perf_counter()
        if now - last[0] > gap:
            seen[("gap", f"{int((now - last[0]) * 1000) // 25 * 25:4d} ms")] += 1
        last[0] = now
        return step()
    controller.poll = poll

    def sample() -> None:
        me = threading.get_ident()
        names = {t.ident: t.name for t in threading.enumerate()}
        marked = 0.0
        while not stop.wait(0.002):
            t0 = last[0]
            if time.perf_counter() - t0 < gap or t0 == marked:
                continue
            marked = t0
            for ident, frame in sys._current_frames().items():
                if ident == me:
                    continue
                where = []
                while frame is not None and len(where) < 3:
                    where.append(f"{Path(frame.f_code.co_filename).name}:{frame.f_lineno} {frame.f_code.co_name}")
                    frame = frame.f_back
                seen[(names.get(ident, "?"), " < ".join(where))] += 1
    threading.Thread(target=sample, daemon=True).start()
    return seen


def run_station(url: str, sessions: str, big: str, loaders: int, link_process: str) -> None:
    import dataclasses

    from cmm.machine.config import load
    from cmm.station import Station
    from cmm.ui.app import StationApp

    from cmm.control.priority import raise_station_priority

    raise_station_priority()  # as `cmm serve` does, before any thread starts
    config = load()
    config = dataclasses.replace(config, link=dataclasses.replace(config.link, process=link_process))
    station = Station(config, port=url, session_dir=sessions).start(home=True)
    app = StationApp(station.controller.commands, port=0, pendant_port=0)
    station.controller.move(None, [250.0, 200.0, 150.0], frame="machine").wait(60)
    cfg = station.config
    print("ready", app.port, app.pendant.ws_url, flush=True)
    time.sleep(0.2)
    print(f"station: machine loop at {'raised' if station.controller.loop_priority_raised else 'normal'} priority; "
          + ("bus, jog dead-man and release in the link process" if station.machine.guarded else
             "bus, dead-man and release in the station process ([link] process = \"same\")"), flush=True)
    print(f"machine: jog_fast {cfg.speeds.jog_fast:g} mm/s, jog mode {cfg.jog.mode} "
          f"(horizon {cfg.jog.horizon * 1000:.0f} ms of travel), dead-man {cfg.deadman_timeout * 1000:.0f} ms, "
          f"accelerations jog {cfg.accelerations.jog:g} / stop {cfg.accelerations.stop:g} mm/s^2", flush=True)
    counts = {"opened": 0, "reported": 0}
    reporting = [0.0]  # when the report being built now was started (perf_counter), 0: none
    errors: list[str] = []
    stop = threading.Event()
    stalls = watch_stalls(station.controller, stop) if DEBUG else None

    def loader(capp) -> None:  # noqa: ANN001 - an observer's ClientApp
        # what an observer does in the Sessions tab: "Open for replay", then "Report (HTML + CSV)"
        panel = capp.sessions
        while not stop.is_set():
            for what, start in (("opened", panel.open), ("reported", panel.report)):
                job = start(big)
                reporting[0] = time.perf_counter() if what == "reported" and job is not None else 0.0
                ok = job is not None and job.wait(600) and job.error is None
                reporting[0] = 0.0
                if not ok:
                    errors.append(f"{what}:{getattr(job, 'error', None)!r}".replace(" ", "_"))
                    stop.wait(1.0)
                    continue
                counts[what] += 1
            panel.back_to_live()

    for line in sys.stdin:
        cmd = line.split()
        if cmd and cmd[0] == "load":
            observers = [c for c in list(app.clients.values()) if c.client is not None]
            for capp in observers[:loaders]:
                threading.Thread(target=loader, args=(capp,), daemon=True).start()
            print("loading", flush=True)
        elif cmd and cmd[0] == "status":
            stats = getattr(station.machine.bus, "stats", {})
            building = f"{time.perf_counter() - reporting[0]:.0f}" if reporting[0] else "-"
            print("status", len(app.clients), counts["opened"], counts["reported"], building,
                  station.controller.state.mode.value,
                  ",".join(f"{k}={v}" for k, v in stats.items() if k in ("transactions", "retries", "resyncs", "suspect")) or "-",
                  *errors[:3], flush=True)
        elif cmd and cmd[0] == "quit":
            break
    stop.set()
    if stalls:
        print("machine loop stalls > 50 ms: what the other threads were doing", file=sys.stderr)
        for (name, where), n in stalls.most_common(25):
            print(f"  {n:4d} {name}: {where}", file=sys.stderr)
    app.close()
    station.close()


# --- the browsers (this process) --------------------------------------------------------------------------

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


def viser_camera():
    from viser import _messages

    return _messages.ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, 0.01, 100.0, 600, 800,
                                         (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))


def viser_observer(port: int):
    import msgspec
    import viser

    ws = open_ws(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
    ws.send(msgspec.msgpack.encode(viser_camera().as_serializable_dict()))
    return ws


def decode_frame(raw: bytes):
    """viser's wire frame: two little-endian u64 sizes, zstd-compressed msgpack, then raw buffers."""
    import struct

    import msgspec
    import zstandard

    size, packed = struct.unpack_from("<QQ", raw, 0)
    return msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(raw[16:16 + packed], max_output_size=size))


def walk(obj):
    if isinstance(obj, dict):
        yield obj
        for v in obj.values():
            yield from walk(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from walk(v)


def start_hogs(n: int) -> list[subprocess.Popen]:
    """``n`` busy loops at normal priority (other programs on the station PC)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for h in hogs:
        h.kill()
    for h in hogs:
        h.wait()


def write_big_session(root: Path, hits: int) -> str:
    """A session journal with ``hits`` hits (written without fsync: it only has to exist)."""
    from cmm.journal.writer import encode_event

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


class Proc:
    def __init__(self, *args: str) -> None:
        self.p = subprocess.Popen([sys.executable, "-u", __file__, *args], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)

    def send(self, line: str) -> None:
        self.p.stdin.write(line + "\n")
        self.p.stdin.flush()

    def expect(self, word: str) -> list[str]:
        for line in self.p.stdout:
            if line.startswith(word):
                return line.split()[1:]
            if line.startswith(("machine:", "station:")):
                print(line.rstrip())
        raise RuntimeError(f"the child process ended before saying {word!r}")

    def close(self) -> None:
        try:
            self.send("quit")
            self.p.wait(10)
        except Exception:  # noqa: BLE001
            self.p.kill()


class Pendant:
    """The pendant page: jog messages every 50 ms (jog_fast), a release message."""

    name = "pendant"

    def __init__(self, url: str, fast: float) -> None:
        self.ws = open_ws(url)
        self.fast = fast

    def take(self) -> None:
        self.ws.send(json.dumps({"type": "take"}))
        time.sleep(0.5)

    def hold(self, sign: int, seconds: float = 0.3) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ws.send(json.dumps({"type": "jog", "v": [sign * self.fast, 0.0, 0.0]}))
            time.sleep(0.05)
        self.ws.send(json.dumps({"type": "jog", "v": [sign * self.fast, 0.0, 0.0]}))  # the last refresh

    def release(self, sign: int) -> None:
        self.ws.send(json.dumps({"type": "release"}))

    def close(self) -> None:
        self.ws.close()


class ViserPage:
    """The viser page as the browser drives it: "Take control", a jog button's hold events at the page's
    HOLD_HZ while pressed, its click event on release. Speed "positioning" (jog_fast) is chosen first."""

    name = "viser page"

    def __init__(self, port: int) -> None:
        import viser

        from cmm.ui.panel_jog import HOLD_HZ

        self.hz = float(HOLD_HZ)
        self.uuids: dict[str, str] = {}
        self.refresher = None  # the hold refresher's socket to the pendant port (what the page's Web Worker opens)
        self.ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        threading.Thread(target=self._read, daemon=True).start()
        self._send(viser_camera())
        end = time.monotonic() + 60
        while not ({"Take control", "hold X +", "hold X −", "Speed"} <= set(self.uuids) and self.refresher) \
                and time.monotonic() < end:
            time.sleep(0.05)
        from viser import _messages

        self._send(_messages.GuiUpdateMessage(self.uuids["Speed"], {"value": "positioning"}))

    def take(self) -> None:
        self.click("Take control")
        time.sleep(1.0)

    def _read(self) -> None:
        """Read the page's messages (as a browser does) and note the widgets' ids by label."""
        try:
            for raw in self.ws:
                if isinstance(raw, bytes):
                    for d in walk(decode_frame(raw)):
                        found = re.search(r'var WS_URL = "([^"]+)", TOKEN = "([^"]+)"', str(d.get("source") or ""))
                        if found and self.refresher is None:  # the page's hold refresher (web/hold_worker.js)
                            self.refresher = open_ws(found.group(1))
                            self.refresher.send(json.dumps({"type": "hello", "as": found.group(2)}))
                        props = d.get("props")
                        if isinstance(props, dict) and isinstance(props.get("label"), str) and "uuid" in d:
                            self.uuids.setdefault(props["label"], d["uuid"])
        except Exception:  # noqa: BLE001 - closed
            pass

    def _send(self, message) -> None:  # noqa: ANN001 - a viser message
        import msgspec

        self.ws.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def click(self, label: str) -> None:
        from viser import _messages

        self._send(_messages.GuiUpdateMessage(self.uuids[label], {"value": True}))

    def hold(self, sign: int, seconds: float = 0.3) -> None:
        from viser import _messages

        label = "hold X +" if sign > 0 else "hold X −"
        button = self.uuids[label]
        end = time.monotonic() + seconds
        while time.monotonic() < end:  # viser's hold events (25 Hz) and the refresher's holds (every 40 ms)
            self._send(_messages.GuiButtonHoldMessage(button, self.hz))
            self.refresher.send(json.dumps({"type": "hold", "button": label}))
            time.sleep(1.0 / self.hz)
        self._send(_messages.GuiButtonHoldMessage(button, self.hz))  # the last refresh
        self.refresher.send(json.dumps({"type": "hold", "button": label}))

    def release(self, sign: int) -> None:
        self.refresher.send(json.dumps({"type": "release"}))  # the worker's, on pointer-up
        self.click("hold X +" if sign > 0 else "hold X −")

    def close(self) -> None:
        self.ws.close()


def run_trials(front, sim: Proc, trials: int) -> tuple[dict[str, list[float]], dict[str, list[float]]]:  # noqa: ANN001
    """Stop times (s) and X speeds at the release (mm/s) per kind of trial."""
    out: dict[str, list[float]] = {"release": [], "silent (dead-man)": []}
    speeds: dict[str, list[float]] = {k: [] for k in out}
    front.take()  # the front ends take control from one another (the person at the station PC may)
    n = 0
    for i in range(trials):
        for kind in out:
            sign = 1 if n % 2 == 0 else -1  # back and forth inside the travel
            n += 1
            front.hold(sign)
            t = time.perf_counter_ns()
            if kind == "release":
                front.release(sign)
            sim.send(f"arm {t}")
            got, speed = sim.expect("stop")
            out[kind].append(float("inf") if got == "timeout" else float(got))
            speeds[kind].append(float(speed))
            time.sleep(0.1)
    return out, speeds


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q * (len(v) - 1))))]


def line(name: str, values: list[float], speeds: list[float], fast: float) -> str:
    ms = [v * 1000 for v in values]
    at_speed = sum(v >= 0.9 * fast for v in speeds)
    return (f"{name:20s} n={len(ms):3d}  median {statistics.median(ms):6.1f} ms  p99 {pct(ms, 0.99):6.1f} ms  "
            f"max {max(ms):6.1f} ms  | speed at release median {statistics.median(speeds):4.1f} mm/s, "
            f"{at_speed}/{len(speeds)} at >= 90 % of jog_fast")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--observers", type=int, default=20)
    ap.add_argument("--hits", type=int, default=200_000)
    ap.add_argument("--loaders", type=int, default=1, help="observer tabs opening + reporting the big session")
    ap.add_argument("--hogs", type=int, default=2 * (__import__("os").cpu_count() or 1),
                    help="CPU hogs (busy loops) beside the station during the load phase (default: 2 per core)")
    ap.add_argument("--link-process", choices=("auto", "same"), default="auto",
                    help='[link] process: "auto" = the link process (as shipped), "same" = bus in the station process')
    ap.add_argument("--role", choices=("sim", "station", "observers"), help=argparse.SUPPRESS)
    ap.add_argument("--url", help=argparse.SUPPRESS)
    ap.add_argument("--sessions", help=argparse.SUPPRESS)
    ap.add_argument("--big", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role == "sim":
        return run_sim()
    if args.role == "station":
        return run_station(args.url, args.sessions, args.big, args.loaders, args.link_process)
    if args.role == "observers":  # the observer browsers: a process of their own, as browsers are
        clients = [viser_observer(int(args.url)) for _ in range(args.observers)]
        print("connected", len(clients), flush=True)
        for text in sys.stdin:
            if text.strip() == "quit":
                break
        for c in clients:
            c.close()
        return None
    from cmm.control.priority import raise_thread_priority
    from cmm.machine.config import load

    # this process plays the operator's pendant, a device of its own: like the simulator it runs ahead of other
    # work on this PC (the observer browsers, which in use run on other PCs too, stay at normal priority)
    print(f"pendant client at {'raised' if raise_thread_priority() else 'normal'} priority")
    fast = load().speeds.jog_fast
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        big = write_big_session(Path(tmp), args.hits)
        print(f"{args.hits:,}-hit session written in {time.perf_counter() - t0:.1f} s "
              f"({(Path(tmp) / f'{big}.jsonl').stat().st_size / 1e6:.0f} MB)")
        sim = Proc("--role", "sim")
        station = None
        try:
            url, sim_priority = sim.expect("url")
            print(f"simulator at {sim_priority} priority")
            station = Proc("--role", "station", "--url", url, "--sessions", tmp, "--big", big,
                           "--loaders", str(args.loaders), "--link-process", args.link_process)
            viser_port, pendant_url = station.expect("ready")
            fronts = [Pendant(pendant_url, fast), ViserPage(int(viser_port))]
            print("release / last refresh -> every axis standing still (simulated machine time, separate processes):")
            for front in fronts:
                idle, idle_speeds = run_trials(front, sim, args.trials)
                for k, v in idle.items():
                    print(f"  idle        {front.name:10s} " + line(k, v, idle_speeds[k], fast))
            station.send("status")
            print(f"  idle link: {station.expect('status')[5]}")
            observers = Proc("--role", "observers", "--url", viser_port, "--observers", str(args.observers))
            observers.expect("connected")
            station.send("load")
            station.expect("loading")
            hogs = start_hogs(args.hogs)
            try:
                time.sleep(3.0)  # the observers' pages build, the loaders get going
                t_load = time.perf_counter()
                loaded = {f.name: run_trials(f, sim, args.trials) for f in fronts}
                station.send("status")
                clients, opened, reported, building, mode, link, *errors = station.expect("status")
                # the load is a session opened *and* reported: on a busy host the report (niced worker) can take
                # longer than the trials, so trials go on (and count) until one report is written, for up to 3 min
                while int(reported) == 0 and time.perf_counter() - t_load < 180:
                    for f in fronts:
                        more, more_speeds = run_trials(f, sim, 3)
                        for k in more:
                            loaded[f.name][0][k] += more[k]
                            loaded[f.name][1][k] += more_speeds[k]
                    station.send("status")
                    clients, opened, reported, building, mode, link, *errors = station.expect("status")
                load_avg = __import__("os").getloadavg()[0]
            finally:
                stop_hogs(hogs)
            for name, (times, speeds) in loaded.items():
                for k, v in times.items():
                    print(f"  under load  {name:10s} " + line(k, v, speeds[k], fast))
            print(f"  load: {args.hogs} CPU hogs, {clients} viser clients, {args.loaders} observer tab(s) opening "
                  f"(replay) + reporting the {args.hits:,}-hit session through the Sessions tab: {opened} opened, "
                  f"{reported} reported in {time.perf_counter() - t_load + 3:.0f} s"
                  + (f" (a report being built for {building} s when the trials ended)" if building != "-" else "")
                  + f"; host load average {load_avg:.1f} "
                  f"on {__import__('os').cpu_count()} cores; machine {mode}; link since start: {link}"
                  + (f"; errors: {' '.join(errors)}" if errors else ""))
            for name, (times, speeds) in loaded.items():
                p99 = pct(times["release"], 0.99)
                full = [t for t, v in zip(times["release"], speeds["release"]) if v >= 0.9 * fast]
                p99_full = pct(full, 0.99) if full else float("inf")
                silent = pct(times["silent (dead-man)"], 0.99)
                met = max(p99, p99_full) <= 0.2 and silent <= 0.3 and len(full) >= len(times["release"]) // 2 \
                    and int(opened) > 0 and (int(reported) > 0 or building != "-")
                print(f"target {name}: release p99 <= 200 ms and silent p99 <= 300 ms under load -> release "
                      f"{p99 * 1000:.1f} ms over all {len(times['release'])}, {p99_full * 1000:.1f} ms over the "
                      f"{len(full)} released at full speed; silent {silent * 1000:.1f} ms "
                      f"({'met' if met else 'NOT met'})")
            observers.close()
            for f in fronts:
                f.close()
        finally:
            if station is not None:
                station.close()
            sim.close()


if __name__ == "__main__":
    main()
