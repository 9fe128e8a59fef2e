"""What an open station page costs the computer whose browser shows it, without a graphics processor.

Starts the station on the simulator with its page (``cmm serve`` as a library), opens the page in Debian's
headless chromium (software WebGL: SwiftShader in chromium's GPU process), lets it stand idle, and prints the CPU
seconds per wall second of each kind of chromium process (the GPU process draws the 3-D view, the renderer runs
the page's script and lays out the panel) and the frames the view drew, for each way of drawing it:

- ``full``: shadows and the environment map (the default of ``cmm serve``);
- ``no-shadows``: ``cmm serve --no-shadows`` (no shadow maps, no environment map: plain lights);
- ``tests``: as the browser tests draw it (``--no-shadows``, the view at 0.25 device pixels per CSS pixel).

The figures come from /proc (chromium's processes are not children the kernel accounts to this script).

    python benchmarks/bench_page_cpu.py [--seconds 15] [--size 1280x800]
"""

from __future__ import annotations

import argparse
import glob
import re
import socket
import tempfile
import time

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]
WAYS = {"full": (True, None), "no-shadows": (False, None), "tests": (False, 0.25)}  # shadows, view's device pixels


def chromium_cpu() -> dict[str, float]:
    """CPU seconds so far of every chromium process, summed by its --type (browser, renderer, gpu-process ...)."""
    out: dict[str, float] = {}
    for d in glob.glob("/proc/[0-9]*"):
        try:
            cmd = open(d + "/cmdline", "rb").read().replace(b"\0", b" ")
            if b"chromium" not in cmd.split(b" ")[0]:
                continue
            fields = open(d + "/stat").read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        m = re.search(rb"--type=(\S+)", cmd)
        kind = m.group(1).decode() if m else "browser"
        out[kind] = out.get(kind, 0.0) + (int(fields[11]) + int(fields[12])) / 100.0
    return out


def _keep_moving(station, stop) -> None:
    """Go to and fro 100 mm in X and Y high above the table until ``stop`` is set (the simulator uncapped, as in
    the tests)."""
    ctl = station.controller
    while not stop.is_set():
        for target in ([150.0, 150.0, 280.0], [250.0, 250.0, 280.0]):
            ctl.move(None, target, frame="machine", path="straight").wait(120)


def measure(way: str, seconds: float, size: tuple[int, int], moving: bool = False) -> None:
    import threading

    from playwright.sync_api import sync_playwright

    from cmm.station import Station
    from cmm.ui.app import StationApp

    shadows, view_dpr = WAYS[way]
    station = Station(port="sim://?cmm=1", session_dir=tempfile.mkdtemp(prefix="bench-page-")).start(home=True)
    with socket.socket() as sock:  # a free port on loopback for the page
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    app = StationApp(station.controller.commands, host="127.0.0.1", port=port, ask_name=False, shadows=shadows, pendant=False)
    url = app.url + (f"?fixedDpr={view_dpr:g}" if view_dpr else "")
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": size[0], "height": size[1]}, device_scale_factor=0.5)
            page.add_init_script("""(() => { const raf = window.requestAnimationFrame.bind(window); window.__frames = 0;
                window.requestAnimationFrame = (cb) => raf((t) => { window.__frames++; cb(t); }); })();""")
            page.goto(url)
            page.get_by_role("button", name="E-STOP").wait_for(timeout=120_000)
            page.wait_for_timeout(5000)  # past the first paint and the shaders' compilation
            stop = threading.Event()
            mover = threading.Thread(target=_keep_moving, args=(station, stop), daemon=True)
            if moving:
                mover.start()
            before, frames, t0 = chromium_cpu(), page.evaluate("window.__frames"), time.monotonic()
            page.wait_for_timeout(seconds * 1000)
            after, dt = chromium_cpu(), time.monotonic() - t0
            stop.set()
            if moving:
                mover.join(60)
            drawn = page.evaluate("window.__frames") - frames
            browser.close()
    finally:
        app.close()
        station.close()
    cost = {k: (after.get(k, 0.0) - before.get(k, 0.0)) / dt for k in after}
    busiest = ", ".join(f"{k} {v:.2f}" for k, v in sorted(cost.items(), key=lambda kv: -kv[1]) if v >= 0.005)
    print(f"{way:11s} {'moving' if moving else 'idle'} page {size[0]}x{size[1]}: {sum(cost.values()):.2f} of a core ({busiest}); "
          f"{drawn / dt:.1f} animation frames a second")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="idle time measured per way (s)")
    parser.add_argument("--size", default="1280x800", help="the page's size in CSS pixels, WxH")
    parser.add_argument("--way", choices=sorted(WAYS), action="append", help="only these ways (default: all)")
    parser.add_argument("--moving", action="store_true",
                        help="the machine moving to and fro meanwhile (the simulator uncapped, as in the tests)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    for way in args.way or list(WAYS):
        measure(way, args.seconds, (width, height), args.moving)


if __name__ == "__main__":
    main()
