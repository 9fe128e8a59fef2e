"""A start-up failure says its real cause (every one was headed "the machine did not answer on <port>",
also for a full disk; a session database that is down stops nothing). ``cmm serve`` is started for real, on the built-in
simulator; the database is a PostgreSQL URL on a port where nothing listens, the full disk a 64 kB tmpfs filled
up (mounted when this user may, else that case is skipped)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from netutil import free_port

ROOT = Path(__file__).resolve().parents[1]


def _serve(tmp_path, *args):
    out = subprocess.run([sys.executable, "-m", "cmm.cli", "serve", "--http-port", str(free_port()),
                          "--trends", str(tmp_path / "trends"), *args], capture_output=True, text=True, timeout=180,
                         cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return out.returncode, out.stderr


def test_a_session_database_that_is_down_does_not_stop_the_station(tmp_path):
    """The shop's session database being down is no start-up failure (the store journals every event locally
    first and uploads it later): the station starts on the simulator, says nothing of the machine, and never
    prints the database's password."""
    pytest.importorskip("psycopg")
    import selectors
    import time

    url = f"postgresql://cmm:secret@127.0.0.1:{free_port()}/cmm"
    proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "serve", "--http-port", str(free_port()),
                             "--trends", str(tmp_path / "trends"), "--sessions", url, "--trends-db", ""],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1",
                                 "CMM_SESSION_SPOOL": str(tmp_path / "spool")})
    seen = []
    try:
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        end = time.monotonic() + 180  # a bound for a loaded computer, not a measured time
        while time.monotonic() < end and not any("CMM station on" in line for line in seen):
            if proc.poll() is not None:
                seen += proc.stdout.readlines()
                break
            if sel.select(timeout=1.0):
                line = proc.stdout.readline()
                if line:
                    seen.append(line)
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    text = "".join(seen)
    assert any("CMM station on" in line for line in seen), text
    assert "the machine did not answer" not in text and "Traceback" not in text and "secret" not in text, text


def test_a_full_disk_is_named_not_the_machine(tmp_path):
    disk = tmp_path / "tiny"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip("this user may not mount a small tmpfs to fill up")
    try:
        fd = os.open(disk / "filler", os.O_WRONLY | os.O_CREAT)  # fill it: the journal's first write finds no space
        try:
            while True:
                os.write(fd, b"\0" * 4096)
        except OSError:
            pass
        finally:
            os.close(fd)
        rc, err = _serve(tmp_path, "--sessions", str(disk))
        assert rc == 2, err
        line = err.strip().splitlines()[-1]
        assert line.startswith(f"cmm serve: the disk is full: the session journal cannot be written in {disk}"), err
        assert "the machine did not answer" not in err and "Traceback" not in err, err
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)
