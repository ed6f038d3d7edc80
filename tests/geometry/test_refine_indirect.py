"""refine(method="indirect") solves every noisy match the direct method solves, to the same point.

Review finding: about 1e-4 to 1e-3 of noisy matches ended on a spurious part of the epipolar
conic (the opposite half-plane, or the part behind the camera) and were rejected with status 4
("opposite half-plane"). The conic is necessary for consistent measurements, not sufficient.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from optiacoustic import PinholeCamera, Rig
from optiacoustic.geometry import projection as pr
from optiacoustic.geometry import reconstruct as rc


def _case(seed, n=2000):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3)
    t *= rng.uniform(0.1, 1.0) / np.linalg.norm(t)
    cam = PinholeCamera(rng.uniform(400, 1200), rng.uniform(400, 1200), rng.uniform(250, 350),
                        rng.uniform(150, 250), 640, 400)
    rig = Rig(R, t, cam)
    z = rng.uniform(1.0, 10.0, n)
    P = np.stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], -1)
    p = pr.project(rig, P)
    e = rng.standard_normal((n, 4)) * [1.0, 1.0, 0.01, 0.005]
    return rig, (p.pixels + e[:, :2], p.ranges + e[:, 2], p.azimuths + e[:, 3])


@pytest.mark.parametrize("seed", [3, 11, 27])  # seed 3 held a match the old indirect rejected
def test_indirect_solves_what_direct_solves(seed):
    rig, meas = _case(seed)
    sig = dict(sigma_pixel=1.0, sigma_range=0.01, sigma_azimuth=0.005)
    d = rc.refine(rig, *meas, method="direct", **sig)
    i = rc.refine(rig, *meas, method="indirect", **sig)
    assert np.all(i.valid[d.valid]), np.bincount(i.status[d.valid], minlength=8)
    both = d.valid & i.valid
    assert both.sum() > 1900
    np.testing.assert_allclose(i.points[both], d.points[both], atol=1e-6)
    np.testing.assert_allclose(i.cost[both], d.cost[both], rtol=1e-6, atol=1e-9)
