"""pyserial handler for ``sim://`` URLs (see :mod:`cmm.sim.url` for the URL form).

``serial.serial_for_url("sim://?cmm=1")`` returns a :class:`Serial` on an
in-process simulated network. Besides pyserial's byte interface it has
``now()`` and ``sleep(seconds)`` (the world's clock: the NMC transport layer
runs the driver on it) and ``world`` (the network and, for cmm=1, the
simulated CMM).
"""

from __future__ import annotations

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from cmm.sim.transport import SimTransport
from cmm.sim.url import SimUrlError, SimWorld, attach


class Serial(SerialBase):
    """A serial port whose far end is a simulated NMC network."""

    BAUDRATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)

    def __init__(self, *args, **kwargs) -> None:
        self.world: SimWorld | None = None
        self._link: SimTransport | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            self.world = attach(self._port)
        except SimUrlError as exc:
            raise SerialException(str(exc)) from exc
        self._link = SimTransport(self.world.network, baudrate=self._baudrate, timeout=self._timeout)
        self._link.port = self._port
        self.is_open = True

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
        self.is_open = False

    def _reconfigure_port(self, *args, **kwargs) -> None:
        if self._link is not None:
            self._link.baudrate = self._baudrate  # the host's line rate, judged by every module
            self._link.timeout = self._timeout

    def _linked(self) -> SimTransport:
        if not self.is_open or self._link is None:
            raise PortNotOpenError()
        return self._link

    # --- byte I/O ---------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        return self._linked().in_waiting

    def read(self, size: int = 1) -> bytes:
        link = self._linked()
        link.timeout = self._timeout
        return link.read(size)

    def write(self, data) -> int:
        return self._linked().write(data)

    def flush(self) -> None:
        self._linked().flush()

    def reset_input_buffer(self) -> None:
        self._linked().reset_input_buffer()

    def reset_output_buffer(self) -> None:
        self._linked().reset_output_buffer()

    @property
    def out_waiting(self) -> int:
        return 0

    # modem lines: not wired on an NMC network
    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True

    # --- the world's clock ------------------------------------------------------
    @property
    def virtual(self) -> bool:
        """True on the virtual clock: the machine then samples every few ms of machine time (a sample costs CPU,
        not time), as on the simulator's own transport."""
        return self._link is not None and self._link.virtual

    def now(self) -> float:
        return self._linked().now()

    def sleep(self, seconds: float) -> None:
        self._linked().sleep(seconds)

    def rest(self, seconds: float) -> None:
        self._linked().rest(seconds)
