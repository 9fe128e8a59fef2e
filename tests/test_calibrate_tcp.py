"""`cmm calibrate --serial socket://...` against `cmm sim --cmm --tcp`: two processes, as an operator runs them.

The served simulator has the home switches the shipped configuration's homing cycle looks for (as the
real machine does), so the CLI homes it first and says so; without switches, or with ``--no-home``, it
refuses with a message that names what to change. The simulator runs in real time: servo tuning is the
quickest routine (step moves, no probing).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cmm.calibration.records import load_servo_record
from cmm.machine.config import default_text, load

pytestmark = pytest.mark.timeout(180)


def _cmm(*args: str) -> list[str]:
    return [sys.executable, "-u", "-m", "cmm.cli", *args]


class _ServedSim:
    """`cmm sim --cmm --tcp 127.0.0.1:0` in its own process: its banner and driver URL."""

    def __init__(self, *extra: str) -> None:
        self.proc = subprocess.Popen(_cmm("sim", "--cmm", "--tcp", "127.0.0.1:0", *extra),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.banner = ""
        end = time.monotonic() + 60
        while time.monotonic() < end:
            line = self.proc.stdout.readline()
            if not line:
                break
            self.banner += line
            m = re.search(r"(socket://127\.0\.0\.1:\d+)", line)
            if m:
                self.url = m.group(1)
                return
        self.close()
        raise AssertionError(f"the simulator did not print its URL:\n{self.banner}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc.stdout.close()


def _calibrate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(_cmm("calibrate", *args), capture_output=True, text=True, timeout=150)


def test_calibrate_over_tcp_homes_the_served_cmm_first_then_runs_the_routine(tmp_path):
    sim = _ServedSim()
    try:
        assert "home switches on LIMIT2" in sim.banner
        r = _calibrate("servo", "--serial", sim.url, "--records", str(tmp_path), "--quiet")
        assert r.returncode == 0, r.stdout + r.stderr
        lines = r.stdout.splitlines()
        homing = lines.index("homing cycle: the machine moves to its home switches")
        assert lines[homing + 1] == "homed"  # announced before the machine moves, confirmed before the routine
        assert any(line.startswith("proposed X: Kp") for line in lines[homing + 2:]), r.stdout
        proposal = load_servo_record(tmp_path / "servo-proposal.toml")
        assert not proposal.accepted and set(proposal.gains) == {"x", "y", "z"}
        assert all(g["kp"] > 0 and g["kd"] > 0 for g in proposal.gains.values())
        assert (tmp_path / "servo-z.svg").read_text().startswith("<svg")
        # --no-home on the same (freshly connected, so not homed) machine: refused before anything moves
        r = _calibrate("servo", "--serial", sim.url, "--records", str(tmp_path / "again"), "--no-home")
        assert r.returncode == 1
        assert "not homed and --no-home was given: run without --no-home to home it first" in r.stderr
        assert "homing cycle" not in r.stdout and not (tmp_path / "again").exists()
    finally:
        sim.close()


def test_calibrate_over_tcp_without_home_switches_stops_with_what_to_change(tmp_path):
    """A served CMM without switches (`--no-home-switches`): homing fails, the message says why and names the
    configuration setting (and the simulator option); nothing is written. A short search keeps the test quick."""
    config = tmp_path / "machine.toml"
    config.write_text(default_text().replace("backoff = 1.0", "backoff = 1.0\nsearch = 3.0"))
    assert load(config).homing.search == 3.0
    sim = _ServedSim("--no-home-switches", "--config", str(config))
    try:
        assert "home switches" not in sim.banner
        r = _calibrate("servo", "--serial", sim.url, "--config", str(config), "--records", str(tmp_path / "rec"))
        assert r.returncode == 1, r.stdout + r.stderr
        assert "homing cycle: the machine moves to its home switches" in r.stdout and "homed" not in r.stdout.split()
        err = r.stderr
        assert "homing failed: home switch of Z not found" in err, err
        assert '[homing] method = "none"' in err and "--config" in err and "only with --cmm" in err
        assert "Traceback" not in err and not (tmp_path / "rec").exists()
    finally:
        sim.close()


def test_calibrate_no_home_on_a_machine_without_homing_cycle_measures_at_once(tmp_path, capsys):
    """--no-home is for a machine that needs no homing ([homing] method = "none"): it runs (in-process simulator)."""
    from cmm.cli import main

    config = tmp_path / "machine.toml"
    config.write_text(default_text().replace('method = "switch"', 'method = "none"'))
    assert main(["calibrate", "servo", "--config", str(config), "--records", str(tmp_path / "rec"), "--quiet",
                 "--no-home"]) == 0
    out = capsys.readouterr().out
    assert "homing cycle" not in out and "proposed X" in out
    assert (Path(tmp_path) / "rec" / "servo-proposal.toml").is_file()
