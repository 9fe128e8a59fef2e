"""I++ DME tools and their property blocks (spec 6.3.2.14-6.3.2.23, 6.3.6, 6.3.7).

Every tool has a GoToPar block (Speed, Accel) and, unless it is NoTool, a
PtMeasPar block (Speed, Accel, Approach, Search, Retract); each parameter has
Act, Def, Max and Min, and only Act can be set (clamped to Min..Max with the
warning 0504). Becoming the active tool resets Act to Def.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .errors import IppError

GOTO_PARAMS = ("Speed", "Accel")
PTMEAS_PARAMS = ("Speed", "Accel", "Approach", "Search", "Retract")
SUBS = ("Act", "Def", "Max", "Min")


@dataclass
class Param:
    default: float
    min: float
    max: float
    act: float = float("nan")

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.act = self.default

    def get(self, sub: str) -> float:
        return {"Act": self.act, "Def": self.default, "Max": self.max, "Min": self.min}[sub]

    def set(self, value: float) -> bool:
        """Set Act, clamped; False when it had to be clamped (warning 0504)."""
        self.act = min(max(value, self.min), self.max)
        return self.act == value


@dataclass
class Tool:
    name: str
    radius: float  # stylus ball radius (effective radius from the probe calibration record)
    goto: dict[str, Param]
    ptmeas: dict[str, Param] | None  # None: NoTool cannot measure
    id: str = "0"
    visible: bool = True  # listed by EnumTools
    selectable: bool = True  # ChangeTool / SetTool may select it

    def reset(self) -> None:
        for p in list(self.goto.values()) + list((self.ptmeas or {}).values()):
            p.reset()

    def block(self, name: str) -> dict[str, Param]:
        if name == "GoToPar":
            return self.goto
        if name == "PtMeasPar":
            if self.ptmeas is None:
                raise IppError(507, "", f"{self.name} cannot measure: it has no PtMeasPar")
            return self.ptmeas
        raise IppError(510, "", f"no property block {name}")


@dataclass
class Limits:
    """What the machine allows, from its configuration (mm, mm/s, mm/s^2)."""

    goto_speed: tuple[float, float, float]  # default, min, max
    goto_accel: tuple[float, float, float]
    ptmeas_speed: tuple[float, float, float]
    ptmeas_accel: tuple[float, float, float]
    approach: tuple[float, float, float]
    search: tuple[float, float, float]
    retract: tuple[float, float, float]

    @classmethod
    def from_config(cls, config) -> "Limits":
        s, a, p = config.speeds, config.accelerations, config.probe
        fast = max(s.positioning, s.jog_fast)
        hard = max(a.positioning, a.stop)
        return cls(goto_speed=(s.positioning, 0.1, fast), goto_accel=(a.positioning, 1.0, hard),
                   ptmeas_speed=(s.probing, 0.1, 5 * s.probing), ptmeas_accel=(a.probing, 1.0, hard),
                   approach=(p.approach_distance, 0.1, 50.0), search=(p.search_distance, 0.1, 50.0),
                   retract=(p.retract_distance, -1.0, 50.0))


def _params(limits: Limits, measuring: bool) -> tuple[dict[str, Param], dict[str, Param] | None]:
    goto = {"Speed": Param(*limits.goto_speed), "Accel": Param(*limits.goto_accel)}
    if not measuring:
        return goto, None
    return goto, {"Speed": Param(*limits.ptmeas_speed), "Accel": Param(*limits.ptmeas_accel),
                  "Approach": Param(*limits.approach), "Search": Param(*limits.search),
                  "Retract": Param(*limits.retract)}


@dataclass
class ToolChanger:
    """The tool set: the predefined tools plus one tool per calibrated stylus."""

    tools: dict[str, Tool] = field(default_factory=dict)
    active: str = "UnDefTool"
    found: str = "UnDefTool"

    @classmethod
    def build(cls, limits: Limits, probes: list[tuple[str, float]]) -> "ToolChanger":
        tc = cls()
        tc.add(limits, "BaseTool", 0.0, True, visible=False)
        tc.add(limits, "RefTool", 0.0, True)
        tc.add(limits, "NoTool", 0.0, False)
        for name, radius in probes:
            tc.add(limits, name, radius, True)
        tc.active = "NoTool"  # until the client says which tool it uses: moves allowed, no measuring
        return tc

    def add(self, limits: Limits, name: str, radius: float, measuring: bool = True, **kw) -> Tool:
        """A tool with the machine's parameter limits (a stylus added to the station's probe list, too)."""
        goto, ptmeas = _params(limits, measuring)
        self.tools[name] = Tool(name, radius, goto, ptmeas, id=str(len(self.tools) + 1), **kw)
        return self.tools[name]

    def names(self) -> list[str]:
        return [t.name for t in self.tools.values() if t.visible]

    def lookup(self, name: str, method: str) -> Tool:
        if name == "UnDefTool":
            raise IppError(1503, method, "UnDefTool cannot be selected")
        tool = self.tools.get(name)
        if tool is None:
            raise IppError(1502, method, f"no tool named {name!r}; EnumTools lists {', '.join(self.names())}")
        return tool

    def select(self, name: str, method: str) -> Tool:
        tool = self.lookup(name, method)
        self.active = tool.name
        tool.reset()
        return tool

    def pointer(self, root: str, method: str) -> Tool:
        """The tool a property path starts from: Tool (active) or FoundTool."""
        name = self.active if root == "Tool" else self.found
        if name == "UnDefTool" or name not in self.tools:
            raise IppError(1503, method, f"{root} is UnDefTool")
        return self.tools[name]

    @property
    def tool(self) -> Tool | None:
        return self.tools.get(self.active)


# --- property paths ---------------------------------------------------------------


def resolve(tc: ToolChanger, path: str, method: str):
    """A property path -> (tool, block, param, sub) with None for the parts not given.

    ``Tool.PtMeasPar.Speed`` means ``Tool.PtMeasPar.Speed.Act`` (6.3.6).
    """
    parts = path.split(".")
    if parts[0] not in ("Tool", "FoundTool"):
        raise IppError(510, method, f"unknown property {path}")
    tool = tc.pointer(parts[0], method)
    if len(parts) == 1:
        return tool, None, None, None
    if parts[1] in ("Name", "Id", "AvrRadius", "Alignment", "CollisionVolume") and len(parts) == 2:
        return tool, parts[1], None, None
    block = tool.block(parts[1])
    if len(parts) == 2:
        return tool, block, None, None
    param = block.get(parts[2])
    if param is None or len(parts) > 4 or (len(parts) == 4 and parts[3] not in SUBS):
        raise IppError(510, method, f"unknown property {path}")
    return tool, block, param, parts[3] if len(parts) == 4 else None


def children(tc: ToolChanger, path: str, method: str, recursive: bool) -> list[tuple[str, str]]:
    """EnumProp / EnumAllProp: (name, type) pairs below a property path."""
    tool, block, param, sub = resolve(tc, path, method)
    if isinstance(block, str) or sub is not None:
        return []
    if param is not None:
        return [(s, "Number") for s in SUBS]

    def param_entries(name: str) -> list[tuple[str, str]]:
        out = [(name, "Number"), (name, "Property")]
        if recursive:
            out += [(f"{name}.{s}", "Number") for s in SUBS]
        return out

    if block is not None:
        return [e for name in block for e in param_entries(name)]
    out: list[tuple[str, str]] = []
    for bname in ("GoToPar", "PtMeasPar"):
        if bname == "PtMeasPar" and tool.ptmeas is None:
            continue
        out.append((bname, "Property"))
        if recursive:
            out += [(f"{bname}.{n}", t) for n, t in
                    (e for name in tool.block(bname) for e in param_entries(name))]
    return out
