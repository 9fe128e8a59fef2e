"""`cmm sim`: serve the simulated PIC-SERVO network over TCP (plain or RFC 2217) or a pseudo-terminal."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--tcp", metavar="HOST:PORT", default=None,
                       help="listen on HOST:PORT (default 127.0.0.1:7777; port 0 picks a free one); "
                            "the driver opens socket://HOST:PORT")
    where.add_argument("--pty", action="store_true", help="create a pseudo-terminal and print its device path")
    where.add_argument("--rfc2217", metavar="HOST:PORT", default=None,
                       help="listen for RFC 2217 clients (rfc2217://HOST:PORT): the client's announced baud rate "
                            "is enforced, as on the pty")
    parser.add_argument("--modules", type=int, default=3, metavar="N",
                        help="modules on the network (default 3; with --cmm, modules after the three axes idle)")
    parser.add_argument("--no-wire-time", dest="wire_time", action="store_false",
                        help="deliver bytes instantly instead of 10 bits per baud each way")
    parser.add_argument("--firmware", choices=("pic-servo", "pic-servo-sc"), default=None,
                        help="firmware family: version, SET_BAUD table, SC-only status items and IO_CTRL bits "
                             "(default pic-servo; with --cmm the machine configuration's)")
    parser.add_argument("--module-version", type=int, default=None, metavar="V",
                        help="version byte reported in status item 0x20 (default 4, SC: 10)")
    cmm = parser.add_argument_group("simulated CMM (--cmm)")
    cmm.add_argument("--cmm", action="store_true",
                     help="serve the whole simulated CMM: 3 axes, the sample part on the table, a 25 mm reference "
                          "sphere and a touch-trigger probe on the LIMIT inputs")
    cmm.add_argument("--config", metavar="FILE", help="machine configuration (axes, probe wiring); default shipped")
    from ..sim.placement import add_part_arguments

    add_part_arguments(cmm)
    cmm.add_argument("--no-home-switches", dest="home_switches", action="store_false",
                     help="serve the CMM without home switches (by default it has the ones the configuration's "
                          "[homing] cycle looks for, as the real machine does)")
    cmm.add_argument("--scale-ppm", type=float, nargs=3, metavar=("X", "Y", "Z"), default=(0.0, 0.0, 0.0),
                     help="injected per-axis scale errors, ppm")
    cmm.add_argument("--squareness-urad", type=float, nargs=3, metavar=("XY", "XZ", "YZ"), default=(0.0, 0.0, 0.0),
                     help="injected squareness errors, urad")


def banner(network, url: str, pty: bool) -> str:
    """Start-up text: what is served, and the gains a host must send."""
    from cmm.sim.plant import DEFAULT_GAINS as g
    from cmm.sim.plant import DEFAULT_PLANT as p

    if pty:
        where = f"device {url}   (open it at 19200 8N1; the rate you set is the host's rate)"
    elif url.startswith("rfc2217://"):
        where = f"driver URL {url}   (RFC 2217: the baud rate the client announces is enforced, 19200 until then)"
    else:
        where = (f"driver URL {url}   (TCP carries no line rate: the host is taken to follow every SET_BAUD, "
                 f"so a host that never switches passes here; --pty is the faithful path)")
    return "\n".join([
        f"cmm sim: {len(network.modules)} simulated PIC-SERVO modules (firmware {network.firmware}, "
        f"version {network.version}), wire-time emulation {'on' if network.wire_time else 'off'}",
        f"  {where}",
        "  power-up gains are 0: send SET_GAIN to every module with",
        f"    Kp {g.kp}  Kd {g.kd}  Ki {g.ki}  IL {g.il}  OL {g.ol}  CL {g.cl}  EL {g.el}  SR {g.sr}  DB {g.db}",
        f"    SET_GAIN data bytes: {g.to_bytes().hex(' ')}",
        f"  plant per axis: {p.supply_v:g} V motor, {p.lead_mm:g} mm lead, {p.counts_per_mm:g} counts/mm, "
        f"top speed about {p.top_speed_mm_s:.0f} mm/s",
        "  Ctrl-C stops.",
    ])


def _cmm_network(args: argparse.Namespace):
    """The simulated CMM's network (its world drives the probe inputs every tick)."""
    from cmm.machine.config import load
    from cmm.sim.cmm_sim import CmmSimSettings, SimulatedCMM
    from cmm.sim.probe_world import GeometryErrors

    config = load(args.config)
    settings = CmmSimSettings(errors=GeometryErrors(tuple(args.scale_ppm), tuple(args.squareness_urad)))
    _place(args, config, settings)
    cmm = SimulatedCMM(config, settings, wire_time=args.wire_time, realtime=True,
                       n_modules=args.modules, firmware=args.firmware, version=args.module_version)
    switches = ""
    if args.home_switches:  # as the station's own simulator has them
        from cmm.sim.home_switches import for_homing

        if for_homing(cmm, config.homing) is not None:
            switches = f", home switches on {config.homing.input.upper()}"
    what = f"the part {Path(args.part).name}" if args.part else "the sample part"
    exact = "" if args.part_pose is None else " (exactly as --part-pose says)"
    print(f"cmm sim: simulated CMM, {what} at X={settings.part_pose[0, 3]:.2f} Y={settings.part_pose[1, 3]:.2f} "
          f"Z={settings.part_pose[2, 3]:.2f}{exact or ' (not exactly where the station assumes)'}, reference sphere D {settings.sphere_diameter:g} mm "
          f"at {settings.sphere_centre}{switches}", flush=True)
    return cmm.network


def _place(args: argparse.Namespace, config, settings) -> None:
    """--part and --part-pose: the part on the table, checked against the reference sphere and the table."""
    from cmm.metrology.mesh import load_part

    from ..sim.cmm_sim import TRUE_PART_POSE
    from ..sim.placement import check_placement, part_pose_of, travel_of
    from ..sim.sample_part import sample_part

    pose = part_pose_of(args)
    if args.part is None and pose is None:
        return
    mesh = load_part(args.part) if args.part else sample_part()[0]
    if pose is None:
        shift = np.eye(4)
        shift[:3, 3] = -mesh.bounds[0]
        pose = TRUE_PART_POSE @ shift
    check_placement(mesh, pose, sphere_centre=settings.sphere_centre, sphere_diameter=settings.sphere_diameter,
                    travel=travel_of(config), name=f"the part {Path(args.part).name}" if args.part else "the sample part")
    settings.part_mesh = mesh if args.part else None
    settings.part_pose = pose


def run(args: argparse.Namespace) -> int:
    import signal
    import sys
    import threading

    from cmm.sim.network import SimNetwork
    from cmm.sim.serve import serve_pty, serve_tcp

    try:
        if args.cmm:
            network = _cmm_network(args)
        else:
            network = SimNetwork(args.modules, version=args.module_version, wire_time=args.wire_time,
                                 realtime=True, firmware=args.firmware or "pic-servo")
    except ValueError as exc:  # ConfigError, MeshError and PlacementError are ValueErrors
        print(f"cmm sim: {exc}", file=sys.stderr)
        return 2
    if args.pty:
        handle = serve_pty(network)
    else:
        address = args.rfc2217 or args.tcp or "127.0.0.1:7777"
        host, _, port = address.rpartition(":")
        try:
            handle = serve_tcp(network, host or "127.0.0.1", int(port), rfc2217=args.rfc2217 is not None)
        except (OSError, ValueError) as exc:
            print(f"cmm sim: cannot listen on {address}: {exc}", file=sys.stderr)
            return 1
    print(banner(network, handle.url, args.pty), flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        handle.close()
    print("cmm sim: stopped", flush=True)
    return 0
