"""The moves an exported DMIS program makes between a feature's hits: the routine runner's hops, as GOTO points.

The routine runner takes a feature's first hit over its clearance height and hops to the others
(:func:`cmm.metrology.hops.with_hops` gives the hop height, the control core's rails decide the route:
:func:`cmm.control.rails.probe_clearance`). The exporter asks the same two, on the part mesh in the program's part
coordinates, and writes what they decide as the GOTO points before each ``PTMEAS`` (which goes straight from
where the tip is to its pre-hit point, as the rails prove it free when the program runs):

- straight from the last hit's retract point: no GOTO;
- over the hop height: a GOTO up to it over the retract point and one across to over the pre-hit point;
- else over the clearance height: a GOTO up to it over the last pre-hit point and one across, as before hops.

The proof at export takes the tip ``SLACK`` mm bigger than it is: the run proves every line again on the part
where the station has it and the hits as the probe takes them, a little off the nominal ones. Without a mesh
every hit goes over its clearance height.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..control.rails import probe_clearance
from ..metrology.hops import with_hops
from ..metrology.mesh import signed_deviation

SLACK = 0.25  # mm the tip is taken bigger when the exporter proves a line free (less than the hop margin less
# the rails' straight margin, 0.5 mm: a hop over the local top stays provable)


class PartMesh:
    """The part mesh in its own coordinates as the rails see a part (:class:`cmm.control.rails.Workspace`)."""

    def __init__(self, mesh: Any) -> None:
        self.mesh = mesh

    def part_pose(self) -> np.ndarray:
        return np.eye(4)

    def clearance_z(self) -> float | None:
        return None  # every hit says its own

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        return signed_deviation(self.mesh, points).deviations


def hop_gotos(hits: list[Any], mesh: Any, *, tip_radius: float, approach: float,
              retract: float) -> tuple[list[list[np.ndarray]], np.ndarray]:
    """For one feature's ``hits`` (programmed hits, part coordinates, in the order they are taken): the GOTO
    points before each one's PTMEAS, and the one after the last (up to its clearance height)."""
    pts = [np.asarray(h.point, float) for h in hits]
    us = [np.asarray(h.approach, float) / np.linalg.norm(h.approach) for h in hits]
    pres = [p - (tip_radius + approach) * u for p, u in zip(pts, us)]
    tops = [max(float(h.clearance_z), float(pre[2])) for h, pre in zip(hits, pres)]
    over = [np.array([pre[0], pre[1], top]) for pre, top in zip(pres, tops)]
    hops = [t[-1] for t in with_hops([(p, u, top) for p, u, top in zip(pts, us, tops)], mesh, np.eye(4), tip_radius)]
    workspace = None if mesh is None else PartMesh(mesh)
    before: list[list[np.ndarray]] = [[over[0]]]
    for k in range(1, len(hits)):
        if workspace is None or hops[k] is None:
            before.append([over[k - 1], over[k]])
            continue
        here = pres[k - 1] if retract < 0 else pts[k - 1] - (tip_radius + retract) * us[k - 1]
        z = probe_clearance(here, pres[k], path="clearance", workspace=workspace, radius=tip_radius + SLACK,
                            clearance_z=tops[k], hop_z=hops[k])
        if z is None:  # straight: the PTMEAS goes there itself
            before.append([])
        elif z < tops[k]:  # over the hop height: up, across (the PTMEAS comes down)
            corners = [here, np.array([*here[:2], max(z, here[2])]), np.array([*pres[k][:2], max(z, pres[k][2])])]
            before.append([c for c, last in zip(corners[1:], corners[:-1])
                           if np.linalg.norm(c - last) > 1e-6 and np.linalg.norm(c - pres[k]) > 1e-6])
        else:
            before.append([over[k - 1], over[k]])
    return before, over[-1]
