"""Trends figures: chart queries over 10,000 parts x 50 characteristics, on the local store and on PostgreSQL.

    python benchmarks/bench_trends.py [--parts 10000] [--chars 50] [--stations 4] [--queries 50] [--db URL]

The parts (4 stations taking turns) are written as one station's local journal in the journal's own format,
indexed (``index.sqlite``, timed), uploaded to the database (timed), then for ``--queries``
characteristics (default: all 50) a chart query is timed on each store: the characteristic's history (every part, in time order, with station,
run id and serial) -> the I-MR statistics, Cp/Cpk and out-of-tolerance parts -> the SVG chart; also the
same for one station's parts, and the list of series / characteristics; p50 / p99 / max of each. Target: under
200 ms per chart query.

Without ``--db`` a throw-away PostgreSQL server is started from /usr/lib/postgresql/*/bin in a temporary
directory (as the tests do) and stopped at the end.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # pg_support: the tests' server helper

from cmm.journal.writer import encode_event  # noqa: E402
from cmm.session.trends import Trends  # noqa: E402
from cmm.session.trends_chart import trend, trend_svg  # noqa: E402


def write_journal(path: Path, parts: int, chars: int, stations: int, seed: int = 1) -> list[str]:
    """A parts journal of ``parts`` parts (a slow drift, two bad parts in a hundred) from several stations."""
    rng = np.random.default_rng(seed)
    names = [f"feature {k // 5 + 1} / {('diameter', 'position ⌀', 'flatness', 'location', 'angle')[k % 5]}"
             for k in range(chars)]
    nominal = rng.uniform(5.0, 80.0, chars)
    t0 = time.time() - parts * 60.0
    with open(path, "w", encoding="utf-8") as fh:
        for i in range(parts):
            drift = 0.004 * i / parts
            noise = rng.normal(0.0, 0.004, chars)
            if rng.random() < 0.02:
                noise[rng.integers(chars)] += 0.05
            values = [[n, float(nom + drift + d), float(nom), float(nom - 0.02), float(nom + 0.02), "mm"]
                      for n, nom, d in zip(names, nominal, noise)]
            fh.write(encode_event({"seq": i + 1, "time": t0 + i * 60.0, "kind": "part", "series": "bracket",
                                   "station": f"cmm-{i % stations + 1}", "run_id": f"run-{i + 1:06d}",
                                   "serial": f"B{i + 1:06d}", "part_time": t0 + i * 60.0, "values": values}) + "\n")
    return names


def timed(fn, repeat: int = 1) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def chart_query(t: Trends, name: str, station: str | None = None) -> tuple[float, float, float, int, float]:
    """(history s, statistics s, svg s, parts, CPU s of the three) of one chart."""
    cpu = time.process_time()
    a = time.perf_counter()
    h = t.history("bracket", name, station)
    b = time.perf_counter()
    tc = trend(h, 1)
    c = time.perf_counter()
    trend_svg(tc)
    d = time.perf_counter()
    return b - a, c - b, d - c, len(h), time.process_time() - cpu


def pct(values: list[float], q: float) -> float:
    """The q-th percentile (nearest rank) of ``values``."""
    v = sorted(values)
    return v[min(len(v) - 1, max(0, math.ceil(q / 100.0 * len(v)) - 1))]


def report(label: str, rows: list[tuple[float, float, float, int, float]]) -> None:
    total = [sum(r[:3]) * 1000 for r in rows]
    q = [r[0] * 1000 for r in rows]
    cpu = [r[4] * 1000 for r in rows]
    print(f"  {label}: {rows[0][3]} parts per chart, {len(rows)} charts; query p50 {pct(q, 50):.1f} / p99 "
          f"{pct(q, 99):.1f} / max {max(q):.1f} ms; query + statistics + SVG p50 {pct(total, 50):.1f} / p99 "
          f"{pct(total, 99):.1f} / max {max(total):.1f} ms [target < 200 ms]; its CPU time p50 {pct(cpu, 50):.1f} / "
          f"max {max(cpu):.1f} ms (the rest of the wall time is waiting for a core)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--parts", type=int, default=10_000)
    ap.add_argument("--chars", type=int, default=50)
    ap.add_argument("--stations", type=int, default=4)
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--db", default=None, help="an existing database (default: a throw-away server)")
    ap.add_argument("--keep", action="store_true", help="keep the journal and index (printed) instead of deleting")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="cmm-bench-trends-"))
    server = None
    url = args.db
    if url is None:
        from pg_support import PgServer

        server = PgServer()
        if server.skip_reason:
            print(f"no PostgreSQL: {server.skip_reason}; local store only")
            server.close()
            server = None
        else:
            url = server.url
    try:
        names = write_journal(root / "parts.jsonl", args.parts, args.chars, args.stations)
        size = (root / "parts.jsonl").stat().st_size
        print(f"{args.parts} parts x {args.chars} characteristics from {args.stations} stations: journal "
              f"{size / 1e6:.1f} MB (load average {os.getloadavg()[0]:.1f})")
        s, t = timed(lambda: Trends(root, station="cmm-1"))
        print(f"local index built from the journal: {s:.2f} s ({(root / 'index.sqlite').stat().st_size / 1e6:.0f} MB)")
        pick = [names[k] for k in np.linspace(0, len(names) - 1, args.queries).round().astype(int)]
        for name in pick[:2]:  # warm the file cache as a running station has it
            chart_query(t, name)
        print("local store (SQLite index of the journal):")
        report("every station", [chart_query(t, n) for n in pick])
        report("one station", [chart_query(t, n, "cmm-2") for n in pick])
        s, _ = timed(lambda: (t.series(), t.characteristics("bracket"), t.stations("bracket")), 5)
        print(f"  series + characteristics + stations lists: {s * 1000:.1f} ms")
        t.close()
        if url is not None:
            t = Trends(root, station="cmm-1", database=url)
            s, sent = timed(lambda: t.sync(force=True))
            print(f"PostgreSQL: uploaded {sent} parts ({sent * args.chars} values) in {s:.1f} s "
                  f"({sent / s:.0f} parts/s)")
            for name in pick[:2]:
                chart_query(t, name)
            report("every station", [chart_query(t, n) for n in pick])
            report("one station", [chart_query(t, n, "cmm-2") for n in pick])
            s, _ = timed(lambda: (t.series(), t.characteristics("bracket"), t.stations("bracket")), 5)
            print(f"  series + characteristics + stations lists: {s * 1000:.1f} ms")
            assert t.source == "database"
            t.close()
        print(f"load average at the end {os.getloadavg()[0]:.1f}")
    finally:
        if server is not None:
            server.close()
        if args.keep:
            print(f"kept {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
