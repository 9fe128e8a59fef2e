"""`cmm serve`: start the station and serve the browser UI (viser) and the pendant page.

With no arguments the simulated CMM is served over TCP on loopback and the
driver talks to it through that byte stream; ``--serial`` drives real
hardware through any pyserial URL with the same UI.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--serial", metavar="URL", default=None,
                        help="pyserial URL of the NMC network (/dev/ttyUSB0, COM3, socket://host:port); "
                             "default: the built-in simulator")
    parser.add_argument("--baud", type=int, default=None, help="baud rate after start-up (19200, 57600, 115200)")
    parser.add_argument("--http-port", type=int, default=8080, help="port of the browser station (default 8080)")
    parser.add_argument("--pendant-port", type=int, default=None,
                        help="port of the pendant page (default: the HTTP port + 1)")
    parser.add_argument("--part", metavar="FILE", default=None,
                        help="the part: STEP/IGES (exact surfaces) or a mesh (STL, OBJ, PLY, 3MF, GLB); on the simulator "
                             "it is also the part on the table")
    parser.add_argument("--part-pose", metavar="X,Y,Z[,RZ]", default=None,
                        help="where the part's CAD origin sits in machine coordinates (mm), turned RZ degrees about Z")
    parser.add_argument("--config", metavar="FILE", default=None, help="machine configuration TOML")
    parser.add_argument("--lan", action="store_true",
                        help="listen on every interface (0.0.0.0) and print an access code for remote operators")
    parser.add_argument("--lan-stop", action="store_true",
                        help="with --lan: anonymous LAN observers may press STOP / E-STOP too (default: only the "
                             "station PC, the holder and clients that gave the access code)")
    parser.add_argument("--allow-host", metavar="NAME", action="append", default=[],
                        help="another host name browsers may use to reach the station (a DNS alias); "
                             "unknown names are refused against DNS rebinding")
    parser.add_argument("--sessions", metavar="DIR", default="sessions", help="where session journals go")
    parser.add_argument("--calibration", metavar="DIR", default=None,
                        help="calibration records folder (probe.toml, machine.toml; artifacts/ for the wizard); "
                             "default: ./calibration when it exists")
    parser.add_argument("--ippdme", metavar="ADDR:PORT", nargs="?", const="127.0.0.1:1294", default=None,
                        help="also serve I++ DME clients (PC-DMIS, CALYPSO, ...) on ADDR:PORT "
                             "(default 127.0.0.1:1294; 0.0.0.0:1294 to accept them from the LAN)")
    parser.add_argument("--opcua", metavar="ADDR:PORT", nargs="?", const="127.0.0.1:4840", default=None,
                        help="also serve OPC UA clients (OPC 40210 Geometrical Measuring Systems model) on ADDR:PORT "
                             "(default 127.0.0.1:4840; 0.0.0.0:4840 for the LAN): anonymous clients read, users "
                             "with a role write and call methods")
    parser.add_argument("--users", metavar="FILE", default=None,
                        help="the user file (cmm users add ...): every client logs in and each command is checked "
                             "against its role; default: the local, no-login mode of a single-user bench")
    parser.add_argument("--ippdme-user", metavar="NAME", default=None,
                        help="with --users: the user I++ DME clients act as (the protocol has no login)")
    parser.add_argument("--tls", action="store_true",
                        help="encrypt the page (https / wss on --http-port), the pendant and OPC UA with the station's "
                             "certificate (--tls-cert/--tls-key, or a self-signed one made on first start in ./tls; "
                             "its fingerprint is printed)")
    parser.add_argument("--tls-cert", metavar="FILE", default=None, help="the certificate (PEM) for --tls")
    parser.add_argument("--tls-key", metavar="FILE", default=None, help="its private key (PEM) for --tls")
    parser.add_argument("--trends", metavar="DIR", default="trends",
                        help="this station's trends journal (every program run is a part of its series; default "
                             "./trends)")
    parser.add_argument("--trends-db", metavar="URL", default=None,
                        help="shared trends database, postgresql://user@host/db, that several stations point at "
                             "(default: CMM_TRENDS_DB, else --sessions when it is a postgresql:// URL)")
    parser.add_argument("--station", metavar="NAME", default=None,
                        help="this station's name in the shared trends (default: CMM_STATION, else the host name)")
    parser.add_argument("--no-shadows", dest="shadows", action="store_false",
                        help="draw the 3-D view without the probe's shadow and the environment map's reflections "
                             "(plain lights): each frame several times cheaper for browsers on computers or tablets "
                             "without a graphics processor")
    from ..session.notify import add_arguments as notify_arguments

    notify_arguments(parser)
    parser.add_argument("--tolerance", type=float, default=0.02,
                        help="colour map tolerance, mm: red / blue beyond it, amber / cyan (warning) beyond half "
                             "of it (default 0.02)")


def _fail(message: str) -> int:
    print(f"cmm serve: {message}", file=sys.stderr)
    return 2


def open_trends(args: argparse.Namespace) -> Any:
    """The station's trends (:func:`cmm.session.trends.open_trends`) from --trends, --trends-db and --station."""
    from ..session.trends import open_trends as open_station_trends

    return open_station_trends(args.trends, station=args.station, database=args.trends_db, sessions=args.sessions)


def run(args: argparse.Namespace) -> int:
    from ..station import ConfigError
    from ..station import load_config as load
    from ..metrology.mesh import MeshError
    from ..station import Station
    from ..session.trends import TrendError

    try:
        config = load(args.config) if args.config else None
    except (ConfigError, OSError) as exc:
        return _fail(f"cannot use the machine configuration: {exc}")
    calibration = getattr(args, "calibration", None)
    if calibration is None and Path("calibration").is_dir():
        calibration = "calibration"
    if calibration is not None and not Path(calibration).is_dir():
        return _fail(f"the calibration folder {calibration} does not exist")
    users = certificate = None
    if args.users:
        from ..control.users import UserStore

        try:
            users = UserStore(args.users)
        except (ValueError, OSError) as exc:
            return _fail(str(exc))
        if not len(users):
            return _fail(f"no users in {args.users}: add one first (cmm users --file {args.users} add NAME --role "
                         "admin)")
        if args.ippdme_user and args.ippdme_user not in {u["name"] for u in users.users()}:
            return _fail(f"--ippdme-user {args.ippdme_user}: there is no such user in {args.users}")
    if args.tls or args.tls_cert or args.tls_key:
        from ..control import tls

        try:
            certificate = tls.certificate("tls", args.tls_cert, args.tls_key,
                                          application_uri=f"urn:cmm-station:{args.station or 'CMM'}")
        except (ValueError, OSError) as exc:
            return _fail(f"TLS: {exc}")
        made = "made now, self-signed" if certificate.made else "in use"
        print(f"TLS certificate {certificate.cert_path} ({made}); SHA-256 fingerprint {certificate.fingerprint}")
    from ..control.priority import raise_station_priority

    raise_station_priority()  # before any thread starts: the station's threads inherit it (control/priority.py)
    try:
        trends = open_trends(args)
    except (TrendError, OSError) as exc:
        return _fail(f"cannot record trends in {args.trends}: {exc}")
    from ..station import PlacementError, part_pose_of

    try:
        station = Station(config, port=args.serial, baud=args.baud, part_path=args.part,
                          session_dir=args.sessions, calibration_dir=calibration, trends=trends,
                          part_pose=part_pose_of(args))
    except Exception as exc:  # noqa: BLE001 - serial errors come in many types; say what happened in one line
        trends.close()
        if isinstance(exc, PlacementError):
            return _fail(str(exc))
        if isinstance(exc, MeshError):
            return _fail(f"cannot load the part: {exc}")
        if isinstance(exc, ConfigError):
            return _fail(f"bad machine configuration: {exc}")
        where = args.serial or "the simulator"
        return _fail(f"cannot open {where}: {exc}")
    if calibration is None:
        print("calibration: no records folder (nominal probe and geometry)")
    else:
        for line in station.calibration.log or ["no records: nominal probe and geometry"]:
            print(f"calibration ({calibration}): {line}")
    print(f"trends: {station.measurement.trends.status_text().replace('**', '')}")
    from ..session.notify import NotifyError, from_args

    try:
        notifier = from_args(args, args.sessions)
    except NotifyError as exc:
        station.close()
        trends.close()
        return _fail(str(exc))
    if notifier is not None:
        notifier.log = station.measurement.log
        notifier.attach(station.measurement)
        print("notifications: " + ", ".join(x for x in (notifier.config.webhook, notifier.config.mqtt) if x))
    try:
        station.start()
    except Exception as exc:  # noqa: BLE001
        station.close()
        from .startup_errors import startup_failure

        return _fail(startup_failure(exc, port=station.port, sessions=args.sessions))  # its real cause

    from ..ui.app import StationApp

    from ..control.access import Control

    host = "0.0.0.0" if args.lan else "127.0.0.1"
    try:
        if users is not None:
            from ..control.roles import RolePolicy

            from ..control.users import register_user_verbs

            station.controller.commands.roles = RolePolicy()  # every command checked against the client's role
            register_user_verbs(station.controller.commands, users)  # the admin's page manages the file
        # with --tls the page and the pendant listen on loopback only, behind TLS proxies on the public ports
        # the page gets the command API only
        app = StationApp(station.controller.commands,
                         host="127.0.0.1" if certificate is not None else host,
                         port=_loopback_port() if certificate is not None else args.http_port, lan=args.lan,
                         pendant_port=0 if certificate is not None else args.pendant_port, tolerance=args.tolerance,
                         allow_hosts=tuple(args.allow_host), shadows=args.shadows,
                         control=Control(lan=args.lan, lan_stop=args.lan_stop), users=users)
    except Exception as exc:  # noqa: BLE001
        station.close()
        return _fail(f"cannot start the web server on port {args.http_port}: {exc}")
    proxies = []
    if certificate is not None:
        try:
            proxies = tls_proxies(app, certificate, host, args.http_port, args.pendant_port)
        except OSError as exc:
            app.close()
            station.close()
            return _fail(str(exc))
    page_url = proxies[0].url if proxies else app.url
    pendant_url = proxies[1].url if len(proxies) > 1 else app.pendant_url
    print(f"CMM station on {station.port}; session journal {station.measurement.journal.path if station.measurement.journal else '-'}")
    print(f"Open {page_url} in a browser")
    if args.lan:
        import socket

        scheme = "https" if proxies else "http"
        print(f"On the LAN: {scheme}://{socket.gethostname()}:{args.http_port if proxies else app.port}/ (or this PC's "
              "IP address)")
    if pendant_url:
        print(f"Pendant page: {pendant_url}")
    if app.control.access_code:
        print(f"Access code for remote operators: {app.control.access_code}")
    ippdme = None
    if getattr(args, "ippdme", None):
        from ..ippdme.serve import start as start_ippdme

        try:
            ippdme = start_ippdme(station.controller.commands, args.ippdme, user=None if users is None or
                                  not args.ippdme_user else (args.ippdme_user, next(
                                      u["role"] for u in users.users() if u["name"] == args.ippdme_user)))
            station.serving_ippdme(ippdme.status)  # the page shows who drives the machine through I++
        except (OSError, ValueError) as exc:
            app.close()
            station.close()
            return _fail(str(exc))
    opcua = None
    if getattr(args, "opcua", None):
        from ..opcua.serve import start as start_opcua

        try:
            opcua = start_opcua(station.controller.commands, args.opcua, name=args.station or "CMM",
                                authenticate=None if users is None else users.identify, certificate=certificate)
        except (OSError, ValueError) as exc:
            if ippdme is not None:
                ippdme.close()
            app.close()
            station.close()
            return _fail(str(exc))
    print("Press Ctrl-C to stop.")
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        print("\nstopping...")
    finally:
        if opcua is not None:
            opcua.close()
        if ippdme is not None:
            ippdme.close()
        for proxy in proxies:
            proxy.close()
        app.close()
        station.close()
        station.measurement.trends.close()
        if notifier is not None:
            notifier.close()
    return 0


def _loopback_port() -> int:
    """A free port on 127.0.0.1 for a page behind the TLS proxy."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def tls_proxies(app: Any, certificate: Any, host: str, page_port: int, pendant_port: int | None) -> list[Any]:
    """The page (and the pendant) of ``app``, listening on loopback, served over TLS on ``host``: https / wss on
    ``page_port`` and on ``pendant_port`` (default ``page_port`` + 1), the station's certificate
    (:mod:`cmm.control.tls_proxy`). Raises OSError with the operator's sentence."""
    from ..control.tls_proxy import TlsProxy

    proxies = [TlsProxy(certificate, host, page_port, app.port, name="page").start()]
    try:
        if app.pendant is not None:
            public = page_port + 1 if pendant_port is None else pendant_port
            proxies.append(TlsProxy(certificate, host, public if page_port else 0, app.pendant.port,
                                    name="pendant").start())
    except OSError:
        proxies[0].close()
        raise
    app.origins.ports.update(p.port for p in proxies)  # the pages on the public ports are the station's own
    app.behind_tls_proxy = True  # each client's address comes from the proxy (the access-code rate limit's key)
    if app.pendant is not None:
        app.pendant.behind_tls_proxy = True
    if len(proxies) > 1:  # the page's embedded pendant and its jog-hold socket: the pendant's public https address
        loopback_src, outer = app.pendant_src, proxies[1].port

        def public_pendant_src(client_id: Any) -> str | None:  # "http://HOST:LOOPBACK/" -> "https://HOST:PUBLIC/"
            src = loopback_src(client_id)
            if src is None or not src.startswith("http://"):
                return src
            return f"https://{src.split('/')[2].rsplit(':', 1)[0]}:{outer}/"
        app.pendant_src = public_pendant_src
    return proxies
