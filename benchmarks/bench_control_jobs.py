"""CPU of a calibration routine run as a job through the control core, against the bare machine.

Probe qualification (one hit per point, 73 points) on the in-process simulator (virtual clock, the same
sampling pause on every path): on a bare ``Machine`` (what `cmm calibrate` did before it used a station),
as ``controller.run_job`` inline (no threads: the CLI), with the machine loop and dispatcher threads
(the browser station), and threaded with a state listener (an I++ DME OnMoveReport, the UI). Prints CPU
seconds, samples (3 NOPs each), and the number of items posted to the dispatcher thread. Run:
    python benchmarks/bench_control_jobs.py [--repeat N] [machine|inline|threaded|listener ...]
CPU is the least of N runs (the machine is shared: the least is the cost, the rest is contention).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

from cmm.control.dispatch import Dispatcher

REPO = Path(__file__).resolve().parents[1]
PAUSE = 0.004  # s of machine time between samples on every path (the bare machine's virtual-clock pause)
posts = [0]
_post = Dispatcher.post


def _counting_post(self, fn, *args):  # type: ignore[no-untyped-def]
    posts[0] += 1
    return _post(self, fn, *args)


Dispatcher.post = _counting_post  # type: ignore[method-assign]


def _records() -> Path:
    d = Path(tempfile.mkdtemp())
    (d / "artifacts").mkdir()
    shutil.copy(REPO / "calibration/artifacts/reference-sphere.toml", d / "artifacts")
    return d


def bare_machine() -> tuple:
    from cmm.calibration.probe import qualify_probe
    from cmm.calibration.records import load_sphere_certificate
    from cmm.machine.config import load
    from cmm.machine.motion import Machine
    from cmm.sim.cmm_sim import CmmSimSettings, SimulatedCMM

    cfg = load()
    sim = SimulatedCMM(cfg, CmmSimSettings(), wire_time=True)
    m = Machine(cfg, sim.transport())
    m.connect()
    m.poll_pause = PAUSE
    cert = load_sphere_certificate(REPO / "calibration/artifacts/reference-sphere.toml")
    posts[0], s0, c0 = 0, m.samples, time.process_time()
    q = qualify_probe(m, cert, repeats=1)
    out = (time.process_time() - c0, m.samples - s0, posts[0], q.record.tip_radius)
    m.close()
    return out


def station(threaded: bool, listener: bool = False) -> tuple:
    from cmm.station import Station

    st = Station(port="sim://?cmm=1", calibration_dir=_records(), session_dir=tempfile.mkdtemp())
    st.machine.poll_pause = PAUSE
    st.controller.connect()
    if threaded:
        st.controller.start()
    if listener:
        st.controller.subscribe_state(lambda state: None)
    st.controller.home(None)
    m = st.machine
    posts[0], s0, c0 = 0, m.samples, time.process_time()
    q = st.calibration.run(None, "probe", repeats=1)
    out = (time.process_time() - c0, m.samples - s0, posts[0], q.record.tip_radius)
    st.close()
    return out


PATHS = {"machine": ("bare Machine", bare_machine), "inline": ("run_job inline", lambda: station(False)),
         "threaded": ("run_job threaded", lambda: station(True)),
         "listener": ("threaded + state listener", lambda: station(True, True))}


def main() -> None:
    args = sys.argv[1:]
    repeat = 1
    if "--repeat" in args:
        i = args.index("--repeat")
        repeat = int(args[i + 1])
        del args[i:i + 2]
    which = args or list(PATHS)
    print(f"{'path':<26} {'CPU s':>6} {'samples':>8} {'posts':>7} {'CPU ms/sample':>13}  r_eff")
    for w in which:
        name, fn = PATHS[w]
        runs = [fn() for _ in range(repeat)]
        cpu, samples, n, r = min(runs)
        print(f"{name:<26} {cpu:6.2f} {samples:8d} {n:7d} {1000 * cpu / max(samples, 1):13.3f}  {r:.5f}", flush=True)


if __name__ == "__main__":
    main()
