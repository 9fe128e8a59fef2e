"""The deviation colour map on the part: known deviations on a box and a cylinder give the expected colours,
grey beyond the reach and on other surfaces, and the scene's vertex colours and the report's views agree."""

from __future__ import annotations

import base64
import io
import re
import struct
import zlib

import numpy as np
import pytest
import trimesh

from cmm.metrology.colour_map import deviation_map, display_mesh, interpolate, png, to_linear, to_srgb
from cmm.metrology.colour_scale import AMBER, CYAN, GREEN, GREY, RED, ColourScale
from cmm.session.report import part_view

BOX = (100.0, 80.0, 40.0)  # centred on the origin: top face z = +20, front face y = -40


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(BOX)


def colours_at(dmap, where):
    """The vertex colours of the display mesh where ``where(vertices, normals)`` holds."""
    m = dmap.mesh
    sel = where(m.vertices, m.vertex_normals)
    assert sel.any()
    return {tuple(c) for c in dmap.vertex_colours[sel].tolist()}


def colours_on(dmap, points, normal):
    """The map's colours at surface points with one normal (where the mesh may have no vertex)."""
    pts = np.asarray(points, float)
    return {tuple(c) for c in dmap.scale.colours(dmap.deviation_at(pts, np.tile(normal, (len(pts), 1)))).tolist()}


def grid(x, y, z):
    """Points on an axis-aligned grid (each argument: a value or a range)."""
    return np.stack(np.meshgrid(*(np.atleast_1d(a) for a in (x, y, z)), indexing="ij"), -1).reshape(-1, 3)


def test_box_map_bands_reach_other_surfaces_and_cutoff(box):
    scale = ColourScale(0.02, reach=15.0)  # warning from 10 um, out of tolerance beyond 20 um
    # compensated points in part coordinates, off the surface by their deviation (+ = outside the material)
    pts = np.array([[-30.0, -35.0, 20.015], [-20.0, -35.0, 20.015],  # top, near the front edge: +15 um (amber)
                    [30.0, -40.03, 0.0],  # 30 um outside the front face: red
                    [30.0, 0.0, -20.0 + 0.8]])  # bottom, 0.8 mm inside: beyond the 0.5 mm cut-off
    dev = np.array([0.015, 0.015, 0.03, -0.8])
    dmap = deviation_map(box, pts, dev, scale)
    assert dmap.hits_used == 3  # the one beyond the cut-off takes no part
    top = lambda v, n: n[:, 2] > 0.9  # noqa: E731
    front = lambda v, n: n[:, 1] < -0.9  # noqa: E731
    # the top face near the two hits: amber; the front face near its hit: red
    assert colours_at(dmap, lambda v, n: top(v, n) & (np.hypot(v[:, 0] + 25, v[:, 1] + 35) < 10)) == {AMBER}
    assert colours_at(dmap, lambda v, n: front(v, n) & (np.hypot(v[:, 0] - 30, v[:, 2]) < 10)) == {RED}
    # the same top face farther than the reach from every hit: grey
    far = lambda v, n: top(v, n) & (np.hypot(v[:, 0] + 25, v[:, 1] + 35) > 5 + 15.5)  # noqa: E731
    assert colours_at(dmap, far) == {GREY}
    # the front face right below the top hits (5 mm away in space, but another surface): grey
    assert colours_on(dmap, grid(np.linspace(-30, -20, 5), -40.0, np.linspace(10, 20, 5)), (0, -1, 0)) == {GREY}
    # the bottom face around the hit beyond the cut-off: grey
    assert colours_on(dmap, grid(np.linspace(25, 35, 5), np.linspace(-5, 5, 5), -20.0), (0, 0, -1)) == {GREY}
    # ... while the map evaluates the same everywhere: amber on the top next to its hits
    assert colours_on(dmap, grid(np.linspace(-30, -20, 5), np.linspace(-38, -30, 5), 20.0), (0, 0, 1)) == {AMBER}
    assert 0 < dmap.coverage < 0.1
    # a longer reach paints more of the part, in the same colours
    wide = deviation_map(box, pts, dev, ColourScale(0.02, reach=40.0))
    assert wide.coverage > 2 * dmap.coverage
    assert {tuple(c) for c in wide.face_colours.tolist()} == {AMBER, RED, GREY}


def test_inverse_distance_weighting_between_two_hits():
    src = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    up = np.tile([0.0, 0.0, 1.0], (2, 1))
    at = np.array([[5.0, 0.0, 0.0], [2.5, 0.0, 0.0], [0.0, 0.0, 0.0], [40.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    normals = np.array([[0, 0, 1.0]] * 4 + [[1.0, 0, 0]])  # the last one: a surface at 90 degrees
    d = interpolate(at, normals, src, up, [0.004, 0.016], reach=15.0)
    assert d[0] == pytest.approx(0.010)  # half-way: the mean
    assert d[1] == pytest.approx((0.004 / 2.5**2 + 0.016 / 7.5**2) / (1 / 2.5**2 + 1 / 7.5**2))
    assert d[2] == pytest.approx(0.004)  # on a hit: its deviation
    assert np.isnan(d[3]) and np.isnan(d[4])  # beyond the reach; another surface


def test_cylinder_map_stays_on_its_side():
    cyl = trimesh.creation.cylinder(radius=5.0, height=30.0, sections=64)  # axis Z, z from -15 to 15
    pts = np.array([[5.0 - 0.015, 0.0, 0.0], [5.0 - 0.015, 0.0, 5.0]])  # 15 um inside the wall: cyan
    dmap = deviation_map(cyl, pts, [-0.015, -0.015], ColourScale(0.02, reach=12.0))
    side = lambda v, n: np.abs(n[:, 2]) < 0.1  # noqa: E731
    assert colours_at(dmap, lambda v, n: side(v, n) & (v[:, 0] > 4.9) & (np.abs(v[:, 2] - 2.5) < 5)) == {CYAN}
    # the far side of the cylinder is within 12 mm in space, but faces the other way: grey
    assert colours_at(dmap, lambda v, n: side(v, n) & (v[:, 0] < -4.9)) == {GREY}
    # the top cap (within reach of the upper hit, but another surface): grey
    assert colours_at(dmap, lambda v, n: n[:, 2] > 0.9) == {GREY}


def test_display_mesh_is_split_refined_near_hits_and_big_meshes_decimated(box):
    m = display_mesh(box, 4000)
    assert len(m.faces) == 12 and len(m.vertices) == 24  # each corner once per face of the box that meets there
    assert len(set(m.metadata["surface"])) == 6
    assert np.allclose(np.abs(m.vertex_normals).max(axis=1), 1.0)  # every vertex has its face's normal
    # the map refines the faces around the hits (edges of about reach / 5), not the rest of the part
    dmap = deviation_map(box, [[0.0, 0.0, 20.0]], [0.0], ColourScale(reach=10.0), faces=4000)
    f = dmap.mesh
    top = f.face_normals[:, 2] > 0.9
    assert f.edges_unique_length.max() > 40  # faces far from the hit stay coarse
    near = top & (np.linalg.norm(f.triangles_center - [0, 0, 20], axis=1) < 10)
    assert near.sum() > 10 and f.edges_unique_length[f.faces_unique_edges[near]].max() < 10 / 3 * 1.01
    assert (f.face_normals[:, 2] < -0.9).sum() == 2  # the bottom: untouched
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=20.0)  # 81920 faces
    small = display_mesh(sphere, 4000)
    assert len(small.faces) < 4000  # about half the budget (vertex clustering is approximate)
    assert np.allclose(np.linalg.norm(small.vertices, axis=1), 20.0, atol=1.0)
    hit = np.array([[0.0, 0.0, 20.03]])
    dmap = deviation_map(sphere, hit, [0.03], ColourScale(0.02, reach=8.0), faces=4000)
    assert len(dmap.mesh.faces) <= 4000 and RED in {tuple(c) for c in dmap.vertex_colours.tolist()}


def _png_pixels(data: bytes) -> np.ndarray:
    """Decode the unfiltered RGBA PNG that :func:`cmm.metrology.colour_map.png` writes."""
    assert data.startswith(b"\x89PNG")
    pos, idat, size = 8, b"", None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            size = struct.unpack(">II", body[:8])
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    w, h = size
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 4 * w)
    assert not raw[:, 0].any()
    return raw[:, 1:].reshape(h, w, 4)


def test_png_round_trip():
    img = np.random.default_rng(1).integers(0, 255, (7, 5, 4), dtype=np.uint8)
    assert np.array_equal(_png_pixels(png(img)), img)


def test_scene_and_report_show_the_same_colour_for_the_same_deviation(box):
    """The scene gets the map's vertex colours (as a GLB); the report draws a z-buffered image of the same map
    and the hit dots: a deviation has one colour in both, the scale's."""
    scale = ColourScale(0.02, reach=20.0)
    pts = np.array([[0.0, 0.0, 20.025], [-40.0, 30.0, 20.005]])  # top: red and green
    dev = [0.025, 0.005]
    dmap = deviation_map(box, pts, dev, scale)
    # the scene: what SceneView sends (add_mesh_trimesh exports a GLB with COLOR_0)
    glb = trimesh.load(io.BytesIO(dmap.coloured_mesh().export(file_type="glb")), file_type="glb", force="mesh")
    stored = np.asarray(glb.visual.vertex_colors)[:, :3]
    assert np.array_equal(stored, to_linear(dmap.vertex_colours))  # glTF vertex colours are linear ...
    rgb = to_srgb(stored)  # ... and shown as sRGB: the scale's colours, to 8-bit rounding
    assert np.abs(rgb.astype(int) - dmap.vertex_colours).max() <= 2
    rgb = dmap.vertex_colours
    near = np.linalg.norm(glb.vertices - [0.0, 0.0, 20.0], axis=1) < 4
    assert {tuple(c) for c in rgb[near].tolist()} == {RED}
    near_green = np.linalg.norm(glb.vertices - [-40.0, 30.0, 20.0], axis=1) < 3
    assert {tuple(c) for c in rgb[near_green].tolist()} == {GREEN}
    # the report: the top view's image under the hit and the hit's dot
    svg = part_view(box, pts, dev, scale, np.array([0.0, 0.0, 1.0]), "top", dmap=dmap)
    img = _png_pixels(base64.b64decode(re.search(r'href="data:image/png;base64,([^"]+)"', svg).group(1)))
    h, w = img.shape[:2]
    W, H = (int(v) for v in re.search(r'viewBox="0 0 (\d+) (\d+)"', svg).groups())
    pad, s = 12, min((W - 24) / BOX[0], (H - 24 - 14) / BOX[1])

    def pixel(x, y):  # part mm (top view) -> the image's pixel
        return img[int((H - pad - (y + 40) * s) * h / H), int((pad + (x + 50) * s) * w / W)]

    assert tuple(pixel(0.0, 0.0)[:3]) == RED and pixel(0.0, 0.0)[3] == 255
    assert tuple(pixel(-40.0, 30.0)[:3]) == GREEN
    assert tuple(pixel(40.0, -30.0)[:3]) == GREY  # far from both hits
    assert 'fill="rgb(220,40,40)"' in svg and 'fill="rgb(40,180,70)"' in svg  # the dots, same colours
    # the front view does not show the top's hits as dots over the front face
    front = part_view(box, pts, dev, scale, np.array([0.0, -1.0, 0.0]), "front", dmap=dmap)
    assert front.count("<circle") == 2  # top hits are on the outline (edge-on), still shown
    back = part_view(box, pts, dev, scale, np.array([0.0, 0.0, -1.0]), "bottom", dmap=dmap)
    assert back.count("<circle") == 0  # looking from below, the top's hits are hidden


def test_no_usable_hits_give_an_all_grey_map(box):
    for pts, dev in ((np.zeros((0, 3)), []), ([[0.0, 0.0, 20.0]], [np.nan]), ([[0.0, 0.0, 20.9]], [0.9])):
        dmap = deviation_map(box, pts, dev, ColourScale(0.02))  # none, unknown, beyond the 0.5 mm cut-off
        assert dmap.hits_used == 0 and dmap.coverage == 0.0
        assert {tuple(c) for c in dmap.vertex_colours.tolist()} == {GREY}
    with pytest.raises(ValueError, match="2 points but 1 deviations"):
        deviation_map(box, [[0, 0, 20.0], [0, 0, -20.0]], [0.0], ColourScale())
