"""The station's built-in simulator in a process of its own.

``cmm serve`` with no port drives the simulated CMM as it drives hardware: over a byte stream (TCP on
loopback) through its link process. The simulator runs here, in a child process at raised priority (the link
process's), never under the station's interpreter lock: a station busy with web pages, reports and sessions
cannot hold up a module's reply, so the link's time-outs measure the link, not the station's load.

The station talks to the child over a socket pair (:class:`SimProcess`): the machine configuration and the
simulator settings go in, the served URL, the part mesh and its nominal features come back; artifacts are
placed (the calibration wizard's simulated operator) and trigger times read through it. The child ends with
the station: when that pipe closes (the station closed it, crashed or was killed with SIGKILL) or its parent
process changes, it stops serving and exits.

The in-process ``sim://`` simulator (cmm/sim/url.py) is unchanged: tests drive it on the virtual clock.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from typing import Any

START_TIMEOUT = 60.0  # s: a fresh interpreter imports numpy, trimesh and builds the sample part
CALL_TIMEOUT = 10.0
PARENT_CHECK_S = 1.0  # the child looks at its parent pid this often (the pipe's EOF is the fast path)
SIM_NICE = -10  # as the link process (cmm/nmc/link_process.py): ahead of the station's web and report work


class SimProcessError(RuntimeError):
    """The simulator process could not be started or stopped answering."""


class SimProcess:
    """A simulated CMM served over TCP on loopback by a child process; ``url`` is what the bus opens."""

    def __init__(self, config: Any, settings: Any, *, home_switches: bool = True) -> None:
        ours, theirs = socket.socketpair()
        self._conn = Connection(ours.detach())
        fd = theirs.fileno()
        self._lock = threading.Lock()
        self._proc = subprocess.Popen([sys.executable, "-m", "cmm.sim.sim_process", str(fd), str(os.getpid())],
                                      pass_fds=(fd,), stdin=subprocess.DEVNULL)
        theirs.close()
        self._closed = False
        self.settings = settings  # what the child's simulated CMM was built with (where its sphere stands)
        try:
            self._conn.send((config, settings, home_switches))
            self.url, self.part_mesh, self.nominal_features = self._reply(START_TIMEOUT, "starting")
        except BaseException:
            self._kill()
            raise

    def _reply(self, timeout: float, what: str) -> Any:
        try:
            if not self._conn.poll(timeout):
                raise SimProcessError(f"the simulator process did not answer {what} within {timeout:g} s")
            reply = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise SimProcessError(f"the simulator process ended while {what} "
                                  f"(exit code {self._proc.poll()})") from exc
        if reply[0] == "err":
            raise SimProcessError(f"the simulator process failed while {what}: {reply[1]}")
        return reply[1]

    def _call(self, op: str, *args: Any) -> Any:
        with self._lock:
            if self._closed:
                raise SimProcessError("the simulator process is closed")
            try:
                self._conn.send((op, *args))
            except (OSError, ValueError) as exc:
                raise SimProcessError(f"the simulator process is gone ({exc})") from exc
            return self._reply(CALL_TIMEOUT, op)

    def place_artifacts(self, spheres: list) -> None:
        """The operator sets up artifacts [(centre, diameter)] (under the simulator's lock, in the child)."""
        self._call("place", [(tuple(map(float, c)), float(d)) for c, d in spheres])

    def mount_stylus(self, tip_diameter: float) -> None:
        """The operator mounts a stylus of ``tip_diameter`` mm (in the child, under the simulator's lock)."""
        self._call("mount", float(tip_diameter))

    def place_part(self, pose: Any, mesh: Any = None) -> None:
        """The operator puts the next part on the table at ``pose`` (4x4 part -> machine), in the child; ``mesh``:
        another part instead of the present one."""
        import numpy as np

        pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        self._call("place_part", pose.tolist(), mesh)
        self.settings.part_pose = pose.copy()
        if mesh is not None:
            self.part_mesh, self.nominal_features = mesh, {}

    @property
    def last_trigger_wall(self) -> float:
        """``time.perf_counter()`` of the last probe trigger (CLOCK_MONOTONIC: comparable across processes)."""
        return float(self._call("get", "last_trigger_wall"))

    @property
    def triggers(self) -> int:
        return int(self._call("get", "triggers"))

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def close(self) -> None:
        with self._lock:
            if not self._closed:
                self._closed = True
                try:
                    self._conn.send(("exit",))
                except (OSError, ValueError):
                    pass
        try:
            self._proc.wait(5)
        except subprocess.TimeoutExpired:
            pass
        self._kill()
        self._conn.close()

    def _kill(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(5)


# --- the child --------------------------------------------------------------------------------------------------

def _raise_priority() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, 0, SIM_NICE)  # before any thread: the serving thread inherits it
    except OSError:
        pass  # not permitted: normal priority, still a process of its own


def _watch_parent(parent: int, stop: threading.Event) -> None:
    """A station killed while this process waits elsewhere: its pid is gone as our parent."""
    while not stop.wait(PARENT_CHECK_S):
        if os.getppid() != parent:
            os._exit(0)


def serve(conn: Connection, parent: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the station, which closes us in order
    _raise_priority()
    stop = threading.Event()
    threading.Thread(target=_watch_parent, args=(parent, stop), name="sim-parent", daemon=True).start()
    try:
        config, settings, home_switches = conn.recv()
    except (EOFError, OSError):
        return
    try:
        from .cmm_sim import SimulatedCMM
        from .serve import serve_tcp

        cmm = SimulatedCMM(config, settings, wire_time=True, realtime=True)
        if home_switches:
            from .home_switches import for_homing

            cmm.home_switches = for_homing(cmm, config.homing)
        handle = serve_tcp(cmm.network, "127.0.0.1", 0)
    except Exception as exc:  # noqa: BLE001 - told to the station, which raises it
        conn.send(("err", f"{type(exc).__name__}: {exc}"))
        return
    try:
        conn.send(("ok", (handle.url, cmm.part_mesh, dict(cmm.nominal_features))))
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return  # the station is gone
            try:
                if msg[0] == "exit":
                    return
                if msg[0] == "place":
                    cmm.place_artifacts(msg[1])
                    reply: tuple = ("ok", None)
                elif msg[0] == "mount":
                    cmm.mount_stylus(msg[1])
                    reply = ("ok", None)
                elif msg[0] == "place_part":
                    import numpy as np

                    cmm.place_part(np.array(msg[1], dtype=np.float64), msg[2] if len(msg) > 2 else None)
                    reply = ("ok", None)
                elif msg[0] == "get" and msg[1] in ("last_trigger_wall", "triggers"):
                    reply = ("ok", getattr(cmm, msg[1]))
                else:
                    reply = ("err", f"unknown request {msg[0]!r}")
            except Exception as exc:  # noqa: BLE001
                reply = ("err", f"{type(exc).__name__}: {exc}")
            try:
                conn.send(reply)
            except (EOFError, OSError):
                return
    finally:
        stop.set()
        handle.close()


def main(argv: list[str]) -> None:
    """``python -m cmm.sim.sim_process FD PARENT_PID`` (started by :class:`SimProcess`)."""
    serve(Connection(int(argv[0])), int(argv[1]))


if __name__ == "__main__":
    main(sys.argv[1:])
