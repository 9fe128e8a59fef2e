"""A station process for tests/test_kill9.py: connect, move to a start, then jog one axis + forever, printing.

Prints ``ready <link process pid>`` once at the start, then after every refresh ``pos <sample time> <x> <y> <z>``:
the position of the machine loop's latest sample and its time on the machine's clock (monotonic, shared with the
link process and the test). Other lines (link warnings, a refused refresh) may come in between.
"""

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
        try:
            ctl.jog(None, v)
        except Exception as exc:  # noqa: BLE001 - a busy loop or a refused refresh: the operator keeps holding
            print("refused", exc, flush=True)
        st = ctl.state.machine
        print("pos {:.4f} {:.4f} {:.4f} {:.4f}".format(st.time, *st.position), flush=True)
        time.sleep(0.05)


if __name__ == "__main__":
    main()
