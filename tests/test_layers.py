"""The architecture holds: imports go down the layers only, and no module imports itself in a circle.

Layers (README "Architecture"): front ends (ui, ippdme, opcua, dmis, cli) -> station (composition root) -> control
-> machine -> nmc, and station -> measurement and session, beside each other; the command API's mechanics (cmm.api)
under the control core, which registers the machine's verbs into it, importing no other part of cmm; -> the program files (cmm.program) -> the
journal (cmm.journal: records, fold, writer, stores) -> metrology; the measurement model never imports the
sessions; calibration beside them; the simulator speaks only bytes. Every import
counts: those inside functions, and those for type checkers only (``if TYPE_CHECKING:``), which draw the
same circle for a reader and for the type checker. So do modules named in a string (the `cmm` command's
sub-commands, loaded with ``importlib``; pyserial's handler package for ``sim://`` URLs): they are imported all the same.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1] / "cmm"

# package -> the cmm packages it may import (itself always)
ALLOWED = {
    "nmc": set(),
    "cad": set(),  # STEP/IGES read with OpenCASCADE into plain data: faces with exact surfaces
    "metrology": {"cad"},  # picks, nominals and deviations use a CAD part's exact surfaces
    "data": set(),
    # the command API's mechanics (registry, calls, error codes, subscriptions, the caller): it knows verbs by name,
    # never what is behind them; every layer registers its own verbs, queries, streams and error kinds into it
    "api": set(),
    "machine": {"nmc", "metrology", "data"},
    "control": {"api", "machine", "nmc"},
    # machine.config: the axes it simulates, never the driver; cad: a CAD part's probe contacts on its exact surfaces
    "sim": {"nmc", "machine", "metrology", "cad"},
    # the journal: the records of its events, their fold (SessionState), its writer and stores; the live model
    # and the session files share it
    "journal": {"machine", "metrology"},  # a HitRecord is the prober's Hit with its id
    "program": {"metrology", "journal"},  # program files (TOML): taught from a recorded session
    "session": {"machine", "metrology", "sim", "journal"},
    "calibration": {"machine", "metrology", "nmc", "sim", "session", "program"},  # program: its TOML text writer
    "measurement": {"metrology", "journal", "program"},  # the measurement model: journals its events, fits with metrology
    "station": {"api", "control", "machine", "measurement", "metrology", "nmc", "session", "sim", "calibration"},
    # the I++ DME and OPC UA servers: front ends on the command API only (the control core's errors and access
    # rules for connections from cmm.control)
    "ippdme": {"api", "control"},
    "opcua": {"api", "control"},
    # DMIS programs: a front end too; program: the part programs' one runner (cmm.program.runner)
    "dmis": {"api", "control", "measurement", "metrology", "session", "program"},
    "ui": {"api", "control", "measurement", "journal", "metrology", "session", "program", "ippdme", "dmis",
           "opcua"},  # hosts I++ and DMIS runs
    # every sub-command is a module of cmm/cli (a front end: it translates options into the capability's calls)
    "cli": {"api", "station", "control", "ui", "sim", "session", "calibration", "metrology", "machine", "nmc", "dmis",
            "ippdme", "opcua", "cad", "measurement", "journal", "program"},
}
# known exceptions (module, package) -> the reason it is there
EXCEPTIONS: dict[tuple[str, str], str] = {
    ("cmm.nmc.transport", "sim"): "names cmm.sim as pyserial's handler package for sim:// URLs (pyserial imports "
                                  "cmm.sim.protocol_sim only when such a URL is opened); the driver never imports it",
}
# modules that must not be imported from the given package at all
FORBIDDEN = {("ui", "cmm.machine.motion"), ("ui", "cmm.sim.cmm_sim"), ("ui", "cmm.nmc.bus"),
             ("ippdme", "cmm.ui.origin"), ("machine", "cmm.control.core"),
             ("cli", "cmm.machine.motion"), ("cli", "cmm.machine.probing"), ("cli", "cmm.nmc.bus")}
# the machine's and the bus's parts are the machine and the bus: what is forbidden of them is forbidden of these
FORBIDDEN |= {(pkg, part) for pkg, whole in list(FORBIDDEN) if whole in ("cmm.machine.motion", "cmm.nmc.bus")
              for part in {"cmm.machine.motion": ("cmm.machine.connection", "cmm.machine.jogging"),
                           "cmm.nmc.bus": ("cmm.nmc.framing", "cmm.nmc.transactions", "cmm.nmc.lost_reply",
                                           "cmm.nmc.resync", "cmm.nmc.startup")}[whole]}


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    """A module's syntax tree, parsed once for all the tests of this file (each walks every module)."""
    return ast.parse(path.read_text(encoding="utf-8"))


def _modules() -> dict[str, Path]:
    mods = {}
    for p in ROOT.rglob("*.py"):
        parts = p.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = p
    return mods


def _imports(name: str, path: Path, mods: dict[str, Path]) -> set[str]:
    return set(_imports_of(name, path, frozenset(mods)))


@functools.lru_cache(maxsize=None)
def _imports_of(name: str, path: Path, mods: frozenset[str]) -> frozenset[str]:
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for alias in node.names:
                full = f"{mod}.{alias.name}"
                out.add(full if full in mods else mod)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in mods:
            out.add(node.value)  # a module imported by its name (importlib, a plug-in package)
    return frozenset(m for m in out if m.split(".")[0] == "cmm" and m in mods)


# modules that are a layer of their own inside their package
SUBLAYERS: dict[str, str] = {}


def _layer(module: str) -> str:
    if module in SUBLAYERS:
        return SUBLAYERS[module]
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "cmm"


def _graph() -> nx.DiGraph:
    mods = _modules()
    g = nx.DiGraph()
    for name, path in mods.items():
        g.add_node(name)
        for target in _imports(name, path, mods):
            if target != name and not name.startswith(target + "."):  # a package's own __init__ is not a cycle
                g.add_edge(name, target)
    return g


def test_imports_go_down_the_layers():
    bad = []
    for a, b in _graph().edges:
        la, lb = _layer(a), _layer(b)
        if la == lb or lb == "cmm" or la == "cmm":
            continue
        if la in ALLOWED and lb not in ALLOWED[la] and (a, lb) not in EXCEPTIONS:
            bad.append(f"{a} -> {b}")
        if (la, b) in FORBIDDEN:
            bad.append(f"{a} -> {b} (forbidden)")
    assert not bad, "imports against the layers:\n" + "\n".join(sorted(bad))


def test_no_import_cycles():
    cycles = [c for c in nx.simple_cycles(_graph()) if len(c) > 1]
    assert not cycles, f"import cycles: {cycles[:5]}"


def test_the_measurement_model_never_imports_the_sessions():
    """cmm/measurement journals through cmm.journal and reads programs from cmm.program; no module of it imports
    cmm.session, at module level, inside a function or for type checkers (a routine's report goes through the
    model's ``reporter``, which the station wires)."""
    g = _graph()
    bad = sorted(f"{a} -> {b}" for a, b in g.edges
                 if (a == "cmm.measurement" or a.startswith("cmm.measurement."))
                 and (b == "cmm.session" or b.startswith("cmm.session.")))
    assert "cmm.measurement.model" in g and "cmm.journal.writer" in set(g.successors("cmm.measurement.model"))
    assert not bad, "the measurement model imports the sessions:\n" + "\n".join(bad)


def test_the_ui_reaches_the_machine_only_through_the_command_api():
    """No UI module imports the machine, the bus, the simulator or the calibration routines and records: the
    calibration tab calls the station's calibration service, which runs them through the command API."""
    g = _graph()
    ui = [n for n in g if n.startswith("cmm.ui")]
    reached = {t for n in ui for t in g.successors(n)}
    assert not {t for t in reached if t.startswith(("cmm.machine", "cmm.nmc", "cmm.sim", "cmm.calibration"))}
    assert any(t.startswith("cmm.control") for t in reached)


def test_the_calibration_cli_reaches_the_machine_only_through_the_command_api():
    """`cmm calibrate` is a front end like the Calibration tab: it builds a station and runs the routines through
    its calibration service; it imports neither the machine, the bus nor the routines that drive them."""
    g = _graph()
    assert "cmm.cli.calibrate" in g and "cmm.calibration.cli" not in g
    reached = set(g.successors("cmm.cli.calibrate"))
    assert "cmm.station" in reached and "cmm.calibration.service" in reached
    assert not {t for t in reached if t.startswith(("cmm.machine", "cmm.nmc"))
                or t in ("cmm.calibration.probe", "cmm.calibration.iso10360", "cmm.calibration.geometry")}


def test_the_control_core_uses_only_the_machines_public_surface():
    """cmm/control reads and drives the machine through its public API (``motion``, ``abort``, ``halt``, ...):
    no ``<anything but self>._name`` attribute, no ``getattr(x, "_name")`` on another object."""
    bad = []
    for path in sorted((ROOT / "control").glob("*.py")):
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                owner = node.value
                if not (isinstance(owner, ast.Name) and owner.id in ("self", "cls")):
                    bad.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "setattr")
                  and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
                  and str(node.args[1].value).startswith("_") and not str(node.args[1].value).startswith("__")
                  and not (isinstance(node.args[0], ast.Name) and node.args[0].id in ("self", "cls"))):
                bad.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    assert not bad, "private attributes of other objects used in cmm/control:\n" + "\n".join(bad)


def test_comments_say_what_the_code_does_not_its_history():
    """No "issue 12 item 5" references and no citations of design notes outside the repository (``shared/docs/...``,
    a ``picservo-nmc.md`` that no file of the repository is called)."""
    import re

    tree = ROOT.parent
    notes = {p.name for d in ("cmm", "tests", "benchmarks", "calibration", "docs") for p in (tree / d).rglob("*.md")}
    notes.add("README.md")

    def outside(line: str) -> bool:
        if re.search(r"\bissue \d+\b|\bitem \d+\b|\bshared/docs/", line, re.IGNORECASE):
            return True
        return any(Path(name).name not in notes for name in re.findall(r"[\w./-]+\.md\b", line))

    bad = [f"{p.relative_to(tree)}:{i}" for d in ("cmm", "tests", "benchmarks") for p in sorted((tree / d).rglob("*.py"))
           for i, line in enumerate(p.read_text().splitlines(), 1) if outside(line) and p.name != "test_layers.py"]
    assert not bad, "history or outside references in comments:\n" + "\n".join(bad)


FRONT_ENDS = ("ui", "cli", "ippdme", "dmis", "calibration", "opcua")
# what holds the machine in the composition root and the control core: a front end names these only to reach the
# command API (``station.controller.commands``) or the control core's read-only views, never their machine
OWNERS = {"station", "host", "st", "controller", "api", "core", "ctl", "self.station", "self.host", "self.controller",
          "self.api", "app.station", "self.app.station", "ctx.station", "self.ctx.station"}
MACHINE_PARTS = {"machine", "prober", "bus", "dispatcher"}
# the control core's commands: front ends send them as verbs (``commands.invoke`` / ``commands.call``)
COMMANDS = {"move", "probe", "step", "home", "zero", "reset", "reconnect", "run_job", "run_routine", "configure",
            "jog", "cancel", "cancel_jobs", "connect"}


@functools.lru_cache(maxsize=None)
def _front_end_uses() -> tuple[tuple[str, int, str, str], ...]:
    """(file, line, owner, attribute) of every ``owner.attribute`` in the front ends (gathered once)."""
    out = []
    for pkg in FRONT_ENDS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(_tree(path)):
                if isinstance(node, ast.Attribute):
                    out.append((f"{pkg}/{path.relative_to(ROOT / pkg)}", node.lineno, ast.unparse(node.value),
                                node.attr))
    return tuple(out)


def test_front_ends_never_touch_the_machine_the_prober_or_the_bus():
    """The UI, the CLI, the I++ server, DMIS and calibration reach the machine only through cmm.control: no
    ``station.machine``, ``host.prober``, ``controller.machine.bus`` ... A calibration routine works on the machine
    the control core hands its job (``job.machine``, ``setup.prober``), inside the ``run_job`` / ``configure`` verbs."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in MACHINE_PARTS and (owner in OWNERS or owner.split(".")[-1] in OWNERS - {"api"})]
    assert not bad, "front ends reaching around the command API:\n" + "\n".join(bad)


# the page's files that get the command API only: they read with its queries (and subscriptions) and change the
# station with its verbs
API_ONLY_UI = ("context.py", "app.py", "panels.py", "panel_machine.py", "panel_features.py", "panel_status.py",
               "panel_align.py", "panel_jog.py", "scene.py", "pendant.py", "panel_colour_map.py", "panel_measure.py",
               "path_preview.py", "model_view.py", "frames.py")
# the tests' hook: StationApp keeps the station the tests and benchmarks hand in (no panel reads it), and turns a
# station handed in where the API is expected into its API; the pendant likewise
TRANSITIONAL = {("app.py", "self.station"), ("app.py", "api.controller"), ("pendant.py", "api.controller")}


def test_the_page_reaches_the_station_through_the_command_api_only():
    """The status bar, the machine, jog, features, align, measure and colour map tabs, the 3-D scene, the pendant and
    the page's entry get the command API, never the station, its control core or the measurement model: no
    ``x.station``, ``x.controller``, ``x.measurement`` or ``x.prober`` (the configuration too is a query,
    ``config``), but for the transitional station attribute."""
    bad = []
    for name in API_ONLY_UI:
        for node in ast.walk(_tree(ROOT / "ui" / name)):
            if (isinstance(node, ast.Attribute) and node.attr in ("station", "controller", "measurement", "prober")
                    and (name, ast.unparse(node)) not in TRANSITIONAL):
                bad.append(f"ui/{name}:{node.lineno} {ast.unparse(node)}")
    assert not bad, "the page reaching around the command API:\n" + "\n".join(bad)


def test_front_ends_send_commands_as_verbs():
    """The page, the pendant, the CLI, DMIS, the I++ server and calibration send their machine commands through
    the command API's verbs, so every front end gets the same checks and answers: no ``controller.move(...)``,
    ``controller.stop(...)`` or ``controller.jogs.hold(...)`` beside ``commands.invoke("move", ...)``; the
    pendant only translates its messages into verbs."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if (attr in COMMANDS | {"stop", "emergency_stop", "jog_release", "step"}
               and owner.split(".")[-1] in ("controller", "api", "core"))
           or (attr in ("hold", "release") and owner.split(".")[-1] == "jogs")]
    assert not bad, "commands sent around the verbs:\n" + "\n".join(bad)


# the measurement model's methods that change the measurement: front ends send the verbs that call them
MODEL_CHANGES = {"fit_feature", "refit_feature", "set_feature_nominal", "construct_feature", "define_datum",
                 "define_gdt", "delete_gdt", "delete_feature", "delete_hit", "undo", "set_info", "set_alignment",
                 "add_hit", "probe", "probe_here"}


def test_front_ends_change_the_measurement_only_through_verbs():
    """Nominal, tolerance, datum, GD&T, refit, report header (the page) and the fits of a DMIS program go through the
    command API's verbs (``set_nominal``, ``define_gdt``, ``refit_feature``, ``measure_feature`` ...), with the
    control check every verb makes: no ``station.measurement.define_gdt(...)`` or ``self.model.fit_feature(...)``."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in MODEL_CHANGES and owner.split(".")[-1] in ("measurement", "model")]
    assert not bad, "the measurement changed around the verbs:\n" + "\n".join(bad)


def test_front_ends_save_and_apply_calibrations_through_verbs():
    """Save record, Accept gains and Use this probe (the page, `cmm calibrate`, an I++ ChangeTool) are the command
    API's ``save_calibration`` / ``accept_gains`` / ``select_probe`` verbs, checked like every other change."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in ("save", "accept_gains", "select_probe") and owner.split(".")[-1] in ("service", "calibration", "svc")
           and f != "calibration/verbs.py"]  # the verbs themselves, registered where the calibration lives
    assert not bad, "calibrations saved or applied around the verbs:\n" + "\n".join(bad)


def test_the_pages_measurement_buttons_send_verbs():
    """Fit, construct, delete, undo, probe here, auto-measure, align and calibrate on the page go through the command
    API's verbs (``ctx.do`` / ``commands.invoke``), not the measurement model's or the calibration's methods."""
    verbs = {"fit_feature", "construct_feature", "delete_feature", "delete_hit", "undo", "probe", "probe_here",
             "run_plan", "run_on", "run_program", "apply"}
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if f.startswith("ui/") and attr in verbs and owner.split(".")[-1] in ("measurement", "alignment", "model")]
    bad += [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
            if f.startswith("ui/") and attr == "run" and owner.split(".")[-1] in ("service", "calibration")]
    assert not bad, "measurement changed around the verbs:\n" + "\n".join(bad)


# the measurement model's methods that write the session journal: front ends send new_session / note / record_event
JOURNAL_WRITES = {"new_session", "new_part", "note", "record", "record_into"}


def test_front_ends_write_the_journal_only_through_verbs():
    """A new session (or part), a note and a front end's own event (a routine saved) are the command API's
    ``new_session``, ``new_part``, ``note`` and ``record_event`` verbs, with their access rule (a note: the holder or a local client): no
    ``station.measurement.note(...)``, ``model.new_session(...)`` or ``measurement.record(...)`` in the page, the
    pendant, the I++ server, DMIS, the CLI or calibration."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in JOURNAL_WRITES and owner.split(".")[-1] in ("measurement", "model")]
    assert not bad, "the journal written around the verbs:\n" + "\n".join(bad)


def test_the_pages_run_controls_send_verbs():
    """Pause, Resume and Skip step of a routine run or a probe qualification are the command API's ``pause``,
    ``resume`` and ``skip_step`` verbs (with their access rule), not the run's or the calibration's own methods."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in ("pause", "resume", "skip") and owner.split(".")[-1] in ("run", "run_", "service", "calibration")]
    assert not bad, "a run paused, resumed or skipped around the verbs:\n" + "\n".join(bad)


def test_front_ends_take_and_release_control_through_verbs():
    """Taking and giving up control (the page, the pendant, the I++ server) is the command API's ``take_control`` /
    ``release_control``: the core decides who may (a local client, the access code, an I++ listener the operator
    opened), not the adapter."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in ("try_take", "take", "release", "disconnected") and owner.split(".")[-1] in ("control", "_control",
                                                                                                  "holder")]
    assert not bad, "control taken or released around the verbs:\n" + "\n".join(bad)


def test_the_page_runs_dmis_programs_with_the_verb():
    """The Routine tab runs a DMIS program with the ``run_dmis`` verb (the holder only), never the runner itself."""
    bad = [f"ui/{p.relative_to(ROOT / 'ui')}" for p in sorted((ROOT / "ui").rglob("*.py")) if "run_text" in p.read_text()]
    assert not bad, "DMIS programs run around the verb:\n" + "\n".join(bad)


def test_front_ends_never_wire_the_station():
    """The station is built with what it records into (its trends) and told what serves it (the I++ DME server's
    status) through its own constructor and methods, and the probe in use reaches the measurement model through
    the station's wiring: no front end assigns ``station.measurement.trends = ...``, ``station.ippdme = ...`` or
    ``host.measurement.probe_name = ...``."""
    bad = []
    for pkg in FRONT_ENDS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(_tree(path)):
                targets = node.targets if isinstance(node, ast.Assign) else \
                    [node.target] if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else []
                for t in targets:
                    if isinstance(t, ast.Attribute) and ast.unparse(t.value).split(".")[-1] in (
                            "station", "measurement", "host"):
                        bad.append(f"{pkg}/{path.relative_to(ROOT / pkg)}:{node.lineno} {ast.unparse(t)}")
    assert not bad, "a front end wiring the station:\n" + "\n".join(bad)


def test_the_pendant_only_translates():
    """The pendant, the page's tab (ui/panels.py, its machine, jog and operator panels) and the panels' context
    (ui/context.py) neither install the access policy (the composition root, StationApp, does) nor judge access
    themselves: the core's verbs refuse in the operator's words, they pass them on (the page asks the core,
    ``check_access``, before an action of its own)."""
    for name in ("ui/pendant.py", "ui/panels.py", "ui/context.py", "ui/panel_machine.py", "ui/panel_jog.py",
                 "ui/panel_operator.py"):
        uses = [(f, line, owner, attr) for f, line, owner, attr in _front_end_uses() if f == name]
        bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in uses
               if attr in ("use_policy_of", "can_move", "may_stop", "policy", "refusal")]
        assert uses and not bad, f"{name} deciding access itself:\n" + "\n".join(bad)


# front-end modules that compose a station themselves, and why: each is a program's entry point that builds the
# station it then drives only through the command API (the composition a front end needs, never the model)
COMPOSERS = {
    "cmm.cli.serve": "`cmm serve` builds the station it serves (the page, the pendant, I++, OPC UA)",
    "cmm.cli.run": "`cmm run` builds the station a program runs on, then sends the run_program verb",
    "cmm.cli.calibrate": "`cmm calibrate` builds the station whose routines it runs with the qualify verb",
}
FRONT_END_PACKAGES = ("ui", "ippdme", "opcua", "cli", "dmis")


def test_front_ends_import_neither_the_station_nor_the_measurement_model():
    """The page, the pendant, the I++ server, OPC UA, DMIS and the command line receive the command API and read
    the model through its queries: none imports ``cmm.station`` or ``cmm.measurement.model`` (their sentences and
    names come from ``cmm.measurement.errors``), except the entry points in COMPOSERS, which build the station."""
    g = _graph()
    bad = [f"{a} -> {b}" for a, b in g.edges
           if _layer(a) in FRONT_END_PACKAGES and b in ("cmm.station", "cmm.measurement.model")
           and not (b == "cmm.station" and a in COMPOSERS)]
    assert not bad, "front ends importing the station or the model:\n" + "\n".join(sorted(bad))
    assert all(m in g for m in COMPOSERS), "a composer named here no longer exists: drop it from COMPOSERS"


# front ends that receive only the command API: built with the API object (``StationBackend(api)``,
# ``OpcUaServer(api, ...)``), they never hold the station, its control core, the measurement model or the
# calibration service, and read the machine through the API's queries and streams
API_ONLY = {"ippdme", "opcua"}
# the page and DMIS receive only the API too (no station, control core, model or calibration object: checked
# below), but import plain pieces of the layers under them: the page its drawings' metrology, DMIS the part
# programs' runner and the measurement's words
API_ONLY_PENDING = {"ui", "dmis"}
# not the calibration service: the tab's Calibration panel (cmm.ui.panel_calibration), named calibration too
API_ONLY_HOOKS = {("ui/panels.py", "self.calibration"), ("ui/panels.py", "self.calibration.build"),
                  ("ui/panels.py", "self.calibration.refresh")}
BEHIND_THE_API = ("station", "controller", "measurement", "calibration")


def test_api_only_front_ends_receive_nothing_but_the_api():
    """The I++ DME and OPC UA servers import neither the station, the measurement, the calibration, the sessions
    nor the machine (only cmm.api and cmm.control's errors and connection rules), and name no ``station``,
    ``controller``, ``measurement`` or ``calibration`` object: no ``station.controller``, ``self.controller.state``
    or ``service.calibration`` beside the API's ``invoke``, ``listen`` and ``subscribe``."""
    assert not API_ONLY & API_ONLY_PENDING and API_ONLY | API_ONLY_PENDING <= set(FRONT_END_PACKAGES)
    g = _graph()
    bad = sorted(f"{a} -> {b}" for a, b in g.edges if _layer(a) in API_ONLY and _layer(b) not in ("api", "control")
                 and _layer(b) != _layer(a) and b != "cmm")
    bad += [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
            if f.split("/")[0] in API_ONLY
            and (attr in BEHIND_THE_API or owner.split(".")[-1] in BEHIND_THE_API)]
    assert not bad, "front ends reaching behind the command API:\n" + "\n".join(bad)


def test_the_page_and_dmis_hold_no_object_behind_the_api():
    """The page (every tab, the scene, the pendant) and the DMIS runner name no ``station``, ``controller``,
    ``measurement`` or ``calibration`` object: they read with the API's queries and change with its verbs."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if f.split("/")[0] in API_ONLY_PENDING
           and (attr in BEHIND_THE_API or owner.split(".")[-1] in BEHIND_THE_API)
           and (f, f"{owner}.{attr}") not in API_ONLY_HOOKS]
    assert not bad, "the page or DMIS reaching behind the command API:\n" + "\n".join(bad)


def test_the_page_never_holds_the_models_lock():
    """The page draws from the API's ``model`` query (a snapshot copied under the model's lock inside the
    measurement package) and never takes ``measurement.lock`` itself, so a slow redraw never holds up a hit."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if f.split("/")[0] in FRONT_END_PACKAGES
           and attr == "lock" and owner.split(".")[-1] in ("measurement", "model", "station", "st", "host")]
    assert not bad, "front ends holding the model's lock:\n" + "\n".join(bad)


def test_in_process_front_ends_call_the_api_one_way():
    """The page, the pendant, the I++ server, DMIS, the command line and calibration call the API with
    ``invoke`` (the verb's result, its own error raised); ``call`` and ``request`` are the forms of the wire
    adapters, which pass a remote client's JSON request on and answer it with an error code: the OPC UA server
    and the pendant's WebSocket (``{"method", "params"}`` in, ``{"result" | "error"}`` out)."""
    wire = ("opcua/", "ui/pendant.py")
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in ("call", "request") and owner.split(".")[-1] in ("commands", "api", "cmds")
           and not f.startswith(wire)]
    assert not bad, "the API called another way than invoke:\n" + "\n".join(bad)


def test_front_ends_and_the_calibration_never_reach_the_simulator_through_the_station():
    """The simulated world comes from behind the port (``cmm.sim.bench``): the page asks the API's ``simulator``
    query where the part lies, the calibration service places its ball bar on the bench it is handed; none reads
    ``station.sim`` or ``host.sim``."""
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if attr in ("sim", "place_sim_artifacts", "mount_sim_stylus")
           and owner.split(".")[-1] in ("station", "st", "host", "self")]
    assert not bad, "the simulator reached through the station:\n" + "\n".join(bad)


# the page's panels that receive only the command API (through their PanelContext): they read with queries and
# change with verbs; a panel converted from reaching into the station joins this list
PANELS_ON_THE_API = ("ui/panel_sessions.py", "ui/panel_calibration.py", "ui/panel_trends.py", "ui/panel_operator.py",
                     "ui/panel_diagnostics.py", "ui/panel_part.py")


def test_panels_on_the_api_never_reach_the_station():
    """The panels in PANELS_ON_THE_API get nothing of the station: no ``ctx.station``, ``app.station``, no
    ``station.measurement``, ``.controller``, ``.calibration`` or ``.config``, no calibration service or trends
    object held; the session store is opened only to read a session for replay (its changes are verbs)."""
    held = ("station", "measurement", "controller", "calibration", "service", "config")
    bad = [f"{f}:{line} {owner}.{attr}" for f, line, owner, attr in _front_end_uses()
           if f in PANELS_ON_THE_API and (attr in held or owner.split(".")[-1] in held)]
    assert not bad, "a panel reaching around the command API:\n" + "\n".join(bad)
    assert all((ROOT / f).is_file() for f in PANELS_ON_THE_API), "a panel named here no longer exists"


# what the page draws from its subscriptions (cmm/ui/feed.py) instead of polling the queries: the status bar (its
# 20 Hz redraw too) and the read-outs the read-outs' subscription delivers; (file, class or None, function or None)
SUBSCRIBERS = (("ui/panel_status.py", "StatusPanel", None), ("ui/panels.py", "ClientApp", "fast_refresh"),
               ("ui/panels.py", "ClientApp", "_readouts"), ("ui/panel_machine.py", "MachinePanel", "show_probe"),
               ("ui/panel_part.py", "PartPanel", "show"))
POLLS = ("query", "invoke", "model", "call")  # a query asked (ctx.query, api.invoke, ctx.model, api.call)


def test_the_status_bar_and_the_subscribed_read_outs_poll_no_query():
    """The status bar, the refresher's 20 Hz pass over it and the read-outs drawn from the read-outs' subscription
    call no query (``query(...)``, ``invoke(...)``, ``model()``) themselves: they draw from the tab's subscriptions
    (a tab without a page reads the bar's queries once per ask, through ``status_snapshot``)."""
    import ast

    bad = []
    for f, cls, fn in SUBSCRIBERS:
        for klass in (n for n in ast.walk(_tree(ROOT / f)) if isinstance(n, ast.ClassDef) and n.name == cls):
            scopes = [n for n in klass.body if isinstance(n, ast.FunctionDef) and fn in (None, n.name)]
            assert scopes, f"{f}: {cls}.{fn} no longer exists"
            bad += [f"{f}:{call.lineno} {ast.unparse(call)}" for scope in scopes for call in ast.walk(scope)
                    if isinstance(call, ast.Call)
                    and (getattr(call.func, "attr", None) or getattr(call.func, "id", None)) in POLLS]
    assert not bad, "polling what the subscriptions deliver:\n" + "\n".join(bad)


MODULE_LINES = 800
CLASS_LINES = 500


def test_modules_and_classes_stay_small():
    """One job per module and class: no module over 800 lines, no class over 500 (a grown file is split by
    responsibility, as the bus, the control core and the DMIS executor were)."""
    import ast

    too_big = []
    for name, path in _modules().items():
        text = path.read_text(encoding="utf-8")
        lines = text.count("\n") + 1
        if lines > MODULE_LINES:
            too_big.append(f"{name}: {lines} lines")
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > CLASS_LINES:
                too_big.append(f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines")
    assert not too_big, "split by responsibility: " + "; ".join(too_big)


# what a routine's run never holds: the measurement model, the control core and its command API, the station
RUN_NEVER_HOLDS = {"model", "measurement", "controller", "commands", "jobs", "api", "station", "prober", "machine"}


def test_a_routines_run_reaches_the_station_only_through_its_host():
    """A routine's run (cmm/measurement/routine_run.py) gets the narrow RoutineHost protocol
    (cmm/measurement/routine_host.py), as the I++ executor gets its Backend and the calibration service its
    CalibrationHost: its constructor takes the host typed as the protocol, it names no ``model``, ``controller``,
    ``commands``, ``jobs`` ... object (no ``self.model``, no ``self.controller.state``), and it imports neither the
    measurement model, the control core, the station nor the host's adapter."""
    run_path, host_path = ROOT / "measurement" / "routine_run.py", ROOT / "measurement" / "routine_host.py"
    protocol = next(n for n in _tree(host_path).body if isinstance(n, ast.ClassDef) and n.name == "RoutineHost")
    assert any(ast.unparse(b) == "Protocol" for b in protocol.bases), "RoutineHost is a typing.Protocol"
    run = next(n for n in _tree(run_path).body if isinstance(n, ast.ClassDef) and n.name == "RoutineRun")
    init = next(n for n in run.body if isinstance(n, ast.FunctionDef) and n.name == "__init__")
    params = {a.arg: None if a.annotation is None else ast.unparse(a.annotation)
              for a in init.args.args + init.args.kwonlyargs}
    assert params.get("host") == "RoutineHost", f"RoutineRun takes its host as the protocol: {params}"
    bad = []
    for node in ast.walk(_tree(run_path)):
        if isinstance(node, ast.Attribute) and (node.attr in RUN_NEVER_HOLDS
                                                or ast.unparse(node.value).split(".")[-1] in RUN_NEVER_HOLDS):
            bad.append(f"routine_run.py:{node.lineno} {ast.unparse(node)}")
        elif isinstance(node, ast.Name) and node.id in RUN_NEVER_HOLDS | {"StationRoutineHost"}:
            bad.append(f"routine_run.py:{node.lineno} {node.id}")
        elif isinstance(node, ast.arg) and node.arg in RUN_NEVER_HOLDS:
            bad.append(f"routine_run.py:{node.lineno} parameter {node.arg}")
    mods = _modules()
    bad += [f"routine_run.py imports {m}" for m in _imports("cmm.measurement.routine_run", run_path, mods)
            if m in ("cmm.measurement.model", "cmm.measurement.verbs", "cmm.station") or _layer(m) == "control"]
    bad += ["routine_run.py imports StationRoutineHost" for node in ast.walk(_tree(run_path))
            if isinstance(node, ast.ImportFrom) and any(a.name == "StationRoutineHost" for a in node.names)]
    assert not bad, "a routine's run reaching around its host:\n" + "\n".join(bad)
