"""A throw-away PostgreSQL server on loopback that a test can stop and start again (a database outage).

Needs Debian's postgresql (initdb, pg_ctl under /usr/lib/postgresql/*/bin) and psycopg; without them the
caller skips with the reason.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from netutil import free_port


class PgServer:
    def __init__(self) -> None:
        self.skip_reason = ""
        try:
            import psycopg  # noqa: F401
        except ImportError:
            self.skip_reason = "psycopg is not installed (pip install 'cmm[postgres]')"
            return
        bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
        if not bins:
            self.skip_reason = "PostgreSQL server binaries not found (apt-get install postgresql)"
            return
        self.bindir = Path(bins[-1]).parent
        self.root = Path(tempfile.mkdtemp(prefix="cmm-pg-"))
        self.prefix: list[str] = []
        if os.geteuid() == 0:  # initdb refuses to run as root: run the server as the postgres user
            import pwd

            if shutil.which("runuser") is None:
                self.skip_reason = "running as root without runuser: cannot start PostgreSQL as another user"
                return
            try:
                pw = pwd.getpwnam("postgres")
            except KeyError:
                self.skip_reason = "running as root and there is no 'postgres' user to run the server"
                return
            os.chown(self.root, pw.pw_uid, pw.pw_gid)
            self.prefix = ["runuser", "-u", "postgres", "--"]
        self.data, self.port = self.root / "data", free_port()
        r = self._run("initdb", "-D", str(self.data), "-A", "trust", "-U", "cmm", "--no-sync")
        if r.returncode != 0:
            self.skip_reason = f"initdb failed: {r.stderr.strip()[-300:]}"
            return
        self.url = f"postgresql://cmm@127.0.0.1:{self.port}/postgres"
        err = self.start()
        if err:
            self.skip_reason = f"the PostgreSQL server did not start: {err}"

    def _run(self, tool: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(self.prefix + [str(self.bindir / tool), *args], capture_output=True, text=True,
                              timeout=120)

    def start(self) -> str:
        """Start (again) on the same port and data; returns the error text or ''."""
        r = self._run("pg_ctl", "-D", str(self.data), "-l", str(self.root / "log"), "-w", "-t", "60", "start",
                      "-o", f"-k {self.root} -p {self.port} -c listen_addresses=127.0.0.1 -c fsync=off")
        if r.returncode != 0:
            log = (self.root / "log").read_text() if (self.root / "log").exists() else ""
            return (r.stderr + log).strip()[-300:]
        return ""

    def stop(self, mode: str = "fast") -> None:
        self._run("pg_ctl", "-D", str(self.data), "-m", mode, "-w", "stop")

    def close(self) -> None:
        if getattr(self, "data", None) is not None and self.data.exists():
            self.stop("immediate")
        if getattr(self, "root", None) is not None:
            shutil.rmtree(self.root, ignore_errors=True)
