"""Routine > the routine and its steps: *Teach from this session*, the step list, the Edit step folder (rename, move,
skip, delete, tolerance, clearance, nominal, hit plan, a hit, probe, insert) and the File folder (Save, Export
DMIS, Open).

*Teach from this session* turns what the operator did (the 3-2-1 alignment, every measured feature, the
constructions) into a routine (:mod:`cmm.measurement.routine`); each step is a line the operator can select and
edit. *Save* / *Open* use the program file format; *Export DMIS* writes the routine as a DMIS program beside it
(and offers it as a download).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable

from ..measurement.errors import MeasurementError
from ..measurement.routine import CONSTRUCTIONS, Routine, RoutineError
from ..program.toml_program import ProgramError, load, part_hash
from .context import OPERATOR_ERRORS, PanelContext


def parse_nominal(text: str) -> dict[str, Any]:
    """'radius=15.01 point=30 40 0' -> {'radius': 15.01, 'point': [30.0, 40.0, 0.0]}."""
    out: dict[str, Any] = {}
    key = None
    for word in text.replace(",", " ").replace(";", " ").replace("=", "= ").split():
        if word.endswith("="):
            key = word[:-1].strip()
            if not key:
                raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
            out[key] = []
            continue
        if key is None:
            raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
        try:
            out[key].append(float(word))
        except ValueError:
            raise RoutineError(f"{key}: {word!r} is not a number") from None
    if not out or any(not v for v in out.values()):
        raise RoutineError("write name=value, e.g. radius=15.01 or point=30 40 0")
    return {k: v[0] if len(v) == 1 else v for k, v in out.items()}



class RoutineEditPanel:
    """The routine of one tab and its edits; ``busy`` says why the routine cannot be edited now (None: it can)."""

    def __init__(self, ctx: PanelContext, gui: dict[str, Any], busy: Callable[[], str | None]) -> None:
        self.ctx = ctx
        self.gui = gui  # the Routine tab's widgets (shared with its run and DMIS panels)
        self.busy = busy
        self.routine: Routine | None = None

    def teach(self, name: str = "") -> Routine | None:
        try:  # from the live session's journal, on the part loaded
            self.routine = self.ctx.commands.invoke(self.ctx.who(), "teach_routine", name=name.strip() or None)
        except MeasurementError as exc:  # no journal file to teach from
            self.ctx.error(exc, "Routine")
            return None
        except (ProgramError, ValueError, OSError) as exc:
            self.ctx.error(exc, "Teach")
            return None
        self.ctx.notify("Routine taught", f"{len(self.routine.steps)} steps from this session")
        self._show()
        return self.routine

    def open(self, path: str) -> Routine | None:
        try:
            self.routine = Routine(load(self._path(path)))
        except (ProgramError, OSError) as exc:
            self.ctx.error(exc, "Open routine")
            return None
        self._show()
        return self.routine

    def save(self, path: str) -> Path | None:
        if self.routine is None:
            self.ctx.error("teach or open a routine first", "Save routine")
            return None
        try:
            saved = self.routine.save(self._path(path))
        except OSError as exc:
            self.ctx.error(f"cannot write {path}: {exc.strerror or exc}", "Save routine")
            return None
        try:
            self.ctx.commands.invoke(self.ctx.who(), "record_event", kind="routine_saved",
                                     data={"name": self.routine.name, "path": str(saved), "text": self.routine.text()})
        except OPERATOR_ERRORS as exc:  # the file is written; the journal refused to say so (this tab observes)
            self.ctx.notify("Routine saved", f"{saved} (not in the session journal: {exc})", "error")
            return saved
        self.ctx.notify("Routine saved", str(saved))
        return saved

    def export_dmis(self, path: str) -> Path | None:
        """Write the routine as a DMIS program, ``<routine name>.dmi`` beside its routine file (``path``, as Save
        takes it), for the part where the station has it now (a feature's later hits hop over its mesh as the
        routine runner's); offered to the browser as a download."""
        from ..dmis.export import to_dmis

        if self.routine is None:
            self.ctx.error("teach or open a routine first", "Export DMIS")
            return None
        part = self.ctx.model().part
        pose = part.pose if part is not None else [[1, 0, 0, 190.0], [0, 1, 0, 150.0], [0, 0, 1, 0], [0, 0, 0, 1]]
        probe = self.ctx.commands.invoke(self.ctx.who(), "probing_setup")  # the configured probe and its cycle
        # the part the routine was taught on: its later hits of a feature hop over its mesh as the runner's
        mesh = part.mesh if part is not None and part_hash(part) == self.routine.program.part_sha256 else None
        stem = re.sub(r"[^\w.-]+", "_", self.routine.name).strip("._") or "routine"
        out = self._path(path).parent / f"{stem}.dmi"
        try:
            text = to_dmis(self.routine.program, pose, tip_radius=probe["nominal_tip_diameter"] / 2.0,
                           approach=probe["approach_distance"], search=probe["search_distance"],
                           retract=probe["retract_distance"], mesh=mesh)
            out.write_text(text, encoding="utf-8")
        except OSError as exc:
            self.ctx.error(f"cannot write {out}: {exc.strerror or exc}", "Export DMIS")
            return None
        except (ProgramError, ValueError, KeyError) as exc:
            self.ctx.error(f"the routine cannot be written as DMIS: {exc}", "Export DMIS")
            return None
        send = getattr(self.ctx.client, "send_file_download", None)
        if send is not None:
            try:
                send(out.name, out.read_bytes())
            except Exception:  # noqa: BLE001 - the tab may have closed; the file is on disk anyway
                pass
        self.ctx.notify("DMIS program exported", f"{out} ({len(self.routine.steps)} steps; run it with cmm run "
                        "or Open DMIS here)")
        return out

    def _path(self, text: str) -> Path:
        p = Path(text.strip() or f"{self.routine.name if self.routine else 'routine'}.toml").expanduser()
        base = self.ctx.commands.invoke(self.ctx.who(), "probing_setup")["session_dir"]
        return p if p.is_absolute() or base is None else Path(base) / p

    def edit(self, action: str, *args: Any) -> bool:
        """An edit of the selected step: rename, up, down, delete, skip, tolerance, clearance, nominal, hits, hit,
        probe, insert."""
        r = self.routine
        if r is None:
            self.ctx.error("teach or open a routine first", "Routine")
            return False
        refusal = self.busy()  # a run going on, or stopped on a fault and waiting, keeps its routine as it is
        if refusal:
            self.ctx.error(refusal, "Routine")
            return False
        i = self.selected()
        try:
            if action == "rename":
                r.rename(i, args[0])
            elif action in ("up", "down"):
                i = r.move(i, -1 if action == "up" else 1)
            elif action == "delete":
                r.delete(i)
                i = min(i, len(r.steps) - 1)
            elif action == "skip":
                r.set_skip(i, not r.steps[i].get("skip"))
            elif action == "manual":
                if r.steps[i]["kind"] != "align":
                    raise RoutineError(f"{r.steps[i]['name']} is not an alignment: choose the align step")
                r.set_manual(i, not r.steps[i].get("manual"))
            elif action == "probe":
                if r.steps[i]["kind"] not in ("feature", "align"):
                    raise RoutineError(f"{r.steps[i]['name']} does not measure: choose a feature or alignment step")
                r.set_probe(i, str(args[0]))
            elif action in ("tolerance", "clearance", "nominal", "hits", "hit"):
                step = r.steps[i]
                if step["kind"] != "feature":
                    raise RoutineError(f"{step['name']} is not a feature: choose a feature step")
                if action == "tolerance":
                    words = str(args[0]).replace(",", " ").split()
                    if len(words) != 3:
                        raise RoutineError("write three tolerances in mm: size form location (e.g. 0.02 0.01 0.05)")
                    size, form, location = (float(x) for x in words)
                    r.set_tolerance(step["name"], size=size, form=form, location=location)
                elif action == "clearance":
                    r.set_clearance(step["name"], float(args[0]))
                elif action == "nominal":
                    r.set_nominal(step["name"], **parse_nominal(str(args[0])))
                elif action == "hits":
                    r.set_hits(step["name"], [int(x) for x in str(args[0]).replace(",", " ").split()])
                else:
                    words = str(args[0]).replace(",", " ").split()
                    if len(words) not in (4, 7):
                        raise RoutineError("write the hit's id and its point X Y Z, optionally its approach I J K")
                    hid = int(words[0])
                    if hid not in r.feature(step["name"]).hits:
                        raise RoutineError(f"hit {hid} is not one of {step['name']}'s hits "
                                           f"({', '.join(map(str, r.feature(step['name']).hits))})")
                    nums = [float(x) for x in words[1:]]
                    r.set_hit(hid, nums[:3], nums[3:] or None)
            elif action == "insert":
                r.insert(i + 1, args[0])
                i += 1
        except (RoutineError, ValueError, IndexError) as exc:
            self.ctx.error(exc, "Routine")
            return False
        self._selected = i
        self._show(select=i)
        return True

    def insert_text(self, text: str) -> bool:
        """'report NAME', 'feature NAME' (a feature of the routine), 'align PRIMARY SECONDARY TERTIARY [manual]'
        or 'OPERATION A B [NAME]' (distance, angle, intersection, midpoint)."""
        words = text.split()
        if len(words) >= 1 and words[0] == "report":
            return self.edit("insert", {"kind": "report", "name": " ".join(words[1:]) or "report"})
        if len(words) == 2 and words[0] == "feature":
            return self.edit("insert", {"kind": "feature", "name": words[1]})
        if len(words) in (4, 5) and words[0] == "align" and (len(words) == 4 or words[4] == "manual"):
            taken = {s["name"] for s in self.routine.steps} if self.routine is not None else set()
            name = next(n for n in ("alignment", *(f"alignment {k}" for k in range(2, 99))) if n not in taken)
            return self.edit("insert", {"kind": "align", "name": name, "datums": words[1:4],
                                        "manual": len(words) == 5 or None})
        if len(words) in (3, 4) and words[0] in CONSTRUCTIONS:
            name = words[3] if len(words) == 4 else f"{words[1]}-{words[2]}"
            return self.edit("insert", {"kind": "construct", "name": name, "operation": words[0],
                                        "of": [words[1], words[2]]})
        self.ctx.error("write 'report NAME', 'feature NAME', 'align A B C [manual]' or 'distance A B [NAME]' "
                       "(distance, angle, intersection, midpoint)", "Insert step")
        return False

    # --- what the tab shows --------------------------------------------------------------

    def select(self, index: int) -> None:
        """Choose step ``index`` (0-based), as the Step dropdown does."""
        self._selected = int(index)
        r = self.routine
        if "step" in self.gui and r is not None and r.steps:
            self.gui["step"].value = r.lines()[min(max(int(index), 0), len(r.steps) - 1)]

    def selected(self) -> int:
        if "step" not in self.gui:  # no page (scripts, tests): the last select()
            return max(0, getattr(self, "_selected", 0))
        value = self.gui["step"].value
        try:
            return max(0, int(str(value).split(".")[0]) - 1)
        except ValueError:
            return 0

    def text(self) -> str:
        r = self.routine
        if r is None:
            return "*No routine yet.* Measure the part (alignment, features, constructions), then **Teach from this session**, or open a routine file."
        rows = []
        for i, line in enumerate(r.lines()):
            rows.append(f"- {line}")
            got = r.settings(i)
            if got:  # what the edits set, seen without saving the file
                rows.append(f"  <br><small>± {got['tolerance']} mm (size form location) · clearance Z {got['clearance']}"
                            f" · {got['nominal'] or 'no nominal'} · hits {got['hits']}</small>")
        return f"**{r.name}** · {len(r.steps)} steps\n\n" + "\n".join(rows)

    def fill_fields(self) -> None:
        """The edit fields show the selected step's present values (tolerance, clearance, nominal, hit plan,
        probe), so an edit starts from what the step has."""
        r = self.routine
        if r is None or not r.steps:
            return
        i = min(self.selected(), len(r.steps) - 1)
        got = r.settings(i)
        g = self.gui
        for key in ("tolerance", "nominal", "hits"):
            if key in got and g.get(key) is not None:
                g[key].value = got[key]
        if "clearance" in got and g.get("clearance") is not None and got["clearance"] != "nan":
            g["clearance"].value = float(got["clearance"])
        if g.get("probe") is not None:
            g["probe"].value = r.steps[i].get("probe") or ""

    def _show(self, select: int | None = None) -> None:
        self.ctx.set("routine:list", "content", self.text(), self.gui.get("list"))
        r = self.routine
        opts = tuple(r.lines()) if r is not None and r.steps else ("-",)
        step = self.gui.get("step")
        if step is not None:
            self.ctx.set("routine:step", "options", opts, step)
            if select is not None and r is not None and r.steps:
                step.value = opts[min(select, len(opts) - 1)]

    def build(self, gui: Any) -> None:
        """The step list, Teach, the Step dropdown, the Edit step and File folders."""
        g = self.gui
        g["list"] = gui.add_markdown(self.text())
        name = gui.add_text("Routine name", "", hint="default: the session's name")
        gui.add_button("Teach from this session").on_click(lambda _: self.teach(name.value))
        g["step"] = gui.add_dropdown("Step", ("-",), initial_value="-")
        g["step"].on_update(lambda _: self.fill_fields())
        with gui.add_folder("Edit step"):
            new_name = gui.add_text("New name", "")
            gui.add_button("Rename").on_click(lambda _: self.edit("rename", new_name.value))
            gui.add_button_group("Move / skip / delete", ("Up", "Down", "Skip", "Delete")).on_click(
                lambda e: self.edit(e.target.value.lower()))
            gui.add_button("Manual 3-2-1 hits on/off", hint="an align step: the operator's 6 hits first, or not"
                           ).on_click(lambda _: self.edit("manual"))
            tol = g["tolerance"] = gui.add_text("Tolerance ± mm (size form location)", "0.02 0.02 0.02")
            gui.add_button("Set tolerance").on_click(lambda _: self.edit("tolerance", tol.value))
            clear = g["clearance"] = gui.add_number("Clearance Z (part mm)", 60.0, step=1.0)
            gui.add_button("Set clearance").on_click(lambda _: self.edit("clearance", clear.value))
            nominal = g["nominal"] = gui.add_text("Nominal (part mm)", "", hint="e.g. radius=15.01  or  point=30 40 0")
            gui.add_button("Set nominal").on_click(lambda _: self.edit("nominal", nominal.value))
            hits = g["hits"] = gui.add_text("Hit plan (hit ids in order)", "",
                                            hint="e.g. 12 13 14 16: drop or reorder hits")
            gui.add_button("Set hit plan").on_click(lambda _: self.edit("hits", hits.value))
            hit = gui.add_text("Move hit (id X Y Z [I J K], part mm)", "", hint="e.g. 14 45 40 20")
            gui.add_button("Move hit").on_click(lambda _: self.edit("hit", hit.value))
            probe = g["probe"] = gui.add_text("Probe of the step", "", hint="a probe's name (Calibration tab); empty: any")
            gui.add_button("Set probe").on_click(lambda _: self.edit("probe", probe.value))
            new = gui.add_text("Insert after", "", hint="report NAME, feature NAME, align A B C [manual], "
                               "distance A B [NAME]")
            gui.add_button("Insert step").on_click(lambda _: self.insert_text(new.value))
        with gui.add_folder("File", expand_by_default=False):
            path = g["file"] = gui.add_text("Routine file", "", hint="name.toml (in the sessions folder) or a full path")
            gui.add_button_group("Routine file actions", ("Save", "Export DMIS", "Open")).on_click(
                lambda e: {"Save": self.save, "Export DMIS": self.export_dmis, "Open": self.open}[e.target.value](
                    path.value))
