"""The OPC UA server (OPC 40210 GMS) on the simulated station, through asyncua's own client: the served model
against the official nodesets (read in place from ../shared/opcua), the position as the machine moves, who may
write and call methods."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

pytest.importorskip("asyncua")
from asyncua import Client, ua  # noqa: E402
from asyncua.ua.uaerrors import UaStatusCodeError  # noqa: E402

import opcua_support as ops  # noqa: E402
from cmm.control.access import Control  # noqa: E402
from cmm.control import tls  # noqa: E402
from cmm.control.roles import RolePolicy  # noqa: E402
from cmm.control.users import UserStore  # noqa: E402
from cmm.opcua import model  # noqa: E402
from cmm.opcua.server import OpcUaServer  # noqa: E402
from netutil import free_port  # noqa: E402

USERS = {"maria": ("s3cret-maria", "operator")}
SHARED = ops.shared_dir()


@pytest.fixture(scope="module")
def served(module_stations, tmp_path_factory):
    station = module_stations.nist(start=False)  # started below, once its policy and roles are set
    station.controller.use_policy_of(Control())  # the holder rule of `cmm serve`: observers do not command
    store = UserStore(tmp_path_factory.mktemp("users") / "users.toml")  # `cmm serve --users FILE`
    for name, (password, role) in USERS.items():
        store.add(name, role, password)
    station.controller.commands.roles = RolePolicy()
    station.start()
    cert = tls.certificate(tmp_path_factory.mktemp("tls"), application_uri="urn:cmm-station:CMM-7")  # self-signed
    server = OpcUaServer(station.controller.commands, "127.0.0.1", free_port(), name="CMM-7",
                         authenticate=store.identify, rate=20.0, certificate=cert).start()
    server.store = store
    try:
        yield server, station
    finally:
        server.close()
        station.close()


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 120))


async def wait_for(predicate, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not await predicate():
        assert time.monotonic() < end, "condition not reached"
        await asyncio.sleep(0.05)


async def gms_node(client: Client):
    ns = await client.get_namespace_array()
    machines = await client.nodes.objects.get_child([f"{ns.index(model.MACHINERY)}:Machines"])
    (gms,) = await machines.get_children()
    return gms, ns


async def browse_all(client: Client, start, refs=ua.ObjectIds.HierarchicalReferences, depth: int = 99):
    """Every node under ``start`` by forward ``refs`` (with subtypes): nodeid -> (class, browse name, type
    definition, parent nodeid)."""
    seen = {start.nodeid: None}
    out = {}
    todo = [start.nodeid]
    while todo and depth > 0:
        depth -= 1
        results = []
        for k in range(0, len(todo), 100):
            params = ua.BrowseParameters()
            params.NodesToBrowse = [ua.BrowseDescription(NodeId=n, BrowseDirection=ua.BrowseDirection.Forward,
                                                         ReferenceTypeId=ua.NodeId(refs), IncludeSubtypes=True,
                                                         NodeClassMask=0, ResultMask=63) for n in todo[k:k + 100]]
            results += await client.uaclient.browse(params)
        nxt = []
        for parent, result in zip(todo, results):
            for r in result.References:
                nid = r.NodeId
                if nid in seen:
                    continue
                seen[nid] = parent
                out[nid] = (r.NodeClass.name, r.BrowseName, r.TypeDefinition, parent)
                nxt.append(nid)
        todo = nxt
    return out


def official_key(ns: list[str], nid: ua.NodeId) -> tuple[str, str]:
    return ns[nid.NamespaceIndex], f"i={nid.Identifier}"


@pytest.mark.skipif(SHARED is None, reason="the official nodesets (../shared/opcua) are not beside the checkout")
def test_every_served_type_browse_name_and_node_id_is_the_official_one(served):
    server, station = served
    official = ops.load_official(SHARED)

    async def check():
        async with Client(server.url, timeout=60) as client:
            ns = await client.get_namespace_array()
            companion = {ns.index(u) for u in model.COMPANION}
            station_ns = ns.index(model.STATION)
            # the types: every node of a companion namespace among the subtypes of the base types, with the
            # nodes the companion types hold (the states of a state machine type, a data type's encoding)
            types = {}
            for root in (ua.ObjectIds.BaseObjectType, ua.ObjectIds.BaseVariableType, ua.ObjectIds.BaseDataType):
                types.update(await browse_all(client, client.get_node(root), refs=ua.ObjectIds.HasSubtype))
            encodings = {}
            for nid, (cls, _, _, _) in list(types.items()):
                if nid.NamespaceIndex in companion:
                    encodings.update(await browse_all(client, client.get_node(nid), refs=ua.ObjectIds.HasEncoding
                                                      if cls == "DataType" else ua.ObjectIds.HasComponent, depth=1))
            served_types = {k: v for k, v in {**types, **encodings}.items() if k.NamespaceIndex in companion}
            assert len(served_types) >= 40
            for nid, (cls, bname, _, parent) in served_types.items():
                key = official_key(ns, nid)
                assert key in official, f"{key} is not in the official nodesets"
                want = official[key]
                assert want.node_class == cls, key
                assert (ns[bname.NamespaceIndex], bname.Name) == want.browse_name, key
                if cls in ("ObjectType", "VariableType", "DataType"):  # its supertype as officially
                    sup = want.target(ops.HAS_SUBTYPE, forward=False)
                    assert official_key(ns, parent) == sup, f"{key}: supertype {parent} is not {sup}"
                elif cls == "Object" and parent.NamespaceIndex in companion:  # a state of a state machine type
                    assert official_key(ns, parent) in {t for r, f, t in want.refs if not f}, key
            # the instance: Objects/Machines is the official folder; every node under the GMS instance is an
            # official instance declaration of its parent's type (browse name and type definition), or one of the
            # station's own nodes
            gms, _ = await gms_node(client)
            assert official_key(ns, (await gms.read_type_definition())) == (model.GMS, "i=1002")
            machines = await client.nodes.objects.get_child([f"{ns.index(model.MACHINERY)}:Machines"])
            assert official_key(ns, machines.nodeid) == (model.MACHINERY, "i=1001")
            nodes = await browse_all(client, gms)
            typedef = {gms.nodeid: await gms.read_type_definition(), **{k: v[2] for k, v in nodes.items()}}
            own = set()
            for nid, (cls, bname, tdef, parent) in nodes.items():
                assert nid.NamespaceIndex == station_ns, nid
                uri = ns[bname.NamespaceIndex]
                if uri == model.STATION:
                    own.add(bname.Name)
                    continue
                parent_type = typedef[parent]
                if parent_type.NamespaceIndex == 0:
                    continue  # declared by the OPC UA base model (X, Y, Z, EnumStrings ...): asyncua's own
                decl = ops.declarations(official, official_key(ns, parent_type))
                assert (uri, bname.Name) in decl or uri == ops.UA, \
                    f"{bname.Name} is not declared by {official[official_key(ns, parent_type)].browse_name}"
                want = decl.get((uri, bname.Name))
                if want is not None and tdef.NamespaceIndex in companion:
                    assert ops.is_subtype(official, official_key(ns, tdef), want), (bname.Name, tdef, want)
                elif want is not None:
                    assert (ops.UA, f"i={tdef.Identifier}") == want or want[0] == ops.UA, (bname.Name, tdef)
            assert {"Axes", "Position", "Probe", "Progress", "ReportHeader", "StartProgram", "Stop", "Job",
                    "Program"} <= own
            # the production plan's job is a GMSJobType with its state machine; the result management has the
            # Machinery Result methods, their arguments (names and data types) as the official declarations
            served_names = {(ns[b.NamespaceIndex], b.Name): (nid, tdef) for nid, (_, b, tdef, _) in nodes.items()}
            _, job_type = served_names[(model.STATION, "Job")]
            assert official_key(ns, job_type) == (model.GMS, "i=1016")
            assert (model.MACHINE_TOOL, "ProductionPlan") in served_names
            arguments = ops.method_arguments(SHARED)
            for method in ("GetLatestResult", "GetResultById"):
                nid, _ = served_names[(model.RESULT, method)]
                decl = ops.declaration_id(official, (model.GMS, "i=1008"), (model.RESULT, method))
                assert decl is not None and official[decl].node_class == "Method", method
                node = client.get_node(nid)
                for kind in ("InputArguments", "OutputArguments"):
                    got = [(a.Name, official_key(ns, a.DataType))
                           for a in await (await node.get_child(f"0:{kind}")).read_value()]
                    assert got == arguments[decl][kind], (method, kind)

    run(check())


def test_a_client_browses_the_gms_instance_and_sees_the_position_change_as_the_machine_moves(served):
    server, station = served
    api = station.controller.commands

    async def check():
        async with Client(server.url, timeout=60) as client:
            gms, ns = await gms_node(client)
            mt, st = ns.index(model.MACHINE_TOOL), ns.index(model.STATION)
            ident = await gms.get_child([f"{ns.index(model.DI)}:Identification", f"{ns.index(model.DI)}:SerialNumber"])
            assert await ident.read_value() == "CMM-7"
            state = await gms.get_child([f"{mt}:Monitoring", f"{mt}:MachineTool",
                                         f"{ns.index(model.MACHINERY)}:MachineryItemState", "0:CurrentState"])
            position = await gms.get_child([f"{mt}:Monitoring", f"{st}:Axes", f"{st}:Position", "0:X"])
            probe = await gms.get_child([f"{mt}:Equipment", f"{mt}:Tools", f"{st}:Probe", f"{mt}:Name"])
            await wait_for(lambda: _nonempty(probe))
            seen: list[float] = []

            class Handler:
                def datachange_notification(self, node, value, data):
                    seen.append(float(value))

            sub = await client.create_subscription(50, Handler())
            await sub.subscribe_data_change(position)
            await wait_for(lambda: _true(bool(seen)))
            start = float(api.invoke(None, "position")[0])
            target = [start + 60.0, 0.0, 0.0]
            network = station.sim.network
            pace = network.pace
            network.set_pace(0.5)  # the move spans seconds of wall time whatever the load: the client sees it go
            try:
                status = api.invoke(None, "move", target=target, frame="machine", path="straight")
                await wait_for(lambda: _true(any(abs(v - target[0]) < 1e-3 for v in seen)))
                await asyncio.get_running_loop().run_in_executor(None, status.wait, 60)
            finally:
                network.set_pace(pace)
            between = {round(v, 3) for v in seen if start + 1 < v < target[0] - 1}
            assert len(between) >= 2, f"the position did not change as the machine moved: {sorted(set(seen))}"
            assert abs(seen[-1] - target[0]) < 1e-3
            assert not server.errors
            # a front end on the API: the values came through the API's change streams, not a poll of the station
            assert api._subscriptions.count() >= 2 and server.deliveries >= len(between)
            assert (await state.read_value()).Text in ("NotExecuting", "Executing")
            await sub.delete()

    run(check())


async def _nonempty(node) -> bool:
    return bool(await node.read_value())


async def _true(value: bool) -> bool:
    return value


def test_an_anonymous_client_is_refused_writes_and_methods_and_a_user_may(served):
    server, station = served
    api = station.controller.commands

    async def check():
        async with Client(server.url, timeout=60) as client:  # anonymous
            gms, ns = await gms_node(client)
            mt, st = ns.index(model.MACHINE_TOOL), ns.index(model.STATION)
            part = await gms.get_child([f"{mt}:Production", f"{st}:ReportHeader", f"{st}:part_number"])
            with pytest.raises(UaStatusCodeError) as refused:
                await part.write_value(ua.Variant("P-100", ua.VariantType.String))
            assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
            location = await gms.get_child([f"{ns.index(model.DI)}:Identification", f"{ns.index(model.MACHINERY)}:Location"])
            with pytest.raises(UaStatusCodeError):
                await location.write_value(ua.Variant("hall 3", ua.VariantType.String))
            production = await gms.get_child([f"{mt}:Production"])
            for method, args in ((f"{st}:Stop", ()), (f"{st}:StartProgram", ("program.toml",))):
                with pytest.raises(UaStatusCodeError) as refused:
                    await production.call_method(method, *args)
                assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
        assert not api.invoke(None, "report_info").get("part_number")

        bad = Client(server.url, timeout=60)
        bad.set_user("maria")
        bad.set_password("wrong")
        with pytest.raises(Exception):
            await bad.connect()

        user = Client(server.url, timeout=60)
        user.set_user("maria")
        user.set_password(USERS["maria"][0])
        async with user:
            gms, ns = await gms_node(user)
            mt, st = ns.index(model.MACHINE_TOOL), ns.index(model.STATION)
            part = await gms.get_child([f"{mt}:Production", f"{st}:ReportHeader", f"{st}:part_number"])
            await part.write_value(ua.Variant("P-100", ua.VariantType.String))
            assert await part.read_value() == "P-100"
            production = await gms.get_child([f"{mt}:Production"])
            assert await production.call_method(f"{st}:Stop") == "stopped"
        assert api.invoke(None, "report_info")["part_number"] == "P-100"
        assert station.controller.holder.holder_name == "maria"  # the person, in every control message

        program = Client(server.url, timeout=60)  # a program with an API token: user "token", the token as password
        program.set_user("token")
        program.set_password(server.store.new_token("maria", "mes"))
        async with program:
            gms, ns = await gms_node(program)
            part = await gms.get_child([f"{ns.index(model.MACHINE_TOOL)}:Production",
                                        f"{ns.index(model.STATION)}:ReportHeader", f"{ns.index(model.STATION)}:drawing"])
            await part.write_value(ua.Variant("D-7", ua.VariantType.String))
        assert api.invoke(None, "report_info")["drawing"] == "D-7"

    run(check())


def test_a_program_run_shows_its_progress_and_ends_as_a_result(served, tmp_path):
    server, station = served
    api = station.controller.commands
    # a two-hit program on the top face of the simulated part, as the routine tests write them
    program = _top_face_program(station, tmp_path)

    async def check():
        user = Client(server.url, timeout=60)
        user.set_user("maria")
        user.set_password(USERS["maria"][0])
        async with user:
            gms, ns = await gms_node(user)
            mt, st, res = ns.index(model.MACHINE_TOOL), ns.index(model.STATION), ns.index(model.RESULT)
            gms_ns = ns.index(model.GMS)
            results = await gms.get_child([f"{gms_ns}:ResultManagement", f"{res}:Results"])
            before = len(await results.get_children())
            progress = await gms.get_child([f"{mt}:Production", f"{mt}:ActiveProgram", f"{st}:Progress"])
            job = await gms.get_child([f"{mt}:Production", f"{mt}:ProductionPlan", f"{st}:Job"])
            job_state = await job.get_child([f"{mt}:State", "0:CurrentState"])
            seen, states = [], []

            class Handler:
                def datachange_notification(self, node, value, data):
                    (seen if node == progress else states).append(value)

            sub = await user.create_subscription(50, Handler())
            await sub.subscribe_data_change([progress, job_state])
            production = await gms.get_child([f"{mt}:Production"])
            assert await production.call_method(f"{st}:StartProgram", str(program)) in ("started", "finished")
            await wait_for(lambda: _count(results, before + 1), timeout=120)
            (node,) = [n for n in await results.get_children()][before:]
            assert official_key(ns, await node.read_type_definition()) == (model.GMS, "i=2004")
            value = await node.read_value()
            meta = value.ResultMetaData
            assert meta.InternalRecipeId and meta.ResultEvaluation in (1, 2, 3)
            assert value.ResultContent, "the result lists the run's characteristics"
            assert 100.0 in seen
            # the production plan's job: this run, Running then Ended, its program by name
            assert "Running" in [v.Text for v in states] and (await job_state.read_value()).Text == "Ended"
            assert await (await job.get_child(f"{mt}:Identifier")).read_value() == meta.JobId
            assert await (await job.get_child(f"{mt}:RunsCompleted")).read_value() == 1
            program_name = await job.get_child([f"{mt}:ProductionPrograms", f"{st}:Program", f"{mt}:Name"])
            assert await program_name.read_value() == meta.InternalRecipeId
            await sub.delete()
        async with Client(server.url, timeout=60) as anonymous:  # the result management's methods only read
            gms, ns = await gms_node(anonymous)
            rm = await gms.get_child(f"{ns.index(model.GMS)}:ResultManagement")
            res = ns.index(model.RESULT)
            handle, latest, error = await rm.call_method(f"{res}:GetLatestResult", ua.Variant(0, ua.VariantType.Int32))
            assert (handle, error) == (0, 0) and latest.ResultMetaData.ResultId == meta.ResultId
            assert latest.ResultContent == value.ResultContent
            _, by_id, error = await rm.call_method(f"{res}:GetResultById", ua.Variant(meta.ResultId,
                                                   ua.VariantType.String), ua.Variant(0, ua.VariantType.Int32))
            assert error == 0 and by_id.ResultMetaData.JobId == meta.JobId
            _, _, error = await rm.call_method(f"{res}:GetResultById", ua.Variant("no such result",
                                               ua.VariantType.String), ua.Variant(0, ua.VariantType.Int32))
            assert error == -2
        # the holder's name in every record: the program's hits and its feature were taken by maria
        import json

        events = [json.loads(line) for line in station.measurement.journal.path.read_text().splitlines() if line]
        taken = [e for e in events if e["kind"] in ("hit", "feature")][-4:]
        assert [e["kind"] for e in taken] == ["hit", "hit", "hit", "feature"]
        assert {e.get("by") for e in taken} == {"maria"}
    run(check())


async def _count(folder, n: int) -> bool:
    return len(await folder.get_children()) >= n


def _top_face_program(station, tmp_path):
    """A program of three hits on the part's top face, fitted as a plane, saved as a TOML program file."""
    from cmm.program import toml_program as prog

    part = station.measurement.part
    lo, hi = part.mesh.bounds
    hits = []
    for k, (fx, fy) in enumerate(((0.15, 0.15), (0.3, 0.15), (0.15, 0.3)), 1):
        x, y = lo[0] + fx * (hi[0] - lo[0]), lo[1] + fy * (hi[1] - lo[1])
        found, _, _ = part.mesh.ray.intersects_location([[x, y, hi[2] + 10]], [[0.0, 0.0, -1.0]])
        z = float(max(found[:, 2]))
        hits.append(prog.ProgramHit(k, (x, y, z), (0.0, 0.0, -1.0), float(hi[2]) + 10.0))
    program = prog.Program("top face", part.name, prog.part_hash(part),
                           [prog.ProgramFeature("top", "plane", "ls", [1, 2, 3])], hits)
    return prog.save(program, tmp_path / "top.toml")


def test_a_client_logs_in_over_basic256sha256_and_sees_the_fingerprint_the_station_printed(served, tmp_path):
    server, station = served
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    assert server.certificate.made and len(server.certificate.fingerprint.split(":")) == 32
    cert, key = tmp_path / "client-cert.pem", tmp_path / "client-key.pem"
    tls.make(cert, key, application_uri="urn:cmm-test:client", common_name="test client")

    async def check():
        client = Client(server.url, timeout=60)
        client.application_uri = "urn:cmm-test:client"
        endpoints = await client.connect_and_get_server_endpoints()
        secure = [e for e in endpoints if e.SecurityPolicyUri == SecurityPolicyBasic256Sha256.URI]
        assert secure, "the server offers Basic256Sha256 with its certificate"
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes

        seen = x509.load_der_x509_certificate(secure[0].ServerCertificate).fingerprint(hashes.SHA256())
        assert ":".join(f"{b:02X}" for b in seen) == server.certificate.fingerprint
        await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key),
                                  server_certificate=str(server.certificate.cert_path),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
        client.set_user("maria")
        client.set_password(USERS["maria"][0])
        async with client:
            gms, ns = await gms_node(client)
            serial = await gms.get_child([f"{ns.index(model.DI)}:Identification", f"{ns.index(model.DI)}:SerialNumber"])
            assert await serial.read_value() == "CMM-7"

    run(check())
