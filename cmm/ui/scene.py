"""The 3D scene of the browser station: machine, part, live probe, hits and fitted features.

Units: the machine speaks millimetres; the scene is drawn in metres
(``SCALE``) so viser's default camera and clipping suit a 0.5 m machine.
Anything that needs micrometre resolution is drawn as float32 offsets in a
local frame (``/local``) near the part, or as node positions (float64 on the
wire), so a 1-count (2 um) move is never quantised the way a float16 point
cloud in machine coordinates would be.

One :class:`SceneView` draws into the shared ``server.scene`` (every client
sees the same scene); the live probe is pushed by :class:`ProbeUpdater`, a
throttled thread that reads the latest state (the API's state query) at a fixed rate
rather than forwarding every machine sample.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any, Callable

import numpy as np
import trimesh

from ..metrology.colour_map import DeviationMap, deviation_map
from ..metrology.colour_scale import DEFAULT_TOLERANCE, ColourScale
from ..metrology.transform import apply_points, invert
from .feature_drawing import Drawing, feature_drawing, ghost_drawing
from .model_view import model_of, reader

SCALE = 0.001  # scene units per millimetre (the scene is in metres)
PROBE_HZ = 50.0  # the probe updater's rate (it also samples the following-error plot)
# At most this many probe-node moves a second reach the scene: each one makes every open page draw its 3-D view
# again, which a station PC without a GPU (WebGL in software) pays for with CPU the station needs; 25 a second
# still moves smoothly beside the status bar's 20 Hz DRO.
PROBE_SCENE_HZ = 25.0
STYLUS_LENGTH = 40.0  # mm, drawn above the tip centre
ARROW_LENGTH = 4.0  # mm, approach arrows drawn before each hit



def deviation_colour(deviation: float, tolerance: float = DEFAULT_TOLERANCE) -> tuple[int, int, int]:
    """The colour of a deviation on the scale the report uses too (:mod:`cmm.metrology.colour_scale`)."""
    return ColourScale(tolerance).colour(deviation)


def quat_from_matrix(R: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> (w, x, y, z)."""
    q = trimesh.transformations.quaternion_from_matrix(np.asarray(R, float))
    return tuple(float(v) for v in q)  # type: ignore[return-value]


def _frame_for_axis(direction: np.ndarray) -> np.ndarray:
    """A 4x4 rotation taking +Z to ``direction``."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    return trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d)


FEATURE_COLOURS = {"plane": (240, 180, 40), "circle": (250, 120, 20), "sphere": (170, 90, 230),
                   "cylinder": (40, 180, 200), "cone": (230, 90, 160), "point": (250, 250, 250),
                   "line": (250, 250, 250)}


# camera distance in part radii at start (viser's 75 degree view): at 1280 x 800 the part's bounding sphere is
# about 400 px across, between the view's centre and the side panel; 3.5 left it a third of that free room
PART_FILL_DISTANCE = 2.6

class SceneView:
    """Draws the station into a viser scene (``server.scene``) from the command API's queries (``api``: the API or
    a query function, :func:`cmm.ui.model_view.reader`): the configuration, the state, the model."""

    def __init__(self, scene: Any, api: Any, *, tolerance: float = DEFAULT_TOLERANCE,
                 on_feature_click: Callable[[int, Any], None] | None = None) -> None:
        self.scene = scene
        self.query = reader(api)
        self.scale = ColourScale(tolerance)
        self.on_feature_click = on_feature_click
        self.origin_mm = np.zeros(3)  # the local frame's origin (near the part), machine mm
        self.probe = None
        self._feature_nodes: dict[int, FeatureNode] = {}
        self.hidden_features: set[int] = set()  # features the operator hid (Features tab, Show)
        self.hidden_kinds: set[str] = set()  # feature kinds the operator hid
        self.selected: int | None = None
        self._lock = threading.Lock()
        self._part_node: Any = None
        self._map_node: Any = None
        self.map_on = False  # the deviation colour map on the part (shared: every client sees it)
        self.map: DeviationMap | None = None  # the map last drawn
        self.map_error = ""
        self._map_cond = threading.Condition()
        self._map_pending: tuple[dict[int, float] | None] | None = None
        self._map_thread: threading.Thread | None = None

    # --- coordinates --------------------------------------------------------

    def local(self, points_mm: Any) -> np.ndarray:
        """Machine mm -> float32 metres in the local frame near the part."""
        return ((np.asarray(points_mm, float) - self.origin_mm) * SCALE).astype(np.float32)

    @staticmethod
    def to_mm(scene_xyz: Any) -> np.ndarray:
        """Scene (world, metres) -> machine mm; for pick rays."""
        return np.asarray(scene_xyz, float) / SCALE

    # --- building -------------------------------------------------------------

    def fit_portrait(self, camera: Any) -> bool:
        """A view narrower than it is high (a tablet or phone upright): viser's field of view is vertical, so the
        start distance that fills a landscape view would crop the part at the sides. Backs ``camera`` (a client's,
        still where :meth:`frame_camera` put it) off along its line of sight by 1 / aspect, so the part fills the
        view's width as it fills a landscape view's height. Returns whether it moved the camera."""
        aspect = float(getattr(camera, "aspect", 1.0) or 1.0)
        if not 0.0 < aspect < 1.0:
            return False
        look = np.asarray(camera.look_at, float)
        camera.position = tuple(float(v) for v in look + (np.asarray(camera.position, float) - look) / aspect)
        return True

    def frame_camera(self, camera: Any) -> None:
        """Start new clients (viser's initial camera) from the front right looking at the part, close enough that it
        fills the view beside the panel (the envelope without a part); a portrait view is fitted when the client
        reports its size (:meth:`fit_portrait`)."""
        cfg = self.query("machine_config")
        lo = np.array([a.min for a in cfg.axes])
        hi = np.array([a.max for a in cfg.axes])
        part = self.query("part_frame").part
        if part is not None and part.mesh is not None:
            corners = np.array([[x, y, z] for x in part.mesh.bounds[:, 0] for y in part.mesh.bounds[:, 1]
                                for z in part.mesh.bounds[:, 2]])
            pose = np.asarray(part.pose, float)
            world = corners @ pose[:3, :3].T + pose[:3, 3]
            centre = world.mean(axis=0) * SCALE
            radius = float(np.max(np.linalg.norm(world * SCALE - centre, axis=1)))
            direction = np.array([1.1, -1.5, 1.0]) / np.linalg.norm([1.1, -1.5, 1.0])
            camera.look_at = tuple(float(v) for v in centre)
            camera.position = tuple(float(v) for v in centre + direction * radius * PART_FILL_DISTANCE)
            return
        centre = (lo + hi) / 2 * SCALE
        size = float(np.max(hi - lo)) * SCALE
        camera.look_at = (float(centre[0]), float(centre[1]), float(lo[2] * SCALE))
        camera.position = tuple(float(v) for v in centre + np.array([1.1, -1.5, 1.0]) * size)

    def build(self) -> None:
        cfg = self.query("machine_config")
        lo = np.array([a.min for a in cfg.axes])
        hi = np.array([a.max for a in cfg.axes])
        self.scene.set_up_direction("+z")
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
        self.scene.add_line_segments("/machine/envelope", (corners[np.array(edges)] * SCALE).astype(np.float32),
                                     colors=(120, 120, 120), thickness=1.5, thickness_units="screen")
        table_z = lo[2] - 5.0
        self.scene.add_box("/machine/table", color=(70, 70, 78), dimensions=(
            (hi[0] - lo[0] + 100) * SCALE, (hi[1] - lo[1] + 100) * SCALE, 10 * SCALE),
            position=(float((lo[0] + hi[0]) / 2 * SCALE), float((lo[1] + hi[1]) / 2 * SCALE), table_z * SCALE),
            receive_shadow=True, cast_shadow=False)
        self.draw_part()
        here = self.query("state").position  # the control core's last sample
        start = here if here is not None else (lo + hi) / 2
        self.probe = self.scene.add_frame("/probe", show_axes=False, position=tuple(np.asarray(start) * SCALE))
        r = float(self.query("probe_settings").tip_radius)
        self.scene.add_icosphere("/probe/tip", radius=r * SCALE, color=(230, 30, 30), subdivisions=3)
        stylus = trimesh.creation.cylinder(radius=max(r * 0.4, 0.2), segment=[[0, 0, r * 0.8], [0, 0, STYLUS_LENGTH]],
                                           sections=24)
        self.scene.add_mesh_simple("/probe/stylus", (stylus.vertices * SCALE).astype(np.float32), stylus.faces,
                                   color=(200, 200, 210))
        body = trimesh.creation.cylinder(radius=8.0, segment=[[0, 0, STYLUS_LENGTH], [0, 0, STYLUS_LENGTH + 30]])
        self.scene.add_mesh_simple("/probe/body", (body.vertices * SCALE).astype(np.float32), body.faces,
                                   color=(60, 60, 70))
        self.draw_hits()
        self.draw_features()

    def draw_part(self) -> None:
        part = self.query("part_frame").part
        if part is None:
            self.scene.add_frame("/local", show_axes=False)
            return
        pose = np.asarray(part.pose, float)
        self.origin_mm = np.round(pose[:3, 3])
        self.scene.add_frame("/local", show_axes=False, position=tuple(self.origin_mm * SCALE))
        self._part_node = self.scene.add_mesh_simple(
            "/part", (np.asarray(part.mesh.vertices) * SCALE).astype(np.float32),
            np.asarray(part.mesh.faces, np.uint32), color=(96, 128, 170),  # darker: the part reads against the table
            wxyz=quat_from_matrix(pose[:3, :3]), position=tuple(pose[:3, 3] * SCALE),
            flat_shading=False, opacity=0.85, visible=not (self.map_on and self._map_node is not None))

    # --- deviation colour map ---------------------------------------------------

    def show_colour_map(self, on: bool, deviations: dict[int, float] | None = None) -> DeviationMap | None:
        """Turn the colour map on the part on or off (in every client's scene)."""
        self.map_on = bool(on)
        return self.draw_colour_map(deviations)

    def request_colour_map(self, deviations: dict[int, float] | None = None) -> None:
        """Redraw the map in a background thread (the latest request wins): a new hit during a measurement
        must not hold up the refresher's 20 Hz DRO while the map (0.2-1 s) is computed."""
        with self._map_cond:
            self._map_pending = (deviations,)
            if self._map_thread is None:
                self._map_thread = threading.Thread(target=self._map_loop, name="colour-map", daemon=True)
                self._map_thread.start()
            self._map_cond.notify()

    def _map_loop(self) -> None:
        while True:
            with self._map_cond:
                if self._map_pending is None:
                    self._map_cond.wait(timeout=5.0)
                if self._map_pending is None:  # idle: the thread ends (the next request starts one)
                    self._map_thread = None
                    return
                (deviations,) = self._map_pending
                self._map_pending = None
            try:
                self.draw_colour_map(deviations)
            except Exception:  # noqa: BLE001 - a closing server; the next request draws again
                pass

    def draw_colour_map(self, deviations: dict[int, float] | None = None) -> DeviationMap | None:
        """(Re)draw the colour map from the hits' deviations (see :mod:`cmm.metrology.colour_map`): the part
        mesh painted by the interpolated deviation, grey beyond the scale's reach; the plain part while off."""
        view = model_of(self.query)
        part, hits = view.part, view.hits
        if self.map_on and part is not None:
            if deviations is None:
                try:
                    deviations = self.query("hit_deviations")
                except Exception:  # noqa: BLE001 - no deviations: an all-grey map
                    deviations = {}
            pose = np.asarray(part.pose, float)
            ids = sorted(hits)
            pts = np.array([hits[h].point for h in ids], float).reshape(-1, 3)
            local = apply_points(invert(pose), pts)  # machine -> part coordinates (the alignment in force)
            try:
                dmap = deviation_map(part.mesh, local, [deviations.get(h, math.nan) for h in ids], self.scale)
                self.map_error = ""
            except Exception as exc:  # noqa: BLE001 - a map that cannot be made must not break the scene
                dmap, self.map_error = None, f"no colour map: {exc}"
        else:
            dmap = None
        with self._lock:
            self.map = dmap
            if dmap is None:
                if self._map_node is not None:
                    self._map_node.remove()
                    self._map_node = None
                if self._part_node is not None:
                    self._part_node.visible = True
                return None
            self._map_node = self.scene.add_mesh_trimesh(
                "/part_map", dmap.coloured_mesh(), scale=SCALE, wxyz=quat_from_matrix(pose[:3, :3]),
                position=tuple(pose[:3, 3] * SCALE), cast_shadow=False)
            if self._part_node is not None:
                self._part_node.visible = False
            return dmap

    # --- live probe -------------------------------------------------------------

    def set_probe(self, position_mm: Any) -> None:
        """Move the probe node (float64 position on the wire: no quantisation)."""
        if self.probe is not None:
            self.probe.position = tuple(float(v) * SCALE for v in position_mm)

    # --- hits ---------------------------------------------------------------------

    @property
    def tolerance(self) -> float:
        return self.scale.tolerance

    def set_scale(self, scale: ColourScale) -> None:
        """Change the colour scale (tolerance bands, max-deviation cut-off, map reach); every client sees it."""
        self.scale = scale

    def hit_colours(self, ids: list[int], deviations: dict[int, float]) -> np.ndarray:
        return self.scale.colours(np.array([deviations.get(h, float("nan")) for h in ids], dtype=np.float64))

    def draw_hits(self, deviations: dict[int, float] | None = None) -> None:
        hits = model_of(self.query).hits
        with self._lock:
            if not hits:
                self.scene.add_frame("/local/hits", show_axes=False)  # replaces the previous hits with nothing
                return
            ids = sorted(hits)
            if deviations is None:
                try:
                    deviations = self.query("hit_deviations")
                except Exception:  # noqa: BLE001 - colour is a help, not a requirement
                    deviations = {}
            points = np.array([hits[h].point for h in ids])
            approach = np.array([hits[h].approach for h in ids])
            colours = self.hit_colours(ids, deviations)
            self.scene.add_frame("/local/hits", show_axes=False)
            sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.35 * SCALE)
            self.scene.add_batched_meshes_simple(
                "/local/hits/points", sphere.vertices.astype(np.float32), sphere.faces,
                batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(ids), 1)), batched_positions=self.local(points),
                batched_colors=colours, lod="off")
            segs = np.stack([self.local(points - ARROW_LENGTH * approach), self.local(points)], axis=1)
            self.scene.add_line_segments("/local/hits/approach", segs,
                                         np.repeat(colours[:, None, :], 2, axis=1), thickness=2.0,
                                         thickness_units="screen")

    # --- features -----------------------------------------------------------------

    def draw_features(self) -> None:
        """Draw each feature as it was measured (:mod:`cmm.ui.feature_drawing`): a translucent patch or a faint
        surface with thin outlines, its check alternative as a dashed ghost; a feature redraws when it is refit."""
        view = model_of(self.query)
        features, hits = view.features, view.hit_or_deleted()
        with self._lock:
            for fid in list(self._feature_nodes):
                if fid not in features:
                    self._feature_nodes.pop(fid).remove()
            for fid, feature in features.items():
                key = (feature.kind, id(feature.result), tuple(feature.hit_ids))
                node = self._feature_nodes.get(fid)
                if node is not None and node.key == key:
                    continue
                if node is not None:
                    node.remove()
                    self._feature_nodes.pop(fid)
                pts = np.array([hits[h].point for h in feature.hit_ids if h in hits]).reshape(-1, 3)
                drawing = feature_drawing(feature.kind, feature.result.geometry(), pts)
                if drawing is None:
                    continue
                alternative = getattr(feature.result, "alternative", None)
                ghost = None if alternative is None else ghost_drawing(feature.kind, alternative.geometry(), pts)
                self._feature_nodes[fid] = FeatureNode(self, fid, feature.kind, key, drawing, ghost)
            self._apply_visibility()
            self._highlight()

    def select_feature(self, fid: int | None) -> None:
        with self._lock:
            self.selected = fid
            self._highlight()

    # --- what is shown: per feature and per kind (shared by every tab, kept while the station serves) --------

    def feature_shown(self, fid: int, kind: str | None = None) -> bool:
        """Whether the feature ``fid`` (of ``kind``) is drawn: neither it nor its kind is hidden."""
        return fid not in self.hidden_features and (kind is None or kind not in self.hidden_kinds)

    def show_feature(self, fid: int, shown: bool) -> None:
        (self.hidden_features.discard if shown else self.hidden_features.add)(int(fid))
        with self._lock:
            self._apply_visibility()

    def show_kind(self, kind: str, shown: bool) -> None:
        (self.hidden_kinds.discard if shown else self.hidden_kinds.add)(kind)
        with self._lock:
            self._apply_visibility()

    def show_all(self) -> None:
        self.hidden_features.clear()
        self.hidden_kinds.clear()
        with self._lock:
            self._apply_visibility()

    def _apply_visibility(self) -> None:
        for fid, node in self._feature_nodes.items():
            node.set_visible(self.feature_shown(fid, node.kind))

    def _highlight(self) -> None:
        for fid, node in self._feature_nodes.items():
            node.set_selected(fid == self.selected)
        # the selected feature's hits: larger yellow spheres around them
        view = model_of(self.query)
        feature = view.features.get(self.selected) if self.selected is not None else None
        hits = view.hits
        pts = [hits[h].point for h in (feature.hit_ids if feature is not None else []) if h in hits]
        if not pts:
            self.scene.add_frame("/local/selection", show_axes=False)
            return
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.9 * SCALE)
        self.scene.add_batched_meshes_simple(
            "/local/selection", sphere.vertices.astype(np.float32), sphere.faces,
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(pts), 1)), batched_positions=self.local(np.array(pts)),
            batched_colors=np.tile(np.array([[255, 230, 0]], np.uint8), (len(pts), 1)), lod="off", opacity=0.6)


class FeatureNode:
    """One feature's nodes under ``/local/features/f<id>``: its ``patch`` (translucent, takes the clicks),
    its ``outline`` (thin lines, thicker when selected) and its ``ghost`` (the dashed check alternative)."""

    THIN, THICK = 1.5, 3.5  # px: outline widths, selected thicker
    GHOST_COLOUR = (150, 150, 160)

    def __init__(self, view: SceneView, fid: int, kind: str, key: Any, drawing: Drawing,
                 ghost: np.ndarray | None) -> None:
        self.view, self.fid, self.kind, self.key = view, fid, kind, key
        self.name = f"/local/features/f{fid}"
        self.colour = FEATURE_COLOURS.get(kind, (200, 200, 200))
        self.opacity = drawing.opacity
        self.lines = drawing.lines
        self.selected = False
        scene = view.scene
        self.frame = scene.add_frame(self.name, show_axes=False)
        self.patch = None
        if drawing.patch is not None:
            self.patch = scene.add_mesh_simple(
                f"{self.name}/patch", view.local(drawing.patch.vertices), np.asarray(drawing.patch.faces, np.uint32),
                color=self.colour, opacity=self.opacity, side="double", cast_shadow=False, receive_shadow=False)
            if view.on_feature_click is not None:
                self.patch.on_click(lambda event: view.on_feature_click(fid, event.client))  # type: ignore[misc]
        self.outline = self._outline(self.THIN)
        self.ghost = None
        if ghost is not None and len(ghost):
            self.ghost = scene.add_line_segments(f"{self.name}/ghost", view.local(ghost), self.GHOST_COLOUR,
                                                 thickness=1.5, thickness_units="screen")

    def _outline(self, thickness: float) -> Any:
        if not len(self.lines):
            return None
        return self.view.scene.add_line_segments(f"{self.name}/outline", self.view.local(self.lines), self.colour,
                                                 thickness=thickness, thickness_units="screen")

    @property
    def visible(self) -> bool:
        return bool(self.frame.visible)

    def set_visible(self, shown: bool) -> None:
        if bool(self.frame.visible) != shown:
            self.frame.visible = shown

    def set_selected(self, selected: bool) -> None:
        if selected == self.selected:
            return
        self.selected = selected
        if self.patch is not None:
            self.patch.opacity = min(self.opacity * 2.2, 0.6) if selected else self.opacity
        if self.outline is not None:
            self.outline = self._outline(self.THICK if selected else self.THIN)  # replaces the node of that name

    def remove(self) -> None:
        self.frame.remove()  # and everything under it


class ReplayView:
    """A recorded session's state (``cmm.journal.state.SessionState``) drawn into one client's scene.

    The live scene (:class:`SceneView`, shared by every tab) is left alone: a
    replay is what one browser looks at, so it goes to ``client.scene`` under
    ``/replay`` (part in amber, hits coloured by deviation, features).
    While it is shown, the live part, hits and features are hidden in that
    tab only: an invisible client-scoped node of the same name shadows the
    shared one (viser shows a client's variant of a name over the broadcast
    one). ``clear()`` removes both again (back to live).
    """

    LIVE_NODES = ("/local", "/part", "/part_map")

    PART_COLOUR = (205, 170, 90)

    def __init__(self, scene: Any, tolerance: float | ColourScale = DEFAULT_TOLERANCE, root: str = "/replay") -> None:
        self.scene = scene
        self.scale = tolerance if isinstance(tolerance, ColourScale) else ColourScale(tolerance)
        self.root = root
        self.origin_mm = np.zeros(3)
        self._part: Any = None
        self._part_key: Any = None
        self._nodes: list[Any] = []
        self._hidden: list[Any] = []
        self._lock = threading.Lock()

    def local(self, points_mm: Any) -> np.ndarray:
        return ((np.asarray(points_mm, float) - self.origin_mm) * SCALE).astype(np.float32)

    def _hide_live(self) -> None:
        if not self._hidden:
            self._hidden = [self.scene.add_frame(name, show_axes=False, visible=False) for name in self.LIVE_NODES]

    def show(self, state: Any, mesh: Any = None, deviations: dict[int, float] | None = None) -> None:
        """Draw ``state`` (hits, features, part at its pose); replaces the previous replay drawing."""
        deviations = deviations or {}
        pose = state.pose_array
        with self._lock:
            self._hide_live()
            key = (id(mesh), state.part_pose)
            if key != self._part_key:
                if self._part is not None:
                    self._part.remove()
                    self._part = None
                if pose is not None:
                    self.origin_mm = np.round(pose[:3, 3])
                elif state.hits:
                    self.origin_mm = np.round(np.mean([h.point for h in state.hits.values()], axis=0))
                self._part = self.scene.add_frame(self.root, show_axes=False, position=tuple(self.origin_mm * SCALE))
                if mesh is not None and pose is not None:
                    self.scene.add_mesh_simple(
                        f"{self.root}/part", (np.asarray(mesh.vertices) * SCALE).astype(np.float32),
                        np.asarray(mesh.faces, np.uint32), color=self.PART_COLOUR,
                        wxyz=quat_from_matrix(pose[:3, :3]), position=tuple((pose[:3, 3] - self.origin_mm) * SCALE),
                        flat_shading=False, opacity=0.8)
                self._part_key = key
            for node in self._nodes:
                node.remove()
            self._nodes = []
            ids = list(state.hits)
            if ids:
                points = np.array([state.hits[h].point for h in ids], float)
                approach = np.array([state.hits[h].approach for h in ids], float)
                colours = self.scale.colours(np.array([deviations.get(h, float("nan")) for h in ids], dtype=np.float64))
                sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.35 * SCALE)
                self._nodes.append(self.scene.add_batched_meshes_simple(
                    f"{self.root}/hits", sphere.vertices.astype(np.float32), sphere.faces,
                    batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(ids), 1)), batched_positions=self.local(points),
                    batched_colors=colours, lod="off"))
                segs = np.stack([self.local(points - ARROW_LENGTH * approach), self.local(points)], axis=1)
                self._nodes.append(self.scene.add_line_segments(
                    f"{self.root}/approach", segs, np.repeat(colours[:, None, :], 2, axis=1), thickness=2.0,
                    thickness_units="screen"))
            all_hits = {**state.deleted_hits, **state.hits}
            for fid, f in state.features.items():
                pts = np.array([all_hits[h].point for h in f.hit_ids if h in all_hits]).reshape(-1, 3)
                try:
                    drawing = feature_drawing(f.kind, f.fit, pts)
                except (KeyError, ValueError, TypeError):  # an incomplete record: skip its drawing
                    drawing = None
                if drawing is None:
                    continue
                colour = FEATURE_COLOURS.get(f.kind, (200, 200, 200))
                if drawing.patch is not None:
                    self._nodes.append(self.scene.add_mesh_simple(
                        f"{self.root}/f{fid}", self.local(drawing.patch.vertices),
                        np.asarray(drawing.patch.faces, np.uint32), color=colour, opacity=drawing.opacity,
                        side="double", cast_shadow=False))
                if len(drawing.lines):
                    self._nodes.append(self.scene.add_line_segments(
                        f"{self.root}/f{fid}_outline", self.local(drawing.lines), colour, thickness=1.5,
                        thickness_units="screen"))

    def clear(self) -> None:
        with self._lock:
            for node in self._nodes:
                node.remove()
            self._nodes = []
            if self._part is not None:
                self._part.remove()  # the frame and the part mesh under it
            self._part = None
            self._part_key = None
            for node in self._hidden:
                node.remove()  # the shared live nodes show again
            self._hidden = []


def draw_pick(scene: Any, point_mm: Any, normal_mm: Any, name: str = "/pick") -> list[Any]:
    """A marker and a normal arrow at a picked point (client scene, absolute position); returns their nodes."""
    p = np.asarray(point_mm, float)
    n = np.asarray(normal_mm, float)
    n = n / np.linalg.norm(n)
    point = scene.add_icosphere(f"{name}/point", radius=0.8 * SCALE, color=(255, 230, 0), position=tuple(p * SCALE))
    seg = np.array([[[0, 0, 0], n * 12.0 * SCALE]], dtype=np.float32)
    normal = scene.add_line_segments(f"{name}/normal", seg, (255, 230, 0), thickness=3.0, thickness_units="screen",
                                     position=tuple(p * SCALE))
    head = trimesh.creation.cone(radius=1.2, height=3.0, sections=16)
    T = _frame_for_axis(n)
    T[:3, 3] = n * 12.0
    head.apply_transform(T)
    arrow = scene.add_mesh_simple(f"{name}/head", (head.vertices * SCALE).astype(np.float32), head.faces,
                                  color=(255, 230, 0), position=tuple(p * SCALE))
    return [point, normal, arrow]


PREVIEW_COLOURS = {"rapid": (255, 140, 0), "approach": (255, 60, 200), "retract": (0, 200, 230)}


def draw_cycles(scene: Any, cycles: list[Any], root: str = "/preview") -> dict[str, Any]:
    """Draw probing cycles (:class:`cmm.machine.probing.CyclePath`, machine mm) under ``root``: the rapid legs over
    the clearance height, each approach and search to its contact, each retract, and the contacts. Returns the
    nodes by part (``rapid``, ``approach``, ``retract``, ``hits``)."""
    rapid, approach, retract = [], [], []
    for c in cycles:
        line = np.array([c.start, *c.rapid], float)
        rapid += list(np.stack([line[:-1], line[1:]], axis=1))
        approach.append([c.pre, c.contact])
        retract.append([c.contact, c.retract])
    nodes = {}
    for key, segs, width in (("rapid", rapid, 2.0), ("approach", approach, 3.5), ("retract", retract, 2.0)):
        if segs:
            nodes[key] = scene.add_line_segments(f"{root}/{key}", (np.array(segs, float) * SCALE).astype(np.float32),
                                                 PREVIEW_COLOURS[key], thickness=width, thickness_units="screen")
    contacts = np.array([c.contact for c in cycles], float) * SCALE
    nodes["hits"] = scene.add_point_cloud(f"{root}/hits", contacts.astype(np.float32),
                                          colors=PREVIEW_COLOURS["approach"], point_size=0.003)
    return nodes


class ProbeUpdater:
    """Push the probe position to the scene from the latest state; ``extra(state)`` on every tick (``hz``).

    It is throttled: the machine samples ~100 times a second per axis set,
    but the scene gets at most ``scene_hz`` updates, and only when the probe
    moved (a move held back by the throttle goes out on a later tick, so the
    probe's last position always reaches the scene).
    """

    def __init__(self, api: Any, view: SceneView, hz: float = PROBE_HZ,
                 extra: Callable[[Any], None] | None = None, scene_hz: float = PROBE_SCENE_HZ) -> None:
        self.query = reader(api)  # the command API's state query: the control core's last sample
        self.view = view
        self.period = 1.0 / hz
        self.scene_period = 1.0 / scene_hz
        self.extra = extra
        self.pushes = 0
        self.ticks = 0
        self._last: np.ndarray | None = None
        self._pushed_at = -math.inf  # time.monotonic() of the last push
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="scene-probe", daemon=True)

    def start(self) -> "ProbeUpdater":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)

    def step(self) -> bool:
        """One tick: push the probe if it moved. Returns True when it pushed."""
        state = self.query("state").machine  # the control core's last sample
        self.ticks += 1
        if state is None:
            return False
        pos = state.position
        pushed = False
        now = time.monotonic()
        # 1 ms of slack: a tick a hair early on the updater's clock does not wait a whole period more
        if (self._last is None or np.any(pos != self._last)) and now - self._pushed_at >= self.scene_period - 0.001:
            self.view.set_probe(pos)
            self._last = pos
            self._pushed_at = now
            self.pushes += 1
            pushed = True
        if self.extra is not None:
            self.extra(state)
        return pushed

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                self.step()
            except Exception:  # noqa: BLE001 - a disconnected client must not end the live view
                pass
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t = time.monotonic()
                delay = 0
            self._stop.wait(delay)
