"""Default hit plans against the expected uncertainty: a plan whose expected U (k = 2) is more
than a quarter of the feature's tolerance zone says so before Run (the sphere cap's 5 hits: U of the diameter
about 15 um against the +-0.02 zone); the top face's 4 hits and the bore's 2 rings of 4 do not."""

from __future__ import annotations

import numpy as np

from cmm.metrology.hit_plan import plan_feature
from cmm.metrology.pick import pick, suggest_feature
from cmm.metrology.transform import as_pose
from cmm.sim.sample_part import sample_part


def test_plans_say_when_their_expected_uncertainty_is_too_large():
    mesh, _ = sample_part()
    pose = as_pose(np.eye(4))
    pose[:3, 3] = [190.0, 150.0, 0.0]

    def plan_at(point, direction, **kw):
        hit = pick(mesh, None, np.asarray(point, float) - 30 * np.asarray(direction, float), direction)
        s = suggest_feature(mesh, hit.face_id)
        return plan_feature(mesh, pose, s.feature, s.face_ids, **kw)

    dome = plan_at((70, 58, 49), (0, 0, -1))
    assert dome.kind == "sphere" and len(dome) == 5
    note = next(n for n in dome.notes if n.startswith("the expected uncertainty of the diameter"))
    u = float(note.split("U = ")[1].split(" um")[0])
    assert 10.0 < u < 40.0 and "more than a quarter of its 0.040 mm tolerance zone" in note
    top = plan_at((10, 70, 40), (0, 0, -1))
    bore = plan_at((15, 40, 20), (-1, 0, 0))
    assert not any("expected uncertainty" in n for n in top.notes + bore.notes)
