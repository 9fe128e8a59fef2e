"""The Setup tab's "Part" sub-tab: load a part file (upload), place it, and on the simulator put the next part down elsewhere.

*Load part file* uploads a STEP or IGES file (read with its exact surfaces) or a mesh (STL, OBJ, PLY, 3MF, GLB);
it is kept in the ``parts`` folder beside the session journals and loaded through the command API's ``load_part``
at the pose in the fields: where the part's CAD origin sits in machine coordinates (X, Y, Z mm) and how far it is
turned about the machine's Z (degrees). *Place* loads the present part again at the pose in the fields. On the
simulator both put the same part on the table there (refused next to the reference sphere or off the table).

*Next part* (simulator only) moves and turns the simulated part by the amounts given, from where it lies now,
through the ``place_sim_part`` verb: the station's belief stays where it was, so a routine or a program can be
tried on a part put down differently (its alignment finds it).
"""

from __future__ import annotations

import math
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .context import PanelContext

ACCEPT = (".step", ".stp", ".iges", ".igs", ".stl", ".obj", ".ply", ".off", ".3mf", ".glb", ".gltf")


def pose_text(pose: Any) -> str:
    """X, Y, Z and the turn about Z of a part pose, as the fields and the verbs take them."""
    p = np.asarray(pose, float)
    return (f"X {p[0, 3]:.3f} Y {p[1, 3]:.3f} Z {p[2, 3]:.3f} mm, turned "
            f"{math.degrees(math.atan2(p[1, 0], p[0, 0])):.3f}° about Z")


def part_text(part: dict | None, simulator: dict | None) -> str:
    """Setup > Part's read-out from the ``part`` and ``simulator`` queries (JSON)."""
    if part is None:
        return "*No part loaded: load a part file (STEP, IGES or a mesh).*"
    lines = [f"**{part['name']}**", "", part["description"], "", f"station: part origin at {pose_text(part['pose'])}"]
    if simulator is not None:
        lines.append(f"\nsimulator: the part lies at {pose_text(simulator['part_pose'])}")
    return "\n".join(lines)


def _xyzrz(pose: Any) -> tuple[float, float, float, float]:
    p = np.asarray(pose, float)
    return float(p[0, 3]), float(p[1, 3]), float(p[2, 3]), math.degrees(math.atan2(p[1, 0], p[0, 0]))


class PartPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.path: Path | None = None  # the file of the part loaded here

    # --- what the tab shows ---------------------------------------------------------------

    def part(self) -> dict | None:
        """The API's ``part`` query: None without a part, else its name, pose, description and file."""
        return self.ctx.commands.invoke(self.ctx.who(), "part")

    def text(self, snapshot: dict[str, Any] | None = None) -> str:
        """The part's read-out: from the read-outs' subscription's ``snapshot`` (``part``, ``simulator``), or
        asked now."""
        if snapshot is None:
            snapshot = {"part": self.part(), "simulator": self.simulator()}
        return part_text(snapshot["part"], snapshot["simulator"])

    def show(self, snapshot: dict[str, Any] | None) -> None:
        """Draw the read-out from the read-outs' subscription."""
        if snapshot is not None:
            self.ctx.set("part:text", "content", part_text(snapshot["part"], snapshot["simulator"]),
                         self.gui.get("part"))

    def simulator(self) -> dict | None:
        """The API's ``simulator`` query: None on a real machine, else where the part truly lies."""
        return self.ctx.commands.invoke(self.ctx.who(), "simulator")

    # --- actions ------------------------------------------------------------------------------

    def pose_fields(self) -> list[float]:
        g = self.gui
        x, y, z = (float(v) for v in g["origin"].value)
        return [x, y, z, float(g["rz"].value)]

    def parts_dir(self) -> Path:
        where = self.ctx.commands.invoke(self.ctx.who(), "session_store")
        folder = (Path(tempfile.gettempdir()) / "cmm-parts" if where["url"] else Path(where["store"]).parent / "parts")
        folder.mkdir(parents=True, exist_ok=True)
        return folder

    def upload(self, name: str, content: bytes, pose: Any = None) -> Any:
        """An uploaded part file: kept in the parts folder and loaded at ``pose`` (default: the fields)."""
        ext = Path(name).suffix.lower()
        if ext not in ACCEPT:
            return self.ctx.error(f"'{name}' is not a part file the station reads ({', '.join(ACCEPT)})", "Load part")
        if not self.ctx.allowed("Load part"):
            return None
        safe = re.sub(r"[^\w.-]+", "_", Path(name).name) or f"part{ext}"
        target = self.parts_dir() / safe
        target.write_bytes(content)
        return self.load(target, pose)

    def load(self, path: Path, pose: Any = None) -> Any:
        pose = self.pose_fields() if pose is None and "origin" in self.gui else pose
        if self.ctx.do("Load part", "load_part", path=str(path), pose=pose) is None:
            return None
        part = self.part()  # what the station believes now, as every front end reads it
        self.path = Path(path)
        self.ctx.clear_pick()
        self.ctx.notify("Part", f"{part['name']} loaded at {pose_text(part['pose'])}")
        self._fields_from(part["pose"])
        return part

    def place(self) -> Any:
        """The present part again, at the pose in the fields (and on the simulator's table there)."""
        part = self.part()
        path = self.path or (None if part is None else part["path"])
        if path is None:
            return self.ctx.error("load a part file first (the sample part is placed by the simulator)", "Place part")
        return self.load(Path(path))

    def next_part(self, dx: float = 0.0, dy: float = 0.0, turn: float = 0.0) -> Any:
        """Simulator: the next part put down moved by (dx, dy) mm and turned by ``turn`` degrees about its origin,
        from where the present one lies."""
        sim = self.simulator()
        if sim is None:
            return self.ctx.error("there is no simulator: put the next part on the table by hand", "Next part")
        x, y, z, rz = _xyzrz(sim["part_pose"])
        pose = [x + dx, y + dy, z, rz + turn]
        done = self.ctx.do("Next part", "place_sim_part", pose=pose)
        if done is not None:
            self.ctx.notify("Next part", f"the part now lies at X {pose[0]:.3f} Y {pose[1]:.3f}, turned "
                            f"{pose[3]:.3f}° (align it before measuring)")
        return done

    def _fields_from(self, pose: Any) -> None:
        if "origin" in self.gui:
            x, y, z, rz = _xyzrz(pose)
            self.gui["origin"].value = (x, y, z)
            self.gui["rz"].value = rz

    # --- widgets ----------------------------------------------------------------------------------

    def build(self, gui: Any) -> None:
        g = self.gui
        part = self.part()
        x, y, z, rz = _xyzrz(part["pose"]) if part is not None else (190.0, 150.0, 0.0, 0.0)
        feed = self.ctx.readouts
        g["part"] = gui.add_markdown(self.text(None if feed is None else feed.snapshot()))
        if feed is not None:  # a delivery that came while the widget was made
            self.show(feed.snapshot())
        upload = gui.add_upload_button("Load part file", hint="STEP or IGES (exact surfaces), STL, OBJ, PLY, 3MF, GLB",
                                       mime_type=",".join(ACCEPT))
        upload.on_upload(lambda e: self.upload(e.target.value.name, e.target.value.content))
        g["origin"] = gui.add_vector3("Part origin X, Y, Z (mm)", (x, y, z), step=0.1,
                                      hint="where the part's CAD origin sits in machine coordinates")
        g["rz"] = gui.add_number("Turned about Z (°)", rz, step=0.5)
        gui.add_button("Place").on_click(lambda _: self.place())
        if self.simulator() is not None:
            gui.add_markdown("**Next part** (simulator): put the part down moved and turned from where it lies; "
                             "the station finds it by aligning.")
            g["move"] = gui.add_vector2("Move by X, Y (mm)", (5.0, -3.0), step=0.5)
            g["turn"] = gui.add_number("Turn by (°)", 2.0, step=0.5)
            gui.add_button("Next part").on_click(
                lambda _: self.next_part(*(float(v) for v in g["move"].value), float(g["turn"].value)))

    def refresh(self) -> None:
        if self.ctx.readouts is None:  # a tab with a page draws it from its subscription (show)
            self.ctx.set("part:text", "content", self.text(), self.gui.get("part"))
