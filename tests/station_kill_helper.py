"""A station process for tests/test_kill9.py: connect, move to a start, then jog one axis + forever, printing."""

from __future__ import annotations

import sys
import time

from cmm.control import Controller
from cmm.machine.config import load
from cmm.machine.motion import Machine


def main() -> None:
    url, config, axis = sys.argv[1], sys.argv[2], int(sys.argv[3])
    start = [float(v) for v in sys.argv[4:7]]
    ctl = Controller(Machine(load(config), url))
    ctl.connect()
    ctl.start()
    ctl.move(None, start, frame="machine").wait(60)
    print("ready", getattr(ctl.machine.bus, "pid", 0), flush=True)  # the link process, on a real port
    v = [0.0, 0.0, 0.0]
    v[axis] = 40.0
    while True:  # an operator holding the jog button: refreshed every 50 ms until the process dies
        ctl.jog(None, v)
        st = ctl.state.machine
        print("pos {:.4f} {:.4f} {:.4f} {:.4f}".format(time.monotonic(), *st.position), flush=True)
        time.sleep(0.05)


if __name__ == "__main__":
    main()
