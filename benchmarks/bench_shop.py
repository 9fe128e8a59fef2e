"""Shop-integration figures: the PostgreSQL session store through an outage, and QIF 3 documents.

    python benchmarks/bench_shop.py [--events 2000] [--qif-features 60]

1. Session store: ``--events`` notes appended (each fsync'ed to the local journal) with the database up (append
   rate, and how long until the last one is in the database), the same number while the database is down (the
   append rate must not change: nothing waits for the network), then the catch-up after the server is started
   again (events per second). Every event in the database exactly once is checked.
2. QIF: a session with ``--qif-features`` fitted cylinders (each diameter, position, cylindricity) written as a
   QIF 3 Results document (time, size) and validated against ../shared/qif/schemas (schema load and validation
   times), when the schemas are there.

A throw-away PostgreSQL server is started from /usr/lib/postgresql/*/bin (as the tests do) and stopped at the end.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # pg_support, qif_support


def bench_store(n: int) -> None:
    import psycopg
    from pg_support import PgServer

    from cmm.journal.store import PostgresStore

    server = PgServer()
    if server.skip_reason:
        print(f"session store: skipped ({server.skip_reason})")
        return
    try:
        store = PostgresStore(server.url, spool=tempfile.mkdtemp(prefix="cmm-spool-"))
        w = store.create("bench", append=True)
        t0 = time.perf_counter()
        for k in range(n):
            w.append("note", text=f"online {k}")
        t1 = time.perf_counter()
        store.uploader.wait_uploaded("bench", 120)
        t2 = time.perf_counter()
        print(f"online : {n} events appended in {t1 - t0:.2f} s ({n / (t1 - t0):.0f}/s, "
              f"{(t1 - t0) / n * 1000:.2f} ms each); all in the database {t2 - t1:.2f} s after the last")
        server.stop("immediate")
        t0 = time.perf_counter()
        for k in range(n):
            w.append("note", text=f"offline {k}")
        t1 = time.perf_counter()
        while "offline" not in w.upload_status():
            time.sleep(0.01)
        print(f"offline: {n} events appended in {t1 - t0:.2f} s ({n / (t1 - t0):.0f}/s); status: "
              f"{w.upload_status().split(' (')[0]}")
        assert server.start() == ""
        t0 = time.perf_counter()
        ok = store.uploader.wait_uploaded("bench", 300)
        t1 = time.perf_counter()
        print(f"catch-up: {n} events in {t1 - t0:.2f} s after the restart (reconnect back-off included; "
              f"{'complete' if ok else 'INCOMPLETE'})")
        w.close()
        with psycopg.connect(server.url) as conn:
            seqs = [r[0] for r in conn.execute("SELECT seq FROM cmm_events ORDER BY seq").fetchall()]
        assert seqs == list(range(1, 2 * n + 1)), "events missing or doubled"
        print(f"database: {len(seqs)} events, seq 1..{2 * n}, each once")
    finally:
        server.close()


def bench_qif(n: int) -> None:
    import numpy as np

    from cmm.journal.session import Session
    from cmm.session.qif import qif_bytes

    events = [{"seq": 1, "time": 0.0, "kind": "start", "port": "bench"}]
    for k in range(n):
        c = [20.0 * (k % 10), 20.0 * (k // 10), 0.0]
        events.append({"seq": k + 2, "time": float(k), "kind": "feature", "id": k + 1, "name": f"hole {k + 1}",
                       "feature_kind": "cylinder", "method": "ls", "hit_ids": [], "n_points": 8, "form": 0.001,
                       "point": [c[0] + 0.001, c[1], 0.0], "direction": [0, 0, 1.0], "radius": 5.002,
                       "diameter": 10.004, "uncertainty": {"diameter": 0.0004, "axis_position": 0.0003},
                       "nominal": {"kind": "cylinder", "point": c, "direction": [0, 0, 1.0], "radius": 5.0}})
    s = Session.from_events(events, "bench")
    t0 = time.perf_counter()
    data = qif_bytes(s)
    t1 = time.perf_counter()
    print(f"QIF: {n} features, {3 * n} characteristics written in {(t1 - t0) * 1000:.0f} ms, {len(data) / 1024:.0f} kB")
    try:
        import qif_support

        t0 = time.perf_counter()
        schema, why = qif_support._load()
        t1 = time.perf_counter()
        if schema is None:
            print(f"QIF validation: skipped ({why})")
            return
        from lxml import etree

        doc = etree.fromstring(data).getroottree()
        ok = schema.validate(doc)
        t2 = time.perf_counter()
        print(f"QIF validation: schemas loaded in {(t1 - t0) * 1000:.0f} ms, document {'valid' if ok else 'INVALID'} "
              f"in {(t2 - t1) * 1000:.0f} ms")
        del np
    except ImportError as exc:
        print(f"QIF validation: skipped ({exc})")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--events", type=int, default=2000)
    p.add_argument("--qif-features", type=int, default=60)
    a = p.parse_args()
    bench_qif(a.qif_features)
    bench_store(a.events)


if __name__ == "__main__":
    main()
