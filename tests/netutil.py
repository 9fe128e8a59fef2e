"""Loopback helpers shared by the tests that start servers."""

import socket


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# The simulated CMM in the test's own process, on the simulator's virtual clock: a loaded machine slows
# the simulation down instead of making replies late. PACED caps simulated time at the wall clock, for
# tests where a person's wall-time actions (holding a jog, a pendant's refreshes) meet the dead-man.
SIM = "sim://?cmm=1"
SIM_PACED = "sim://?cmm=1&pace=1"
