"""The part of the OPC 40210 (Geometrical Measuring Systems) companion model the station serves, built in code.

The namespace URIs, browse names and NodeIds below are those of the official nodesets (DI, Machinery,
MachineTool, Machinery Result, GMS; the OPC Foundation's UA-Nodeset files). Only the types this station uses are
built, as ObjectTypes / VariableTypes / DataTypes with their supertypes and, for the state machines, their states
(so a state's ``Id`` points at a real node); their other instance declarations are not served. The one GMS
instance is ``Objects/Machines/<station>`` in the station's own namespace; every node under it carries the
official browse name of the instance declaration it stands for (or a name of the station's namespace where the
companion model has none: the position, the progress, the report header, the methods). ``tests/test_opcua.py``
compares every served type node and instance browse name with the official nodesets.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from asyncua import Server, ua
from asyncua.common.structures104 import create_encoding

UA = "http://opcfoundation.org/UA/"
DI = "http://opcfoundation.org/UA/DI/"
MACHINERY = "http://opcfoundation.org/UA/Machinery/"
MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/"
RESULT = "http://opcfoundation.org/UA/Machinery/Result/"
GMS = "http://opcfoundation.org/UA/GMS/"
COMPANION = (DI, MACHINERY, MACHINE_TOOL, RESULT, GMS)  # registered in this order after the station's own
STATION = "urn:cmm-station:opcua"  # the station's own namespace: the instance and its vendor-specific nodes

# ObjectTypes: (namespace, id, browse name, supertype (namespace, id))
OBJECT_TYPES = (
    (DI, 1005, "FunctionalGroupType", (UA, ua.ObjectIds.FolderType)),
    (MACHINERY, 1004, "MachineryItemIdentificationType", (DI, 1005)),
    (MACHINERY, 1012, "MachineIdentificationType", (MACHINERY, 1004)),
    (MACHINERY, 1002, "MachineryItemState_StateMachineType", (UA, ua.ObjectIds.FiniteStateMachineType)),
    (MACHINERY, 1008, "MachineryOperationModeStateMachineType", (UA, ua.ObjectIds.FiniteStateMachineType)),
    (MACHINE_TOOL, 1003, "MachineOperationModeStateMachineType", (MACHINERY, 1008)),
    (MACHINE_TOOL, 13, "MachineToolType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 11, "MachineToolIdentificationType", (MACHINERY, 1012)),
    (MACHINE_TOOL, 14, "MonitoringType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 26, "MachineOperationMonitoringType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 23, "ElementMonitoringType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 12, "EquipmentType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 44, "ToolListType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 49, "BaseToolType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 50, "ToolType", (MACHINE_TOOL, 49)),
    (MACHINE_TOOL, 21, "ProductionType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 59, "ProductionProgramType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 32, "ProductionActiveProgramType", (MACHINE_TOOL, 59)),
    (MACHINE_TOOL, 24, "ProductionStateMachineType", (UA, ua.ObjectIds.FiniteStateMachineType)),
    (MACHINE_TOOL, 15, "ProductionProgramStateMachineType", (MACHINE_TOOL, 24)),
    (MACHINE_TOOL, 28, "ProductionJobStateMachineType", (MACHINE_TOOL, 24)),
    (MACHINE_TOOL, 29, "ProductionJobType", (UA, ua.ObjectIds.BaseObjectType)),
    (MACHINE_TOOL, 30, "ProductionJobListType", (UA, ua.ObjectIds.OrderedListType)),
    (RESULT, 1004, "ResultManagementType", (UA, ua.ObjectIds.BaseObjectType)),
    (GMS, 1002, "GMSType", (MACHINE_TOOL, 13)),
    (GMS, 1011, "GMSIdentificationType", (MACHINE_TOOL, 11)),
    (GMS, 1004, "GMSMonitoringType", (MACHINE_TOOL, 14)),
    (GMS, 1003, "GMSEquipmentType", (MACHINE_TOOL, 12)),
    (GMS, 1007, "SensorType", (MACHINE_TOOL, 50)),
    (GMS, 1008, "GMSResultManagementType", (RESULT, 1004)),
    (GMS, 1016, "GMSJobType", (MACHINE_TOOL, 29)),
)
VARIABLE_TYPES = (  # (namespace, id, browse name, supertype, data type)
    (RESULT, 2001, "ResultType", (UA, ua.ObjectIds.BaseDataVariableType), (RESULT, 3008)),
    (GMS, 2004, "GMSResultType", (RESULT, 2001), (RESULT, 3008)),
)
# the states of the state machine types: (type, state id, browse name, state number, initial?)
STATES = (
    ((MACHINERY, 1002), 5004, "OutOfService", 1, False), ((MACHINERY, 1002), 5005, "NotAvailable", 0, False),
    ((MACHINERY, 1002), 5006, "Executing", 3, False), ((MACHINERY, 1002), 5007, "NotExecuting", 2, False),
    ((MACHINERY, 1008), 5024, "None", 0, False), ((MACHINERY, 1008), 5025, "Maintenance", 1, False),
    ((MACHINERY, 1008), 5026, "Processing", 3, False), ((MACHINERY, 1008), 5027, "Setup", 2, False),
    ((MACHINE_TOOL, 15), 5039, "Initializing", 0, True), ((MACHINE_TOOL, 15), 5041, "Running", 1, False),
    ((MACHINE_TOOL, 15), 5038, "Ended", 2, False), ((MACHINE_TOOL, 15), 5040, "Interrupted", 3, False),
    ((MACHINE_TOOL, 15), 5037, "Aborted", 4, False),
    ((MACHINE_TOOL, 28), 5015, "Initializing", 0, True), ((MACHINE_TOOL, 28), 5017, "Running", 1, False),
    ((MACHINE_TOOL, 28), 5014, "Ended", 2, False), ((MACHINE_TOOL, 28), 5016, "Interrupted", 3, False),
    ((MACHINE_TOOL, 28), 5013, "Aborted", 4, False),
)
STATE_IDS = {(t, name): sid for t, sid, name, _, _ in STATES}

# enumerations: (namespace, id, browse name, values)
ENUMS = (
    (MACHINE_TOOL, 65, "MachineOperationMode", ("Manual", "Automatic", "Setup", "AutoWithManualIntervention",
                                                 "Service")),
    (RESULT, 3002, "ResultEvaluationEnum", ("Undefined", "OK", "NotOK", "NotDecidable")),
    (GMS, 3002, "ToolIsQualifiedStatus", ("Qualified", "Imprecise", "NotQualified")),
)
SENSOR_CLASSES = ("Other", "NoTool", "UnDefTool", "TactileTouchTrigger", "TactileMeasuring", "Optical-1D",
                  "Optical-2D", "Optical-3D", "Roughness", "Eddy Current Sensor", "TemperatureProbing", "PtMeas")
TRIMMED = ua.NodeId(31918)  # TrimmedString
# structures of Machinery Result: (namespace, id, browse name, Default Binary id, fields (name, type, array,
# optional)); a type given as a (namespace, id) pair is one of these
STRUCTS = (
    (RESULT, 3006, "ProcessingTimesDataType", 5003, (
        ("StartTime", ua.NodeId(ua.ObjectIds.UtcTime), False, False),
        ("EndTime", ua.NodeId(ua.ObjectIds.UtcTime), False, False),
        ("AcquisitionDuration", ua.NodeId(ua.ObjectIds.Duration), False, True),
        ("ProcessingDuration", ua.NodeId(ua.ObjectIds.Duration), False, True))),
    (RESULT, 3007, "ResultMetaDataType", 5005, (
        ("ResultId", TRIMMED, False, False),
        ("HasTransferableDataOnFile", ua.NodeId(ua.ObjectIds.Boolean), False, True),
        ("IsPartial", ua.NodeId(ua.ObjectIds.Boolean), False, True),
        ("IsSimulated", ua.NodeId(ua.ObjectIds.Boolean), False, True),
        ("ResultState", ua.NodeId(ua.ObjectIds.Int32), False, True),
        ("StepId", TRIMMED, False, True), ("PartId", TRIMMED, False, True),
        ("ExternalRecipeId", TRIMMED, False, True), ("InternalRecipeId", TRIMMED, False, True),
        ("ProductId", TRIMMED, False, True), ("ExternalConfigurationId", TRIMMED, False, True),
        ("InternalConfigurationId", TRIMMED, False, True), ("JobId", TRIMMED, False, True),
        ("CreationTime", ua.NodeId(ua.ObjectIds.UtcTime), False, True),
        ("ProcessingTimes", (RESULT, 3006), False, True),
        ("ResultUri", ua.NodeId(ua.ObjectIds.UriString), True, True),
        ("ResultEvaluation", (RESULT, 3002), False, True),
        ("ResultEvaluationCode", ua.NodeId(ua.ObjectIds.Int64), False, True),
        ("ResultEvaluationDetails", ua.NodeId(ua.ObjectIds.LocalizedText), False, True),
        ("FileFormat", ua.NodeId(ua.ObjectIds.String), True, True))),
    (RESULT, 3008, "ResultDataType", 5008, (
        ("ResultMetaData", (RESULT, 3007), False, False),
        ("ResultContent", ua.NodeId(ua.ObjectIds.BaseDataType), True, False))),
)
MACHINES = (MACHINERY, 1001)  # Objects/Machines (a FolderType object)

# The instance under Objects/Machines: (path, browse name (namespace, name), node class, type definition, data
# type) in build order; a path names the node's parent by the path before its last "/". "Object" nodes take an
# ObjectType, "Variable" / "Property" nodes a data type (the variable type is BaseDataVariableType / PropertyType
# unless given as a third element), "Method" nodes are the station's methods.
V = ua.ObjectIds
INSTANCE: tuple[tuple[str, tuple[str, str], str, Any], ...] = (
    ("Identification", (DI, "Identification"), "Object", (GMS, 1011)),
    ("Identification/Manufacturer", (DI, "Manufacturer"), "Property", V.LocalizedText),
    ("Identification/Model", (DI, "Model"), "Property", V.LocalizedText),
    ("Identification/SerialNumber", (DI, "SerialNumber"), "Property", V.String),
    ("Identification/ProductInstanceUri", (DI, "ProductInstanceUri"), "Property", V.String),
    ("Identification/SoftwareRevision", (DI, "SoftwareRevision"), "Property", V.String),
    ("Identification/DeviceClass", (DI, "DeviceClass"), "Property", V.String),
    ("Identification/Location", (MACHINERY, "Location"), "Property", V.String),
    ("Monitoring", (MACHINE_TOOL, "Monitoring"), "Object", (GMS, 1004)),
    ("Monitoring/MachineTool", (MACHINE_TOOL, "MachineTool"), "Object", (MACHINE_TOOL, 26)),
    ("Monitoring/MachineTool/OperationMode", (MACHINE_TOOL, "OperationMode"), "Variable", (MACHINE_TOOL, 65)),
    ("Monitoring/MachineTool/MachineryItemState", (MACHINERY, "MachineryItemState"), "Object", (MACHINERY, 1002)),
    ("Monitoring/MachineTool/MachineryItemState/CurrentState", (UA, "CurrentState"), "State", None),
    ("Monitoring/MachineTool/MachineryOperationMode", (MACHINERY, "MachineryOperationMode"), "Object",
     (MACHINE_TOOL, 1003)),
    ("Monitoring/MachineTool/MachineryOperationMode/CurrentState", (UA, "CurrentState"), "State", None),
    ("Monitoring/Axes", (STATION, "Axes"), "Object", (MACHINE_TOOL, 23)),
    ("Monitoring/Axes/Name", (MACHINE_TOOL, "Name"), "Property", V.String),
    ("Monitoring/Axes/Position", (STATION, "Position"), "Position", None),
    ("Monitoring/Axes/Homed", (STATION, "Homed"), "Variable", V.Boolean),
    ("Monitoring/Axes/Mode", (STATION, "Mode"), "Variable", V.String),
    ("Monitoring/Axes/Reason", (STATION, "Reason"), "Variable", V.String),
    ("Equipment", (MACHINE_TOOL, "Equipment"), "Object", (GMS, 1003)),
    ("Equipment/Tools", (MACHINE_TOOL, "Tools"), "Object", (MACHINE_TOOL, 44)),
    ("Equipment/Tools/Probe", (STATION, "Probe"), "Object", (GMS, 1007)),
    ("Equipment/Tools/Probe/Name", (MACHINE_TOOL, "Name"), "Property", V.String),
    ("Equipment/Tools/Probe/Identifier", (MACHINE_TOOL, "Identifier"), "Property", V.String),
    ("Equipment/Tools/Probe/Class", (GMS, "Class"), "Class", None),
    ("Equipment/Tools/Probe/IsQualifiedStatus", (GMS, "IsQualifiedStatus"), "Property", (GMS, 3002)),
    ("Equipment/Tools/Probe/Locked", (MACHINE_TOOL, "Locked"), "Variable", V.Boolean),
    ("Equipment/Tools/Probe/TipDiameter", (STATION, "TipDiameter"), "Variable", V.Double),
    ("Production", (MACHINE_TOOL, "Production"), "Object", (MACHINE_TOOL, 21)),
    ("Production/ActiveProgram", (MACHINE_TOOL, "ActiveProgram"), "Object", (MACHINE_TOOL, 32)),
    ("Production/ActiveProgram/Name", (MACHINE_TOOL, "Name"), "Property", V.String),
    ("Production/ActiveProgram/NumberInList", (UA, "NumberInList"), "Property", V.UInt16),
    ("Production/ActiveProgram/JobIdentifier", (MACHINE_TOOL, "JobIdentifier"), "Variable", V.String),
    ("Production/ActiveProgram/State", (MACHINE_TOOL, "State"), "Object", (MACHINE_TOOL, 15)),
    ("Production/ActiveProgram/State/CurrentState", (UA, "CurrentState"), "State", None),
    ("Production/ActiveProgram/Progress", (STATION, "Progress"), "Variable", V.Double),
    ("Production/ActiveProgram/Step", (STATION, "Step"), "Variable", V.String),
    # the production plan: the current (or last) job, one program run: GMSJobType with its program
    ("Production/ProductionPlan", (MACHINE_TOOL, "ProductionPlan"), "Object", (MACHINE_TOOL, 30)),
    ("Production/ProductionPlan/Job", (STATION, "Job"), "Object", (GMS, 1016)),
    ("Production/ProductionPlan/Job/Identifier", (MACHINE_TOOL, "Identifier"), "Property", V.String),
    ("Production/ProductionPlan/Job/NumberInList", (UA, "NumberInList"), "Property", V.UInt16),
    ("Production/ProductionPlan/Job/RunsPlanned", (MACHINE_TOOL, "RunsPlanned"), "Variable", V.UInt32),
    ("Production/ProductionPlan/Job/RunsCompleted", (MACHINE_TOOL, "RunsCompleted"), "Variable", V.UInt32),
    ("Production/ProductionPlan/Job/State", (MACHINE_TOOL, "State"), "Object", (MACHINE_TOOL, 28)),
    ("Production/ProductionPlan/Job/State/CurrentState", (UA, "CurrentState"), "State", None),
    ("Production/ProductionPlan/Job/Duration", (GMS, "Duration"), "Property", V.Duration),
    ("Production/ProductionPlan/Job/ProductionPrograms", (MACHINE_TOOL, "ProductionPrograms"), "Object",
     (UA, V.OrderedListType)),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program", (STATION, "Program"), "Object", (MACHINE_TOOL, 59)),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program/Name", (MACHINE_TOOL, "Name"), "Property", V.String),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program/NumberInList", (UA, "NumberInList"), "Property",
     V.UInt16),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program/State", (MACHINE_TOOL, "State"), "Object",
     (MACHINE_TOOL, 15)),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program/State/CurrentState", (UA, "CurrentState"), "State",
     None),
    ("Production/ProductionPlan/Job/ProductionPrograms/Program/Progress", (STATION, "Progress"), "Variable",
     V.Double),
    ("Production/ReportHeader", (STATION, "ReportHeader"), "Object", (UA, V.FolderType)),
    ("Production/StartProgram", (STATION, "StartProgram"), "Method", None),
    ("Production/Stop", (STATION, "Stop"), "Method", None),
    ("ResultManagement", (GMS, "ResultManagement"), "Object", (GMS, 1008)),
    ("ResultManagement/Results", (RESULT, "Results"), "Object", (UA, V.FolderType)),
    ("ResultManagement/GetLatestResult", (RESULT, "GetLatestResult"), "Method", None),
    ("ResultManagement/GetResultById", (RESULT, "GetResultById"), "Method", None),
)
REPORT_FIELDS = ("part_number", "drawing", "operator", "machine_name", "temperature", "remarks")


@dataclass
class Served:
    """The built address space: namespace indexes and the instance's nodes by path."""

    ns: dict[str, int]
    nodes: dict[str, Any] = field(default_factory=dict)
    report: dict[str, Any] = field(default_factory=dict)  # report header field -> its variable node
    results: Any = None  # the Results folder
    state_ids: dict[tuple[str, str], ua.NodeId] = field(default_factory=dict)  # (machine, state name) -> state node

    def nid(self, ref: tuple[str, int]) -> ua.NodeId:
        uri, i = ref
        return ua.NodeId(i, self.ns[uri])


async def build(server: Server, name: str = "CMM") -> Served:
    """Build the types and the GMS instance ``Objects/Machines/<name>`` in ``server``'s address space."""
    ns = {UA: 0}
    ns[STATION] = await server.register_namespace(STATION)
    for uri in COMPANION:
        ns[uri] = await server.register_namespace(uri)
    s = Served(ns)
    for uri, i, type_name, parent_ref in ENUMS:
        await _enum(server, s, (uri, i), type_name, parent_ref)
    for uri, i, type_name, enc, fields in STRUCTS:
        await _struct(server, s, (uri, i), type_name, enc, fields)
    await server.load_data_type_definitions()
    for uri, i, type_name, parent_ref in OBJECT_TYPES:
        parent = server.get_node(s.nid(parent_ref))
        await parent.add_object_type(s.nid((uri, i)), ua.QualifiedName(type_name, ns[uri]))
    for uri, i, type_name, parent_ref, dtype in VARIABLE_TYPES:
        parent = server.get_node(s.nid(parent_ref))
        await parent.add_variable_type(s.nid((uri, i)), ua.QualifiedName(type_name, ns[uri]), s.nid(dtype))
    for type_ref, sid, state, number, initial in STATES:
        tnode = server.get_node(s.nid(type_ref))
        kind = ua.ObjectIds.InitialStateType if initial else ua.ObjectIds.StateType
        # not instantiated: asyncua would number the StateNumber property in the companion namespace (a clash)
        node = await tnode.add_object(s.nid((type_ref[0], sid)), ua.QualifiedName(state, ns[type_ref[0]]))
        await _retype(node, ua.NodeId(kind), ua.NodeId(ua.ObjectIds.BaseObjectType))
        await node.add_property(ua.NodeId(f"{type_name_of(type_ref)}/{state}/StateNumber", ns[STATION]),
                                ua.QualifiedName("StateNumber", 0), ua.Variant(number, ua.VariantType.UInt32))
        s.state_ids[(type_ref, state)] = node.nodeid
    machines = await server.nodes.objects.add_folder(s.nid(MACHINES), ua.QualifiedName("Machines", ns[MACHINERY]))
    root = await machines.add_object(ua.NodeId(name, ns[STATION]), ua.QualifiedName(name, ns[STATION]),
                                     s.nid((GMS, 1002)), instantiate_optional=False)
    s.nodes[""] = root
    for path, (uri, bname), kind, detail in INSTANCE:
        parent = s.nodes[path.rsplit("/", 1)[0] if "/" in path else ""]
        s.nodes[path] = await _add(server, s, parent, ua.NodeId(f"{name}/{path}", ns[STATION]),
                                   ua.QualifiedName(bname, ns[uri]), kind, detail)
    header = s.nodes["Production/ReportHeader"]
    for f in REPORT_FIELDS:
        node = await header.add_variable(ua.NodeId(f"{name}/Production/ReportHeader/{f}", ns[STATION]),
                                         ua.QualifiedName(f, ns[STATION]), "", ua.VariantType.String)
        await node.set_writable(True)
        s.report[f] = node
    s.results = s.nodes["ResultManagement/Results"]
    return s


async def _add(server: Server, s: Served, parent: Any, nid: ua.NodeId, qn: ua.QualifiedName, kind: str,
               detail: Any) -> Any:
    if kind == "Object":
        return await parent.add_object(nid, qn, s.nid(detail) if isinstance(detail, tuple) else detail,
                                       instantiate_optional=False)
    if kind in ("Property", "Variable"):
        dtype = s.nid(detail) if isinstance(detail, tuple) else ua.NodeId(detail)
        vtype = _variant_type(detail)
        value = ua.Variant(_default(vtype), vtype)
        if kind == "Property":
            return await parent.add_property(nid, qn, value, datatype=dtype)
        return await parent.add_variable(nid, qn, value, datatype=dtype)
    if kind == "State":  # FiniteStateVariableType with its Id property
        try:  # instantiated with its state machine (FiniteStateMachineType's mandatory CurrentState)
            node = await parent.get_child(qn)
            await node.get_child(ua.QualifiedName("Id", 0))
            return node
        except ua.UaStatusCodeError:
            pass
        node = await parent.add_variable(nid, qn, ua.LocalizedText(""), ua.VariantType.LocalizedText,
                                         datatype=ua.NodeId(ua.ObjectIds.LocalizedText))
        await _retype(node, ua.NodeId(ua.ObjectIds.FiniteStateVariableType))
        await node.add_property(ua.NodeId(f"{nid.Identifier}/Id", nid.NamespaceIndex), ua.QualifiedName("Id", 0),
                                ua.Variant(ua.NodeId(), ua.VariantType.NodeId))
        return node
    if kind == "Position":  # 3DCartesianCoordinatesType: X, Y, Z in mm
        node = await parent.add_variable(nid, qn, ua.ThreeDCartesianCoordinates(),
                                         datatype=ua.NodeId(ua.ObjectIds.ThreeDCartesianCoordinates))
        await _retype(node, ua.NodeId(ua.ObjectIds.ThreeDCartesianCoordinatesType))
        for axis in "XYZ":
            await node.add_variable(ua.NodeId(f"{nid.Identifier}/{axis}", nid.NamespaceIndex),
                                    ua.QualifiedName(axis, 0), 0.0, ua.VariantType.Double)
        await node.add_property(ua.NodeId(f"{nid.Identifier}/LengthUnit", nid.NamespaceIndex),
                                ua.QualifiedName("LengthUnit", 0), ua.Variant(_mm(), ua.VariantType.ExtensionObject),
                                datatype=ua.NodeId(ua.ObjectIds.EUInformation))
        return node
    if kind == "Class":  # MultiStateDiscreteType with the companion model's EnumStrings
        node = await parent.add_variable(nid, qn, ua.Variant(3, ua.VariantType.UInt32),
                                         datatype=ua.NodeId(ua.ObjectIds.UInteger))
        await _retype(node, ua.NodeId(ua.ObjectIds.MultiStateDiscreteType))
        await node.add_property(ua.NodeId(f"{nid.Identifier}/EnumStrings", nid.NamespaceIndex),
                                ua.QualifiedName("EnumStrings", 0),
                                ua.Variant([ua.LocalizedText(t) for t in SENSOR_CLASSES], ua.VariantType.LocalizedText))
        return node
    if kind == "Method":
        return nid  # added by the server with its callable
    raise ValueError(kind)


def type_name_of(ref: tuple[str, int]) -> str:
    return next(n for u, i, n, _ in OBJECT_TYPES if (u, i) == ref)


async def _retype(node: Any, type_id: ua.NodeId,
                  old: ua.NodeId = ua.NodeId(ua.ObjectIds.BaseDataVariableType)) -> None:
    """Give a node another type definition than the one asyncua gave it (BaseDataVariableType)."""
    await node.delete_reference(old, ua.ObjectIds.HasTypeDefinition)
    await node.add_reference(type_id, ua.ObjectIds.HasTypeDefinition)


def _mm() -> ua.EUInformation:
    """UNECE code MMT (millimetre) as OPC UA 10000-8 encodes it."""
    code = "MMT"
    unit_id = (ord(code[0]) << 16) | (ord(code[1]) << 8) | ord(code[2])
    return ua.EUInformation(NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact", UnitId=unit_id,
                            DisplayName=ua.LocalizedText("mm"), Description=ua.LocalizedText("millimetre"))


def _variant_type(detail: Any) -> ua.VariantType:
    if isinstance(detail, tuple):  # an enumeration of the companion model
        return ua.VariantType.Int32
    return {V.String: ua.VariantType.String, V.LocalizedText: ua.VariantType.LocalizedText,
            V.Boolean: ua.VariantType.Boolean, V.Double: ua.VariantType.Double,
            V.UInt16: ua.VariantType.UInt16, V.UInt32: ua.VariantType.UInt32,
            V.Duration: ua.VariantType.Double}[detail]


def _default(vtype: ua.VariantType) -> Any:
    return {ua.VariantType.String: "", ua.VariantType.LocalizedText: ua.LocalizedText(""),
            ua.VariantType.Boolean: False, ua.VariantType.Double: 0.0, ua.VariantType.UInt16: 0,
            ua.VariantType.UInt32: 0,
            ua.VariantType.Int32: 0}[vtype]


async def _enum(server: Server, s: Served, ref: tuple[str, int], type_name: str, values: tuple[str, ...]) -> None:
    edef = ua.EnumDefinition()
    for k, v in enumerate(values):
        edef.Fields.append(ua.EnumField(Value=k, DisplayName=ua.LocalizedText(v), Description=ua.LocalizedText(v),
                                        Name=v))
    node = await server.nodes.enum_data_type.add_data_type(s.nid(ref), ua.QualifiedName(type_name, s.ns[ref[0]]))
    await node.write_data_type_definition(edef)
    await node.add_property(ua.NodeId(f"{type_name}/EnumStrings", s.ns[STATION]), ua.QualifiedName("EnumStrings", 0),
                            ua.Variant([ua.LocalizedText(v) for v in values], ua.VariantType.LocalizedText))


async def _struct(server: Server, s: Served, ref: tuple[str, int], type_name: str, encoding: int,
                  fields: tuple) -> None:
    node = await server.nodes.base_structure_type.add_data_type(s.nid(ref), ua.QualifiedName(type_name, s.ns[ref[0]]))
    enc = await create_encoding(node, s.nid((ref[0], encoding)), ua.QualifiedName("Default Binary", 0))
    sdef = ua.StructureDefinition(BaseDataType=server.nodes.base_structure_type.nodeid,
                                  StructureType=ua.StructureType.Structure, DefaultEncodingId=enc.nodeid)
    for fname, ftype, array, optional in fields:
        sdef.Fields.append(ua.StructureField(
            Name=fname, DataType=s.nid(ftype) if isinstance(ftype, tuple) else ftype, ValueRank=1 if array else -1,
            ArrayDimensions=[0] if array else [], IsOptional=optional))
        if optional:
            sdef.StructureType = ua.StructureType.StructureWithOptionalFields
    await node.write_data_type_definition(sdef)
