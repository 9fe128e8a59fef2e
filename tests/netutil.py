"""Loopback helpers shared by the tests that start servers."""

import asyncio
import socket
import threading


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


class WssClient:
    """A wss client with the sync client's calls (``send``, ``recv(timeout)``, ``close``, a ``with`` block) whose TLS
    socket only one thread touches: websockets' asyncio client on a loop of its own.

    websockets' sync client reads its socket on a thread of its own while the caller's thread writes it. On Python
    3.11 with OpenSSL 3 and TLS 1.3 that is two threads in one SSL object at once (the reader takes the server's
    session tickets while the writer sends the request): beside CPU hogs the request was lost one connect in ten
    and the process's heap was corrupted (``corrupted size vs. prev_size``); the asyncio client, 0 in 300. A browser
    has no such race, so the tests of wss servers connect with this."""

    def __init__(self, url: str, *, ssl: object, open_timeout: float = 60.0, **options: object) -> None:
        from websockets.asyncio.client import connect

        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="wss-client", daemon=True)
        self._thread.start()

        async def open_() -> object:  # connect() gives an awaitable, not the coroutine the loop's hand-off takes
            return await connect(url, ssl=ssl, open_timeout=open_timeout, **options)

        try:
            self._ws = self._call(open_(), open_timeout + 5)
        except BaseException:
            self._stop()
            raise

    def _call(self, coroutine: object, timeout: float | None) -> object:
        future = asyncio.run_coroutine_threadsafe(coroutine, self._loop)
        try:
            return future.result(timeout)
        except TimeoutError:
            future.cancel()
            raise

    def send(self, message: str | bytes) -> None:
        self._call(self._ws.send(message), 60.0)

    def recv(self, timeout: float | None = None) -> str | bytes:
        return self._call(asyncio.wait_for(self._ws.recv(), timeout), None)

    def close(self) -> None:
        if self._loop.is_running():
            try:
                self._call(self._ws.close(), 30.0)
            finally:
                self._stop()

    def _stop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        if not self._thread.is_alive():
            self._loop.close()

    def __enter__(self) -> "WssClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
