"""The last pick in one tab's 3-D view: the marker with its normal arrow and the picked face highlighted.

A click on the part picks a CAD face; the region the station proposes a feature for (its triangles,
:class:`cmm.metrology.pick.FeatureSuggestion` ``face_ids``) is drawn once per pick as a translucent cyan
overlay in the part's pose, lifted a little along the region's normals so it is drawn over the part's
surface rather than fighting with it. :class:`PickDrawing` owns the nodes of the tab's last pick: the next
pick replaces them; Clear pick, a new part and the run of the plan remove them.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from .scene import SCALE, draw_pick, quat_from_matrix

HIGHLIGHT_COLOUR = (0, 220, 255)  # cyan: apart from the part's blue-grey, the yellow marker and the feature colours
HIGHLIGHT_OPACITY = 0.5
OFFSET_MM = 0.1  # the overlay's lift off the surface: far below what the eye sees, above the depth buffer's step


def face_region(mesh: Any, face_ids: Any, offset: float = OFFSET_MM) -> tuple[np.ndarray, np.ndarray]:
    """The triangles ``face_ids`` of ``mesh`` as a mesh of their own (part coordinates, mm): the vertices they use,
    each moved ``offset`` out along the region's area-weighted vertex normal, and the faces re-indexed to them."""
    ids = np.asarray(face_ids, np.int64).reshape(-1)
    faces = np.asarray(mesh.faces)[ids]
    used, inverse = np.unique(faces, return_inverse=True)
    inverse = inverse.reshape(-1)
    # normals from the region's own triangles: a vertex on the face's edge is not pulled towards its neighbour face
    weighted = np.asarray(mesh.face_normals)[ids] * np.asarray(mesh.area_faces)[ids][:, None]
    normals = np.zeros((len(used), 3))
    np.add.at(normals, inverse, np.repeat(weighted, 3, axis=0))
    normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
    vertices = np.asarray(mesh.vertices, float)[used] + offset * normals
    return vertices, inverse.reshape(-1, 3).astype(np.uint32)


class PickDrawing:
    """The nodes of one tab's last pick in its own scene (other tabs do not see them). The tab's refresher and
    its callbacks run in different threads: the drawing is changed under a lock."""

    def __init__(self, root: str = "/pick") -> None:
        self.root = root
        self.nodes: list[Any] = []
        self.face: Any = None  # the highlight's mesh node
        self.part: Any = None  # the part the pick was made on
        self.state: Any = None  # the fold of the session it was made in (a new part of a series starts another)
        self._lock = threading.RLock()

    def show(self, scene: Any, hit: Any, part: Any, face_ids: Any, state: Any = None) -> None:
        """Draw the marker at ``hit`` and the region ``face_ids`` of ``part`` (its mesh at its pose)."""
        region = None
        if part is not None and face_ids is not None and len(face_ids):
            region = face_region(part.mesh, face_ids)
        with self._lock:
            self.clear()
            self.nodes = list(draw_pick(scene, hit.point, hit.normal, self.root))
            if region is not None:
                pose = np.asarray(part.pose, float)
                self.face = scene.add_mesh_simple(
                    f"{self.root}/face", (region[0] * SCALE).astype(np.float32), region[1], color=HIGHLIGHT_COLOUR,
                    opacity=HIGHLIGHT_OPACITY, side="double", cast_shadow=False, receive_shadow=False,
                    wxyz=quat_from_matrix(pose[:3, :3]), position=tuple(pose[:3, 3] * SCALE))
                self.nodes.append(self.face)
            self.part, self.state = part, state

    def drop_stale(self, part: Any, state: Any) -> bool:
        """Remove a drawing made on another part than ``part`` or in another session than the one whose fold is
        ``state``; True when it was made on another part (its faces are not this part's)."""
        with self._lock:
            if not self.nodes or (self.part is part and self.state is state):
                return False
            other = self.part is not part
            self.clear()
            return other

    def clear(self) -> None:
        with self._lock:
            for node in self.nodes:
                try:
                    node.remove()
                except Exception:  # noqa: BLE001 - the tab may have closed
                    pass
            self.nodes = []
            self.face = None
            self.part = self.state = None
