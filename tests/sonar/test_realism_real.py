"""The shipped device profiles against the real samples they were fitted on (and the frames they were not).

The profiles in ``optiacoustic/data/sonar_profiles`` were fitted by ``oas sensor-fit`` on frame 0
of each sample (the Oculus sample has one ping; the ARIS sample six frames). Here each real
frame is compared with a frame simulated from the profile and the targets of issue 10 are
asserted (numbers in docs/physics.md 4.5). The ARIS frames 1-3 are held out: the profile
was fitted on frame 0 only.
"""

from pathlib import Path

import numpy as np
import pytest

from optiacoustic.sonar.comparison import compare
from optiacoustic.sonar.profile import SensorProfile

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def aris():
    from optiacoustic.io import open_sonar

    frames = list(open_sonar(DATA / "aris" / "sample.aris"))[:4]  # fitted on 0, checked on 1-3
    return compare(frames, SensorProfile.preset("aris-1200-telephoto"))


@pytest.fixture(scope="module")
def oculus():
    from optiacoustic.io import open_sonar

    frames = list(open_sonar(DATA / "oculus" / "one_ping_8bit.raw"))
    return compare(frames, SensorProfile.preset("oculus-m1200d-2mhz"))[0]


def test_aris_profile_holds_on_the_frames_it_was_not_fitted_on(aris):
    assert len(aris) == 4
    for c in aris[1:]:
        s = c.scores()
        assert abs(s["speckle_contrast"]["error"]) <= 0.10, s["speckle_contrast"]
        assert abs(s["corr_length_range"]["error"]) <= 0.20, s["corr_length_range"]
        assert abs(s["corr_length_beam"]["error"]) <= 0.20, s["corr_length_beam"]
        # the mean range profile follows the real one (dB, median absolute difference)
        d = np.abs(10 * np.log10(c.sim.profile / c.real.profile))
        assert np.median(d) < 3.0


def test_aris_intensity_distribution(aris):
    """Two-sample KS distance of the normalised intensities <= 0.05, fitted and held-out frames."""
    ks = [c.ks for c in aris]
    assert max(ks) <= 0.05, ks


def test_oculus_profile_reproduces_its_ping(oculus):
    s = oculus.scores()
    assert abs(s["corr_length_range"]["error"]) <= 0.20
    assert abs(s["corr_length_beam"]["error"]) <= 0.20
    assert np.isfinite(oculus.real.onset_width) and np.isfinite(oculus.sim.onset_width)


@pytest.mark.parametrize("name", ["onset_width", "speckle_contrast", "ks_distance"])
def test_oculus_targets(oculus, name):
    s = oculus.scores()[name]
    if name == "ks_distance":
        assert s["error"] <= 0.05
        return
    bound = {"onset_width": 0.25, "speckle_contrast": 0.10}[name]
    assert abs(s["error"]) <= bound, s


def test_oculus_onset_width_over_seeds():
    """The onset width is the noisiest statistic (sd about 13 % per frame over seeds, docs/physics.md
    4.4): its mean over 4 simulation seeds is within the 25 % target of the real ping's."""
    from optiacoustic.io import open_sonar
    from optiacoustic.sonar.realism import frame_statistics

    real = list(open_sonar(DATA / "oculus" / "one_ping_8bit.raw"))[0]
    prof = SensorProfile.preset("oculus-m1200d-2mhz")
    w_real = frame_statistics(prof.from_device(real.raw), real.ranges, real.azimuths).onset_width
    ws = [frame_statistics(prof.from_device(prof.to_device(prof.simulate(seed=s).image)), real.ranges,
                           real.azimuths).onset_width for s in range(4)]
    assert np.all(np.isfinite(ws)), ws
    assert abs(np.mean(ws) / w_real - 1) <= 0.25, (ws, w_real)


def test_oculus_seabed_echo_sits_where_the_real_one_does():
    """The flat seabed simulated at the shipped profile's seabed pose puts its onset (10 % and
    90 % crossings, median over beam groups) and the plateau's end (far 50 % crossing) where
    the real ping has them: mean over 3 seeds within 3.5 cm (12 range bins, a third of the
    onset's width; the fitted height's stated sigma, 2.8 %, carried to these ranges is
    2.3-3.0 cm). Before the position refinement the offsets were -6.4, -7.7 and -11.7 cm."""
    from optiacoustic.io import open_sonar
    from optiacoustic.sonar.realism import frame_statistics

    real = list(open_sonar(DATA / "oculus" / "one_ping_8bit.raw"))[0]
    prof = SensorProfile.preset("oculus-m1200d-2mhz")
    keys = ("onset_r10", "onset_r90", "plateau_end")
    st = frame_statistics(prof.from_device(real.raw), real.ranges, real.azimuths)
    r = np.array([getattr(st, k) for k in keys])
    sims = []
    for seed in range(3):
        s = frame_statistics(prof.from_device(prof.to_device(prof.simulate(seed=seed).image)), real.ranges, real.azimuths)
        sims.append([getattr(s, k) for k in keys])
    off = np.mean(sims, 0) - r
    assert np.all(np.isfinite(off)), (r, sims)
    tol = 0.035
    assert prof.uncertainty["height"] / prof.height * r[2] <= tol, prof.uncertainty["height"]
    assert np.all(np.abs(off) <= tol), dict(zip(keys, off))
