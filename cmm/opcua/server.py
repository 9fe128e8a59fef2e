"""The OPC UA server: a front end on the command API, serving the GMS model (:mod:`cmm.opcua.model`).

It receives only the command API (``station.controller.commands``) and never reads the station: it subscribes to
the API's queries (:meth:`cmm.api.CommandAPI.subscribe`: ``state``, ``position``, ``job`` at ``rate`` Hz, 10
by default; ``probe_in_use`` and ``report_info`` once a second) and writes what each delivery changed into the
address space, so subscribed clients see the machine move at no more than that rate whatever the machine does;
an idle machine sends nothing. A run's characteristics are a query when it ends. A finished program run becomes a result (``GMSResultType``) in
``ResultManagement/Results`` (the last :data:`KEEP_RESULTS`).

Writes (the report header) and methods (``StartProgram``, ``Stop``) are commands of the session's client: an
anonymous session is an observer that cannot take control, so the API refuses them (``BadUserAccessDenied``);
a user session (name and password, checked by ``authenticate``) takes control as its user and the API's role
table decides (:mod:`cmm.control.roles`). Everything else in the model is read-only.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Callable

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_session import InternalSession

from . import model

log = logging.getLogger(__name__)
KEEP_RESULTS = 20
CURRENT_USER: contextvars.ContextVar[Any] = contextvars.ContextVar("opcua_user", default=None)


@dataclass
class StationUser(User):
    """An OPC UA session's user: the station's name for it and the role the user file gives it."""

    station_role: str | None = None


class _Users:
    """asyncua's user manager over the station's ``authenticate(name, password) -> (user, role) | role | None``
(:meth:`cmm.control.users.UserStore.identify`)."""

    def __init__(self, authenticate: Callable[[str, str], Any] | None) -> None:
        self.authenticate = authenticate

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if not username:  # asyncua's "User" role lets it read, browse and subscribe; the API refuses it commands
            return StationUser(role=UserRole.User)
        if self.authenticate is None:
            return None  # no user file: nobody logs in
        found = self.authenticate(username, password or "")
        if found is None:
            return None  # BadUserAccessDenied
        name, role = found if isinstance(found, tuple) else (username, found)  # a token names its holder
        return StationUser(role=UserRole.User, name=name, station_role=str(role))


class OpcUaServer:
    """``OpcUaServer(api, host, port).start()``; ``close()`` stops it. ``url`` is its endpoint."""

    def __init__(self, api: Any, host: str = "127.0.0.1", port: int = 4840, *, name: str = "CMM",
                 identification: dict[str, str] | None = None, authenticate: Callable[[str, str], Any] | None = None,
                 client_factory: Callable[[str | None, str | None], Any] | None = None, rate: float = 10.0,
                 certificate: Any = None) -> None:
        if not 0.1 <= rate <= 50.0:
            raise ValueError(f"the OPC UA update rate must be 0.1 to 50 per second, got {rate:g}")
        self.api = api
        self.host, self.port, self.name = host, int(port), name
        self.identification = dict(identification or {})
        self.authenticate = authenticate
        self.client_factory = client_factory or default_client
        self.rate = float(rate)
        self.certificate = certificate  # cmm.control.tls.Certificate: Basic256Sha256 sign & encrypt besides None
        self.updates = 0  # passes of the update task that wrote something (the benchmark reads it)
        self.results = 0
        self.kept: dict[str, Any] = {}  # ResultId -> ResultDataType, oldest first (the last KEEP_RESULTS)
        self.errors: list[str] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._failure: BaseException | None = None
        self._last: dict[str, Any] = {}  # what the address space shows, by path
        self._latest: dict[str, Any] = {}  # the API's queries as last delivered
        self._subscriptions: list[Any] = []
        self.deliveries = 0  # change deliveries applied (each is at most one per subscription period)
        self._workers: list[threading.Thread] = []

    @property
    def application_uri(self) -> str:
        return f"urn:cmm-station:{self.name}"

    @property
    def url(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}/"

    # --- life cycle ---------------------------------------------------------------------
    def start(self, timeout: float = 120.0) -> "OpcUaServer":
        self._thread = threading.Thread(target=self._run, name="opcua", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f"the OPC UA server did not start within {timeout:.0f} s")
        if self._failure is not None:
            raise OSError(f"cannot serve OPC UA on {self.host}:{self.port}: {self._failure}") from None
        return self

    def close(self, timeout: float = 10.0) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start() or logged
            if not self._ready.is_set():
                self._failure = exc
            else:
                log.exception("the OPC UA server failed")
                self.errors.append(str(exc))
        finally:
            self._ready.set()
            loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        server = Server(user_manager=_Users(self.authenticate))
        await server.init()
        server.set_endpoint(self.url)
        server.set_server_name(f"CMM station {self.name}")
        policies = [ua.SecurityPolicyType.NoSecurity]
        if self.certificate is not None:
            await server.set_application_uri(self.application_uri)  # the certificate names it
            await server.load_certificate(str(self.certificate.cert_path))
            await server.load_private_key(str(self.certificate.key_path))
            policies.append(ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt)
        server.set_security_policy(policies)
        self.served = await model.build(server, self.name)
        await self._methods(server)
        await self._result_methods()
        _install_sessions(server, self)
        self.server = server
        await self._fill_identification()
        async with server:
            await self._follow()

    async def _follow(self) -> None:
        """Follow the API's change streams until close(): the machine's at ``rate``, the probe's and the report
        header's once a second; each delivery (only what changed) is written into the address space."""
        loop = asyncio.get_running_loop()
        changes: asyncio.Queue[dict[str, Any]] = asyncio.Queue()

        def deliver(changed: dict[str, Any]) -> None:  # on the API's subscription thread
            if not loop.is_closed():
                loop.call_soon_threadsafe(changes.put_nowait, changed)

        observer = self.client_factory(None, None)
        subs = [self.api.subscribe(observer, {"state": {}, "position": {"frame": "machine"}, "job": {}}, deliver,
                                   rate=self.rate),
                self.api.subscribe(observer, {"probe_in_use": {}, "report_info": {}}, deliver, rate=1.0)]
        self._subscriptions = subs
        self._ready.set()
        stop = asyncio.ensure_future(self._stop.wait())
        try:
            while not self._stop.is_set():
                get = asyncio.ensure_future(changes.get())
                await asyncio.wait({get, stop}, return_when=asyncio.FIRST_COMPLETED)
                if not get.done():
                    get.cancel()
                    break
                changed = dict(get.result())
                while not changes.empty():  # a slow pass: what arrived meanwhile, merged (the newest wins)
                    changed.update(changes.get_nowait())
                try:
                    await self._apply(changed)
                except Exception as exc:  # noqa: BLE001 - one bad delivery must not end the server
                    log.exception("OPC UA update failed")
                    self.errors.append(str(exc))
        finally:
            for sub in subs:
                sub.close()
            stop.cancel()

    # --- the API, as the session's client ----------------------------------------------------
    def client_for(self, user: Any) -> Any:
        name = getattr(user, "name", None) if isinstance(user, StationUser) else None  # None: anonymous
        role = getattr(user, "station_role", None) if isinstance(user, StationUser) else None
        return self.client_factory(name, role)

    async def _api(self, client: Any, method: str, **params: Any) -> Any:
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(None, lambda: self.api.call(client, method, params))

    async def command(self, user: Any, method: str, **params: Any) -> tuple[bool, str]:
        """Take control as the session's client, then run ``method``; (ok, the API's sentence)."""
        client = self.client_for(user)
        if method not in ("stop", "cancel"):  # STOP needs no control (the API's stop rule decides)
            answer = await self._api(client, "take_control")
            if not answer.ok:
                return False, answer.error["message"]
        answer = await self._api(client, method, **params)
        return answer.ok, (answer.error["message"] if not answer.ok else "")

    async def _methods(self, server: Server) -> None:
        prod = self.served.nodes["Production"]
        ns = self.served.ns[model.STATION]
        start_id = self.served.nodes["Production/StartProgram"]
        stop_id = self.served.nodes["Production/Stop"]

        async def start_program(parent: Any, path: Any) -> Any:
            user = CURRENT_USER.get()
            client = self.client_for(user)
            taken = await self._api(client, "take_control")
            if not taken.ok:
                return _refused(taken.error["message"])
            # the run holds the machine until it ends: started in a thread of its own, the method returns at once
            done = threading.Event()
            outcome: dict[str, Any] = {}

            def run() -> None:
                outcome["answer"] = self.api.call(client, "run_program", {"path": str(path.Value)})
                done.set()
            worker = threading.Thread(target=run, name="opcua-program", daemon=True)
            worker.start()
            self._workers.append(worker)
            await asyncio.get_running_loop().run_in_executor(None, done.wait, 0.5)
            answer = outcome.get("answer")
            if answer is not None and not answer.ok and answer.error["code"] != "cancelled":
                return _refused(answer.error["message"], bad=answer.error["code"] == "refused")
            return [ua.Variant("started" if answer is None else "finished", ua.VariantType.String)]

        async def stop(parent: Any) -> Any:
            user = CURRENT_USER.get()
            if not isinstance(user, StationUser) or not user.name:
                return _refused("STOP over OPC UA needs a user (log in with a name and password); anonymous "
                                "sessions only observe")
            ok, why = await self.command(user, "stop")
            await self._api(self.client_for(user), "cancel")
            return [ua.Variant("stopped" if ok else why, ua.VariantType.String)] if ok else _refused(why)

        arg = ua.Argument(Name="ProgramPath", DataType=ua.NodeId(ua.ObjectIds.String), ValueRank=-1,
                          Description=ua.LocalizedText("the measurement program file (TOML) on the station"))
        out = ua.Argument(Name="Message", DataType=ua.NodeId(ua.ObjectIds.String), ValueRank=-1)
        await prod.add_method(start_id, ua.QualifiedName("StartProgram", ns), start_program, [arg], [out])
        await prod.add_method(stop_id, ua.QualifiedName("Stop", ns), stop, [], [out])

    async def write_report(self, user: Any, field: str, value: Any) -> tuple[bool, str]:
        """A client writes a report header field: the ``set_info`` verb as its client."""
        return await self.command(user, "set_info", **{field: value})

    # --- updates -------------------------------------------------------------------------
    async def _fill_identification(self) -> None:
        ident = {"Manufacturer": "CMM station", "Model": "PIC-SERVO bridge CMM", "SerialNumber": self.name,
                 "ProductInstanceUri": f"urn:cmm-station:{self.name}", "SoftwareRevision": _version(),
                 "DeviceClass": "coordinate measuring machine", "Location": "", **self.identification}
        for key, value in ident.items():
            node = self.served.nodes[f"Identification/{key}"]
            if key in ("Manufacturer", "Model"):
                await node.write_value(ua.LocalizedText(value))
            else:
                await node.write_value(ua.Variant(str(value), ua.VariantType.String))
        await self.served.nodes["Monitoring/Axes/Name"].write_value(ua.Variant("X, Y, Z (machine frame, mm)",
                                                                              ua.VariantType.String))

    async def _set(self, path: str, value: Any, vtype: ua.VariantType | None = None) -> None:
        if self._last.get(path, _UNSET) == value:
            return
        self._last[path] = value
        node = self.served.nodes[path] if not path.startswith("/") else self.server.get_node(path[1:])
        await node.write_value(ua.Variant(value, vtype) if vtype is not None else value)

    async def _state_machine(self, path: str, type_ref: tuple[str, int], state: str) -> None:
        if self._last.get(path) == state:
            return
        self._last[path] = state
        node = self.served.nodes[path]
        await node.write_value(ua.LocalizedText(state))
        ident = await node.get_child(ua.QualifiedName("Id", 0))
        await ident.write_value(ua.Variant(self.served.state_ids[(type_ref, state)], ua.VariantType.NodeId))

    async def _apply(self, changed: dict[str, Any]) -> None:
        """Write what the API's change streams delivered (JSON values of its queries) into the address space."""
        self.deliveries += 1
        for key, value in changed.items():
            if isinstance(value, dict) and set(value) == {"error"}:
                self.errors.append(f"{key}: {value['error']}")
                continue
            self._latest[key] = value
        latest = self._latest
        pos = changed.get("position")
        if isinstance(pos, list) and len(pos) == 3:
            xyz = [round(float(v), 4) for v in pos]
            if self._last.get("position") != xyz:
                self._last["position"] = xyz
                node = self.served.nodes["Monitoring/Axes/Position"]
                await node.write_value(ua.ThreeDCartesianCoordinates(X=xyz[0], Y=xyz[1], Z=xyz[2]))
                for axis, v in zip("XYZ", xyz):
                    child = await node.get_child(ua.QualifiedName(axis, 0))
                    await child.write_value(ua.Variant(v, ua.VariantType.Double))
                self.updates += 1
        if ("state" in changed or "job" in changed) and isinstance(latest.get("state"), dict):
            st = latest["state"]
            mode = str(getattr(st.get("mode"), "value", st.get("mode")))
            running = latest.get("job") if isinstance(latest.get("job"), list) else []
            programs = [j for j in running if str(j["description"]).startswith("program")]
            await self._set("Monitoring/Axes/Mode", mode, ua.VariantType.String)
            await self._set("Monitoring/Axes/Reason", str(st.get("reason") or ""), ua.VariantType.String)
            await self._set("Monitoring/Axes/Homed", bool(st.get("homed")), ua.VariantType.Boolean)
            await self._state_machine("Monitoring/MachineTool/MachineryItemState/CurrentState",
                                      (model.MACHINERY, 1002), item_state(mode, bool(running), bool(st.get("link_ok"))))
            await self._state_machine("Monitoring/MachineTool/MachineryOperationMode/CurrentState",
                                      (model.MACHINERY, 1008), operation_mode(mode, bool(programs)))
            await self._set("Monitoring/MachineTool/OperationMode", 1 if programs else 0, ua.VariantType.Int32)
            await self._program(programs)
        probe = changed.get("probe_in_use")
        if isinstance(probe, dict) and "name" in probe:
            await self._set("Equipment/Tools/Probe/Name", str(probe["name"]), ua.VariantType.String)
            await self._set("Equipment/Tools/Probe/Identifier", str(probe["name"]), ua.VariantType.String)
            status = {"qualified": 0, "expired": 1}.get(probe.get("status"), 2)
            await self._set("Equipment/Tools/Probe/IsQualifiedStatus", status, ua.VariantType.Int32)
            diameter = probe.get("tip_diameter") if probe.get("tip_radius") is None else 2 * probe["tip_radius"]
            if diameter is not None:
                await self._set("Equipment/Tools/Probe/TipDiameter", float(diameter), ua.VariantType.Double)
        info = changed.get("report_info")
        if isinstance(info, dict):
            for key in model.REPORT_FIELDS:
                value = info.get(key)
                text = "" if value is None else (f"{value:g}" if isinstance(value, float) else str(value))
                if self._last.get(f"report/{key}") != text:
                    self._last[f"report/{key}"] = text
                    await self.served.report[key].write_value(ua.Variant(text, ua.VariantType.String))

    async def _program(self, programs: list[dict[str, Any]]) -> None:
        """The active program and the production plan's job (one program run is one job) from the ``job`` query."""
        now = programs[0] if programs else None
        was = self._last.get("program")
        job, prog = "Production/ProductionPlan/Job", "Production/ProductionPlan/Job/ProductionPrograms/Program"
        if now is not None:
            self._last["program"] = now
            name = str(now["description"]).removeprefix("program ").strip("'\"")
            self._last["program_name"] = name
            if self._last.get("program_started") is None or was is None:
                self._last["program_started"] = datetime.now(timezone.utc)
                self._last["job_number"] = self._last.get("job_number", 0) + 1
            ident = f"{self.name}-{self._last['job_number']}"
            percent = round(100.0 * now["done"] / now["total"], 1) if now["total"] else 0.0
            for base in ("Production/ActiveProgram", prog):
                await self._set(f"{base}/Name", name, ua.VariantType.String)
                await self._set(f"{base}/NumberInList", 0, ua.VariantType.UInt16)
                await self._set(f"{base}/Progress", percent, ua.VariantType.Double)
            await self._set("Production/ActiveProgram/JobIdentifier", ident, ua.VariantType.String)
            await self._set("Production/ActiveProgram/Step", str(now["step"]), ua.VariantType.String)
            await self._set(f"{job}/Identifier", ident, ua.VariantType.String)
            await self._set(f"{job}/NumberInList", 0, ua.VariantType.UInt16)
            await self._set(f"{job}/RunsPlanned", 1, ua.VariantType.UInt32)
            await self._set(f"{job}/RunsCompleted", 0, ua.VariantType.UInt32)
            await self._set(f"{job}/Duration", self._elapsed_ms(), ua.VariantType.Double)
            await self._states("Running")
        elif was is not None:  # the run ended: its result, and the program's and the job's state Ended
            self._last["program"] = None
            await self._set(f"{job}/Duration", self._elapsed_ms(), ua.VariantType.Double)
            await self._set(f"{job}/RunsCompleted", 1, ua.VariantType.UInt32)
            for base in ("Production/ActiveProgram", prog):
                await self._set(f"{base}/Progress", 100.0, ua.VariantType.Double)
            await self._states("Ended")
            await self._publish_result()
        elif "Production/ActiveProgram/State/CurrentState" not in self._last:
            await self._states("Initializing")

    async def _states(self, state: str) -> None:
        prog = "Production/ProductionPlan/Job/ProductionPrograms/Program"
        for path in ("Production/ActiveProgram", prog):
            await self._state_machine(f"{path}/State/CurrentState", (model.MACHINE_TOOL, 15), state)
        await self._state_machine("Production/ProductionPlan/Job/State/CurrentState", (model.MACHINE_TOOL, 28), state)

    def _elapsed_ms(self) -> float:
        started = self._last.get("program_started")
        return 0.0 if started is None else round((datetime.now(timezone.utc) - started).total_seconds() * 1000.0, 0)

    async def _publish_result(self) -> None:
        observer = self.client_factory(None, None)
        answer = await self._api(observer, "characteristics")
        rows = answer.result if answer.ok else []
        self.results += 1
        verdicts = [r["ok"] for r in rows if r["ok"] is not None]
        evaluation = 3 if not verdicts else (1 if all(verdicts) else 2)  # NotDecidable / OK / NotOK
        started = self._last.get("program_started") or datetime.now(timezone.utc)
        self._last["program_started"] = None
        job = f"{self.name}-{self._last.get('job_number', 0)}"
        meta = ua.ResultMetaDataType(
            ResultId=f"{job}-result", JobId=job, PartId=self._last.get("report/part_number") or None,
            InternalRecipeId=self._last.get("program_name"), CreationTime=datetime.now(timezone.utc),
            ProcessingTimes=ua.ProcessingTimesDataType(StartTime=started, EndTime=datetime.now(timezone.utc)),
            ResultEvaluation=evaluation, IsSimulated=None,
            ResultEvaluationDetails=ua.LocalizedText(
                f"{sum(1 for v in verdicts if v)} of {len(verdicts)} characteristics in tolerance"))
        content = [ua.Variant(f"{r['name']}: {r['value']:.4f} {r['unit']}"
                              + ("" if r["ok"] is None else (" OK" if r["ok"] else " NOT OK")), ua.VariantType.String)
                   for r in rows]
        value = ua.ResultDataType(ResultMetaData=meta, ResultContent=content)
        self.kept[meta.ResultId] = value
        while len(self.kept) > KEEP_RESULTS:
            self.kept.pop(next(iter(self.kept)))
        folder = self.served.results
        ns = self.served.ns[model.STATION]
        nid = ua.NodeId(f"{self.name}/ResultManagement/Results/{self.results}", ns)
        node = await folder.add_variable(nid, ua.QualifiedName(f"Result{self.results}", ns), value,
                                         datatype=self.served.nid((model.RESULT, 3008)))
        await node.delete_reference(ua.NodeId(ua.ObjectIds.BaseDataVariableType), ua.ObjectIds.HasTypeDefinition)
        await node.add_reference(self.served.nid((model.GMS, 2004)), ua.ObjectIds.HasTypeDefinition)
        old = self.results - KEEP_RESULTS
        if old >= 1:
            await self.server.delete_nodes([self.server.get_node(
                ua.NodeId(f"{self.name}/ResultManagement/Results/{old}", ns))], recursive=True)

    async def _result_methods(self) -> None:
        """GetLatestResult(Timeout) and GetResultById(ResultId, Timeout) of the Machinery Result model: the kept
        results (the last :data:`KEEP_RESULTS`); ResultHandle is always 0 (no handles to release), Error 0 when
        found, -1 when the station has no result yet, -2 when the id is not (or no longer) kept. Anonymous
        clients may call them: they only read."""
        rm = self.served.nodes["ResultManagement"]
        rns = self.served.ns[model.RESULT]
        timeout = ua.Argument(Name="Timeout", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1,
                              Description=ua.LocalizedText("how long the client needs the result (ms); a hint"))
        result_id = ua.Argument(Name="ResultId", DataType=ua.NodeId(ua.ObjectIds.TrimmedString), ValueRank=-1,
                                Description=ua.LocalizedText("the ResultId of a result's ResultMetaData"))
        outputs = [ua.Argument(Name="ResultHandle", DataType=ua.NodeId(ua.ObjectIds.Handle), ValueRank=-1),
                   ua.Argument(Name="Result", DataType=self.served.nid((model.RESULT, 3008)), ValueRank=-1),
                   ua.Argument(Name="Error", DataType=ua.NodeId(ua.ObjectIds.Int32), ValueRank=-1)]

        def answer(value: Any, error: int) -> list[ua.Variant]:
            if value is None:
                value = ua.ResultDataType(ResultMetaData=ua.ResultMetaDataType(ResultId=""), ResultContent=[])
            return [ua.Variant(0, ua.VariantType.UInt32), ua.Variant(value, ua.VariantType.ExtensionObject),
                    ua.Variant(error, ua.VariantType.Int32)]

        async def latest(parent: Any, _timeout: Any) -> list[ua.Variant]:
            if not self.kept:
                return answer(None, -1)
            return answer(self.kept[next(reversed(self.kept))], 0)

        async def by_id(parent: Any, wanted: Any, _timeout: Any) -> list[ua.Variant]:
            value = self.kept.get(str(wanted.Value))
            return answer(value, 0 if value is not None else -2)

        await rm.add_method(self.served.nodes["ResultManagement/GetLatestResult"],
                            ua.QualifiedName("GetLatestResult", rns), latest, [timeout], outputs)
        await rm.add_method(self.served.nodes["ResultManagement/GetResultById"],
                            ua.QualifiedName("GetResultById", rns), by_id, [result_id, timeout], outputs)


_UNSET = object()


def _refused(message: str, *, bad: bool = True) -> ua.CallMethodResult:
    code = ua.StatusCodes.BadUserAccessDenied if bad else ua.StatusCodes.BadInvalidState
    result = ua.CallMethodResult(StatusCode=ua.StatusCode(code))
    result.OutputArguments = [ua.Variant(message, ua.VariantType.String)]
    return result


def item_state(mode: str, running: bool, link_ok: bool) -> str:
    """MachineryItemState (OPC 40001-1) of the control core's mode."""
    if mode in ("fault", "e-stopped") or not link_ok:
        return "OutOfService"
    if mode == "not homed":
        return "NotAvailable"
    if running or mode in ("homing", "moving", "jogging", "probing"):
        return "Executing"
    return "NotExecuting"


def operation_mode(mode: str, program: bool) -> str:
    """MachineryOperationMode: a program runs -> Processing; homing, jogging or not homed -> Setup; else None."""
    if program:
        return "Processing"
    if mode in ("homing", "jogging", "not homed"):
        return "Setup"
    return "None"


def default_client(user: str | None, role: str | None) -> Any:
    """The API client of an OPC UA session: an anonymous one observes; a user's came through the listener the
    operator opened (``--opcua``) with a name and password, which stands in for the access code."""
    from ..api import Client

    if user is None:
        return Client("opcua (anonymous)")
    return Client(f"opcua {user}", authenticated=True, listener_grants_control=True, user=user, role=role)


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("cmm")
    except Exception:  # noqa: BLE001
        return "0"


def _install_sessions(server: Server, owner: OpcUaServer) -> None:
    """Sessions whose method calls know their user (CURRENT_USER) and whose report header writes go through the
    command API as their client."""
    iserver = server.iserver

    class Session(InternalSession):
        async def call(self, params: Any) -> Any:
            token = CURRENT_USER.set(self.user)
            try:
                return await super().call(params)
            finally:
                CURRENT_USER.reset(token)

        async def write(self, params: ua.WriteParameters) -> list[ua.StatusCode]:
            report = {node.nodeid: key for key, node in owner.served.report.items()}
            results: list[ua.StatusCode] = []
            for item in params.NodesToWrite:
                key = report.get(item.NodeId)
                if key is None or item.AttributeId != ua.AttributeIds.Value:
                    if self.user is None or getattr(self.user, "role", None) != UserRole.Admin:
                        # everything but the report header is the station's to write
                        results.append(ua.StatusCode(ua.StatusCodes.BadUserAccessDenied
                                                     if key is not None else ua.StatusCodes.BadNotWritable))
                        continue
                    results += await super().write(ua.WriteParameters(NodesToWrite=[item]))
                    continue
                value = item.Value.Value.Value if item.Value and item.Value.Value else ""
                ok, why = await owner.write_report(self.user, key, value)
                if not ok:
                    log.info("OPC UA write of %s refused: %s", key, why)
                    results.append(ua.StatusCode(ua.StatusCodes.BadUserAccessDenied))
                    continue
                owner._last.pop(f"report/{key}", None)
                results += await iserver.attribute_service.write(ua.WriteParameters(NodesToWrite=[item]),
                                                                 user=User(role=UserRole.Admin))
            return results

    def create_session(name: str, user: User = User(role=UserRole.Anonymous), external: bool = False) -> Any:
        return Session(iserver, iserver.aspace, iserver.subscription_service, name, user=user, external=external)

    iserver.create_session = create_session
