"""The I++ DME commands that set a session up rather than move the machine:
the machine's identity and state queries (GetDMEVersion, IsHomed, EnableUser ...),
properties (GetProp, SetProp, EnumProp ...), tools (EnumTools, FindTool,
ChangeTool, AlignTool ...) and coordinate systems (SetCoordSystem,
SetCsyTransformation ...), with the argument checks every command uses.

Each handler takes the connection's :class:`~cmm.ippdme.executor.Dme` and the
parsed command, raises :class:`~cmm.ippdme.errors.IppError` to refuse it and
returns (or yields) the data lines of its answer; ``HANDLERS`` maps the
command names to them for the executor's dispatch.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from . import protocol as P
from .errors import IppError
from .tools import children, resolve


DME_VERSION = "1.4.3"


def props(cmd: P.Command, allowed: set[str] | None = None, nargs: int | None = None) -> list[P.Prop]:
    """The command's property arguments, checked: only properties, each once, from ``allowed``, ``nargs`` values."""
    out = []
    for a in cmd.args:
        if not isinstance(a, P.Prop):
            raise IppError(502, cmd.name, f"expected properties like X(), got {a!r}")
        if allowed is not None and a.name not in allowed:
            raise IppError(510, cmd.name, f"{a.name}() is not one of {', '.join(sorted(allowed))}")
        if nargs is not None and len(a.args) != nargs:
            raise IppError(502, cmd.name, f"{a.name} takes {nargs} value(s)")
        out.append(a)
    if len({a.name for a in out}) != len(out):
        raise IppError(502, cmd.name, "an item appears twice")
    return out

def one(cmd: P.Command, kind: type):
    """The command's single argument, which must be a ``kind``."""
    if len(cmd.args) != 1 or not isinstance(cmd.args[0], kind):
        raise IppError(502, cmd.name, f"{cmd.name} takes one {kind.__name__} argument")
    return cmd.args[0]


# --- machine queries --------------------------------------------------------------------------------


def get_dme_version(dme: Any, cmd: P.Command):
    yield P.prop("DMEVersion", P.quote(DME_VERSION))


def is_homed(dme: Any, cmd: P.Command):
    yield P.prop("IsHomed", int(dme.backend.homed))


def enable_user(dme: Any, cmd: P.Command):
    dme.user_enabled = True


def disable_user(dme: Any, cmd: P.Command):
    dme.user_enabled = False


def is_user_enabled(dme: Any, cmd: P.Command):
    yield P.prop("IsUserEnabled", int(dme.user_enabled))


def get_machine_class(dme: Any, cmd: P.Command):
    yield "GetMachineClass(CartCMM)"


# --- properties -----------------------------------------------------------------------------------


def get_prop(dme: Any, cmd: P.Command):
    items = []
    for p in props(cmd, nargs=0):
        tool, block, param, sub = resolve(dme.tools, p.name, cmd.name)
        if block == "Name":
            items.append(P.prop(p.name, P.quote(tool.name)))
        elif block == "Id":
            items.append(P.prop(p.name, P.quote(tool.id)))
        elif block == "AvrRadius":
            items.append(P.prop(p.name, tool.radius))
        elif block == "Alignment":
            items.append(P.prop(p.name, *dme.csy.vector_from_machine([0.0, 0.0, 1.0])))
        elif block == "CollisionVolume":
            items.append(P.prop(p.name))  # not modelled: no volume (the client keeps its own)
        elif param is None:
            raise IppError(510, cmd.name, f"{p.name} is a property block, not a value")
        else:
            items.append(P.prop(p.name, param.get(sub or "Act")))
    yield ", ".join(items)


def set_prop(dme: Any, cmd: P.Command):
    given = props(cmd, nargs=1)
    targets = []
    for p in given:  # all checked before any is set
        tool, block, param, sub = resolve(dme.tools, p.name, cmd.name)
        if param is None or sub not in (None, "Act"):
            raise IppError(509, cmd.name, f"{p.name} cannot be set (only the Act values can)")
        if not math.isfinite(p.args[0]):
            raise IppError(509, cmd.name, f"{p.name}: not a number")
        targets.append((p, param))
    clamped = [p.name for p, param in targets if not param.set(p.args[0])]
    if clamped:
        raise IppError(504, cmd.name, f"clamped to Min..Max: {', '.join(clamped)}")
    return ()


def _enum(dme: Any, cmd: P.Command, recursive: bool):
    p = one(cmd, P.Prop)
    if p.args:
        raise IppError(502, cmd.name, "EnumProp takes a property pointer like Tool.PtMeasPar()")
    for name, kind in children(dme.tools, p.name, cmd.name, recursive):
        yield f"{P.quote(name)}, {P.quote(kind)}"


def enum_prop(dme: Any, cmd: P.Command):
    return _enum(dme, cmd, False)


def enum_all_prop(dme: Any, cmd: P.Command):
    return _enum(dme, cmd, True)


# --- tools (6.3.2.14 ...) -------------------------------------------------------------------------


def enum_tools(dme: Any, cmd: P.Command):
    for name in dme.tools.names():
        yield P.quote(name)


def find_tool(dme: Any, cmd: P.Command):
    name = one(cmd, P.Text).value
    dme.tools.found = "UnDefTool"
    dme.tools.found = dme.tools.lookup(name, cmd.name).name


def change_tool(dme: Any, cmd: P.Command):
    name = one(cmd, P.Text).value
    dme.user_enabled = False
    tool = dme.tools.lookup(name, cmd.name)
    change = getattr(dme.backend, "change_tool", None)
    if change is not None:  # the station's probe in use follows (its radius and pre-travel compensate)
        try:
            change(tool.name)
        except Exception as exc:  # noqa: BLE001 - refused (no control, busy) or a bad record: said, not changed
            raise IppError(511, cmd.name, f"the station could not use probe {tool.name}: {exc}") from None
    dme.tools.select(name, cmd.name)  # one stylus on the machine: a switch, nothing moves
    dme._refresh_daemon()


def get_change_tool_action(dme: Any, cmd: P.Command):
    name = one(cmd, P.Text).value
    dme.tools.lookup(name, cmd.name)
    yield "ChangeToolAction(Switch, X(0), Y(0), Z(0))"


def align_tool(dme: Any, cmd: P.Command):
    if not all(isinstance(a, float) for a in cmd.args) or len(cmd.args) not in (4, 8):
        raise IppError(502, cmd.name, "AlignTool(i, j, k, alpha) or AlignTool(i1, j1, k1, i2, j2, k2, alpha, beta)")
    v = np.array(cmd.args, dtype=float)
    vectors = [v[0:3]] if len(v) == 4 else [v[0:3], v[3:6]]
    for vec in vectors:
        if abs(np.linalg.norm(vec) - 1.0) > 1e-3:
            raise IppError(502, cmd.name, f"{vec.tolist()} is not a unit vector")
    dme._tool_for_motion(cmd.name)
    alpha = v[3] if len(v) == 4 else v[6]
    shaft = dme.csy.vector_from_machine([0.0, 0.0, 1.0])  # the fixed vertical stylus, away from the surface
    off = math.degrees(math.acos(max(-1.0, min(1.0, float(np.dot(vectors[0], shaft))))))
    if alpha != 0 and off > alpha:
        raise IppError(1502, cmd.name, f"the stylus is fixed vertical: {off:.1f} deg from the request")
    reached = list(shaft) + ([] if len(vectors) == 1 else list(vectors[1]))
    yield P.fmt_args(round(float(x), 6) for x in reached)


# --- coordinate systems (6.3.3) -------------------------------------------------------------------


def set_coord_system(dme: Any, cmd: P.Command):
    dme.csy.select(one(cmd, P.Enum).name, cmd.name)
    dme._refresh_daemon()


def get_coord_system(dme: Any, cmd: P.Command):
    yield f"CoordSystem({dme.csy.current})"


def get_csy_transformation(dme: Any, cmd: P.Command):
    t = dme.csy.get(one(cmd, P.Enum).name, cmd.name)
    yield P.prop("GetCsyTransformation", *t.values)


def set_csy_transformation(dme: Any, cmd: P.Command):
    if len(cmd.args) != 7 or not isinstance(cmd.args[0], P.Enum) or \
            not all(isinstance(a, float) for a in cmd.args[1:]):
        raise IppError(502, cmd.name, "SetCsyTransformation(Csy, X0, Y0, Z0, Theta, Psi, Phi)")
    dme.csy.set(cmd.args[0].name, list(cmd.args[1:]), cmd.name)  # type: ignore[union-attr,arg-type]
    dme._refresh_daemon()


HANDLERS: dict[str, Callable[..., Any]] = {
    "GetDMEVersion": get_dme_version,
    "IsHomed": is_homed,
    "EnableUser": enable_user,
    "DisableUser": disable_user,
    "IsUserEnabled": is_user_enabled,
    "GetMachineClass": get_machine_class,
    "GetProp": get_prop,
    "SetProp": set_prop,
    "EnumProp": enum_prop,
    "EnumAllProp": enum_all_prop,
    "EnumTools": enum_tools,
    "FindTool": find_tool,
    "ChangeTool": change_tool,
    "GetChangeToolAction": get_change_tool_action,
    "AlignTool": align_tool,
    "SetCoordSystem": set_coord_system,
    "GetCoordSystem": get_coord_system,
    "GetCsyTransformation": get_csy_transformation,
    "SetCsyTransformation": set_csy_transformation,
    "GetPropE": get_prop,
    "SetPropE": set_prop,
    "SetTool": change_tool,
}
