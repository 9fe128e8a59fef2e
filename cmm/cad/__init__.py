"""CAD models with exact surfaces: STEP and IGES read with OpenCASCADE into plain data.

``read_cad(path)`` -> :class:`CadModel` (faces with their exact surface, a triangulation tagged with faces);
``CadModel.mesh()`` is the trimesh the station draws, picks and measures against, carrying the model in
``mesh.metadata["cad"]`` so picks, nominals, hit plans, deviations and the simulator use the exact surfaces.
"""

import numpy as np

from .model import FREE_FORM, CadError, CadFace, CadModel
from .reader import CAD_EXTENSIONS, read_cad


def cad_of(mesh) -> CadModel | None:
    """The CAD model behind a part mesh, or None for a plain triangle mesh."""
    meta = getattr(mesh, "metadata", None)
    cad = meta.get("cad") if isinstance(meta, dict) else None
    return cad if isinstance(cad, CadModel) else None


def cad_for_mesh(mesh) -> CadModel | None:
    """The CAD model behind a part mesh when the mesh's triangles are still the model's (not a moved copy)."""
    cad = cad_of(mesh)
    if cad is None or len(cad.tri_face) != len(mesh.faces) or len(cad.vertices) != len(mesh.vertices):
        return None
    v = mesh.vertices
    same = bool(np.array_equal(v[0], cad.vertices[0]) and np.array_equal(v[-1], cad.vertices[-1]))
    return cad if same else None


__all__ = ["cad_for_mesh", "CAD_EXTENSIONS", "FREE_FORM", "CadError", "CadFace", "CadModel", "cad_of", "read_cad"]
