"""Sample test parts with known nominal features (part coordinates, mm).

``sample_part()`` is a machinable 120 x 80 x 40 mm block; the origin is the
block corner on the table, z = 0 is the table plane and +z points up:

    top_plane  plane     z = 40, normal +z
    front      plane     y = 0, normal -y      (3-2-1 secondary)
    left       plane     x = 0, normal -x      (3-2-1 tertiary)
    bore       cylinder  through bore D 30, axis (30, 40, z), z 0..40
    boss       cylinder  D 20, axis (70, 22, z), 15 high (z 40..55)
    boss_top   plane     z = 55
    dome       sphere    D 20, centre (70, 58, 39): a 9 mm high cap (top z 49)
    cone       cone      conical boss, axis (100, 40, z), radius 12 at z 40,
                         6 at z 52 (flat top), half angle atan(1/2) = 26.565 deg,
                         apex (100, 40, 64)
    cone_top   plane     z = 52

``reference_sphere()`` is a 25 mm calibration sphere on a vertical stem.

Chordal error (largest distance of a facet from the true surface):
cylinders and cones use 256 sections (1.1 um at R 15, 0.75 um at R 10);
spheres are icospheres with 5 subdivisions (2.9 um at R 10, 3.6 um at
R 12.5). The sample part has 13,062 faces, the reference sphere 21,212. Vertices lie on the true surfaces to ~1e-14 mm: the
booleans run in double precision (manifold3d Mesh64; trimesh's own manifold
wrapper rounds to float32).

Both builders are cached; every call returns fresh copies, so callers may
move or edit the result freely.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import trimesh

from cmm.metrology.pick import NominalFeature

SECTIONS = 256
SPHERE_SUBDIVISIONS = 5


def sample_part() -> tuple[trimesh.Trimesh, dict[str, NominalFeature]]:
    """The sample test part mesh and its nominal features (part coordinates)."""
    mesh, features = _sample_part_cached()
    return mesh.copy(), {name: f.copy() for name, f in features.items()}


def reference_sphere(
    diameter: float = 25.0, stem_diameter: float = 8.0, stem_length: float = 40.0
) -> tuple[trimesh.Trimesh, dict[str, NominalFeature]]:
    """A calibration sphere on a vertical stem standing on the table (z = 0).

    The sphere centre is at (0, 0, stem_length + diameter / 2).
    """
    mesh, features = _reference_sphere_cached(float(diameter), float(stem_diameter), float(stem_length))
    return mesh.copy(), {name: f.copy() for name, f in features.items()}


@functools.lru_cache(maxsize=2)
def _sample_part_cached() -> tuple[trimesh.Trimesh, dict[str, NominalFeature]]:
    block = trimesh.creation.box(bounds=((0.0, 0.0, 0.0), (120.0, 80.0, 40.0)))
    bore = _z_cylinder((30.0, 40.0), 15.0, -1.0, 41.0)
    boss = _z_cylinder((70.0, 22.0), 10.0, 39.0, 55.0)  # starts inside the block: no coplanar faces
    dome = _sphere((70.0, 58.0, 39.0), 10.0)  # centre below the top face: no coplanar ring
    # frustum: radius 12 at z 40 growing 0.5 mm per mm downwards, extended 1 mm into the block
    cone = _frustum((100.0, 40.0), [(12.5, 39.0), (6.0, 52.0)])
    mesh = _boolean(_boolean(block, [boss, dome, cone], "union"), [bore], "difference")

    z = np.array([0.0, 0.0, 1.0])
    features = {
        "top_plane": NominalFeature("plane", {"point": [60.0, 40.0, 40.0], "normal": z}),
        "front": NominalFeature("plane", {"point": [60.0, 0.0, 20.0], "normal": [0.0, -1.0, 0.0]}),
        "left": NominalFeature("plane", {"point": [0.0, 40.0, 20.0], "normal": [-1.0, 0.0, 0.0]}),
        "bore": NominalFeature(
            "cylinder", {"point": [30.0, 40.0, 0.0], "direction": z, "radius": 15.0, "length": 40.0, "bore": True}
        ),
        "boss": NominalFeature(
            "cylinder", {"point": [70.0, 22.0, 40.0], "direction": z, "radius": 10.0, "length": 15.0, "bore": False}
        ),
        "boss_top": NominalFeature("plane", {"point": [70.0, 22.0, 55.0], "normal": z}),
        "dome": NominalFeature("sphere", {"center": [70.0, 58.0, 39.0], "radius": 10.0, "bore": False}),
        "cone": NominalFeature(
            "cone",
            {"apex": [100.0, 40.0, 64.0], "direction": -z, "half_angle": math.atan(0.5), "bore": False},
        ),
        "cone_top": NominalFeature("plane", {"point": [100.0, 40.0, 52.0], "normal": z}),
    }
    return mesh, features


@functools.lru_cache(maxsize=4)
def _reference_sphere_cached(
    diameter: float, stem_diameter: float, stem_length: float
) -> tuple[trimesh.Trimesh, dict[str, NominalFeature]]:
    r = diameter / 2.0
    if not 0.0 < stem_diameter < diameter or stem_length <= 0.0:
        raise ValueError("the stem must be thinner than the sphere and have a positive length")
    center = np.array([0.0, 0.0, stem_length + r])
    stem = _z_cylinder((0.0, 0.0), stem_diameter / 2.0, 0.0, float(center[2]))
    mesh = _boolean(_sphere(center, r), [stem], "union")
    features = {"sphere": NominalFeature("sphere", {"center": center, "radius": r, "bore": False})}
    return mesh, features


def _z_cylinder(xy: tuple[float, float], radius: float, z0: float, z1: float) -> trimesh.Trimesh:
    cyl = trimesh.creation.cylinder(radius=radius, height=z1 - z0, sections=SECTIONS)
    cyl.apply_translation((xy[0], xy[1], 0.5 * (z0 + z1)))
    return cyl


def _sphere(center, radius: float) -> trimesh.Trimesh:
    s = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=radius)
    s.apply_translation(center)
    return s


def _frustum(xy: tuple[float, float], profile: list[tuple[float, float]]) -> trimesh.Trimesh:
    """Solid of revolution about a vertical axis from (radius, z) profile points."""
    (r0, z0), (r1, z1) = profile
    line = np.array([[0.0, z0], [r0, z0], [r1, z1], [0.0, z1]])
    solid = trimesh.creation.revolve(line, sections=SECTIONS)
    solid.apply_translation((xy[0], xy[1], 0.0))
    if solid.volume < 0:
        solid.invert()
    return solid


def _boolean(base: trimesh.Trimesh, others: list[trimesh.Trimesh], operation: str) -> trimesh.Trimesh:
    """Union/difference in double precision with manifold3d (Mesh64)."""
    import manifold3d

    def to_manifold(m: trimesh.Trimesh) -> "manifold3d.Manifold":
        mesh64 = manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(m.vertices, dtype=np.float64),
            tri_verts=np.ascontiguousarray(m.faces, dtype=np.uint64),
        )
        return manifold3d.Manifold(mesh=mesh64)

    result = to_manifold(base)
    for other in others:
        result = result + to_manifold(other) if operation == "union" else result - to_manifold(other)
    out = result.to_mesh64()
    mesh = trimesh.Trimesh(
        vertices=np.asarray(out.vert_properties, dtype=np.float64)[:, :3],
        faces=np.asarray(out.tri_verts, dtype=np.int64),
        process=True,
    )
    if not mesh.is_watertight:  # a builder bug, not an operator error
        raise RuntimeError("sample part boolean produced a non-watertight mesh")
    return mesh
