"""The under-load benchmark's CPU hogs run at normal priority, as its docstring says (it raised its own
priority first and the hogs, started after, inherited nice -10)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_hogs_run_at_the_normal_priority_not_the_raised_one():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_under_load.py"), "--minutes", "0",
                          "--hogs", "2"], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    m = re.search(r"2 CPU hogs at nice (-?\d+) \(normal priority: nice (-?\d+)\)", out.stdout)
    assert m, out.stdout
    assert m.group(1) == m.group(2) == str(os.getpriority(os.PRIO_PROCESS, 0)), out.stdout
