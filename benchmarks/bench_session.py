"""Session figures: journal append rate with fsync, and open / replay time of a 10,000-hit session.

    python benchmarks/bench_session.py [--hits 10000] [--appends 2000] [--dir DIR]

The journal is written in DIR (default: a temporary directory; fsync cost
depends on the file system, so run it where sessions really live).
"""

from __future__ import annotations

import argparse
import random
import tempfile
import time
from pathlib import Path

from cmm.journal.writer import Journal, read_events
from cmm.journal.session import Session
from cmm.session.reevaluate import reevaluate
from cmm.session.replay import Replay
from cmm.journal.store import DirectoryStore, load_session


def hit_event(k: int) -> dict:
    c = [random.randint(0, 250000), random.randint(0, 200000), random.randint(-150000, 0)]
    m = [c[0] / 500, c[1] / 500, 300 + c[2] / 500]
    return {"id": k, "counts": c, "machine": m, "approach": [0.0, 0.0, -1.0], "speed": 2.0, "hit_time": time.time(),
            "point": [m[0], m[1], m[2] - 1.0], "mode": "programmed", "normal": None}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hits", type=int, default=10_000)
    ap.add_argument("--appends", type=int, default=2_000)
    ap.add_argument("--dir", default=None)
    args = ap.parse_args()
    random.seed(1)
    root = Path(args.dir or tempfile.mkdtemp(prefix="cmm-bench-session-"))
    start = {"config": "default", "tip_radius": 1.0, "pretravel": {"const": 0.0}, "part": "p",
             "part_pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
             "axes": [{"name": n, "counts_per_mm": 500.0, "direction": 1, "home": h, "min": 0.0, "max": 500.0}
                      for n, h in (("x", 0.0), ("y", 0.0), ("z", 300.0))]}

    # 1. append rate, fsync per event (what every hit costs before the UI shows it)
    path = root / "append.jsonl"
    with Journal(path) as j:
        j.append("start", **start)
        t0 = time.perf_counter()
        for k in range(1, args.appends + 1):
            j.append("hit", **hit_event(k))
        dt = time.perf_counter() - t0
    print(f"journal append with fsync: {args.appends / dt:,.0f} events/s ({dt / args.appends * 1e3:.3f} ms per hit)")

    # 2. a 10,000-hit session (hits plus a feature every 10 hits), written without per-event timing
    name = f"hits{args.hits}"
    with Journal(root / f"{name}.jsonl") as j:
        j.append("start", **start)
        for k in range(1, args.hits + 1):
            j.append("hit", **hit_event(k))
            if k % 10 == 0:
                ids = list(range(k - 9, k + 1))
                j.append("feature", id=k // 10, name=f"plane {k // 10}", feature_kind="plane", method="ls",
                         hit_ids=ids, n_points=10, form=0.001, sigma=0.0003, point=[0, 0, 0], normal=[0, 0, 1],
                         nominal=None)
    size = (root / f"{name}.jsonl").stat().st_size
    t0 = time.perf_counter()
    contents = read_events(root / f"{name}.jsonl")
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    session = load_session(DirectoryStore(root), name)
    t_open = time.perf_counter() - t0
    n = len(session.events)
    print(f"{args.hits:,}-hit session: {n:,} events, {size / 1e6:.1f} MB; read {t_read * 1e3:.0f} ms, "
          f"open (parse + rebuild) {t_open * 1e3:.0f} ms")
    t0 = time.perf_counter()
    replay = Replay(session)
    t_index = time.perf_counter() - t0
    positions = [random.randrange(n) for _ in range(200)]
    t0 = time.perf_counter()
    for i in positions:
        replay.at(i)
    t_at = (time.perf_counter() - t0) / len(positions)
    t0 = time.perf_counter()
    for _ in replay:
        pass
    t_all = time.perf_counter() - t0
    print(f"replay: build {t_index * 1e3:.0f} ms, random scrubber position at(i) {t_at * 1e3:.2f} ms, "
          f"every state in order {t_all:.2f} s")
    t0 = time.perf_counter()
    reevaluate(Session.from_events(contents.events, name))
    print(f"re-evaluate {args.hits:,} hits + {args.hits // 10:,} plane fits from raw counts: {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
