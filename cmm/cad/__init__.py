"""CAD models with exact surfaces: STEP and IGES read with OpenCASCADE into plain data (see docs/cad.md).

``read_cad(path)`` -> :class:`CadModel` (faces with their exact surface, a triangulation tagged with faces);
``CadModel.mesh()`` is the trimesh the station draws, picks and measures against, carrying the model in
``mesh.metadata["cad"]`` so picks, nominals, hit plans, deviations and the simulator use the exact surfaces.
"""

from .model import FREE_FORM, CadError, CadFace, CadModel
from .reader import CAD_EXTENSIONS, read_cad


def cad_of(mesh) -> CadModel | None:
    """The CAD model behind a part mesh, or None for a plain triangle mesh."""
    meta = getattr(mesh, "metadata", None)
    cad = meta.get("cad") if isinstance(meta, dict) else None
    return cad if isinstance(cad, CadModel) else None


__all__ = ["CAD_EXTENSIONS", "FREE_FORM", "CadError", "CadFace", "CadModel", "cad_of", "read_cad"]
