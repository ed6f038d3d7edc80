"""The sonar detector's CFAR maps handed in by the caller (``maps=``)."""

import numpy as np
import pytest


def test_precomputed_cfar_maps_give_the_same_answers_and_wrong_ones_are_named():
    """``maps=`` (the pair's CFAR maps, computed once by ``match``) changes no number; maps of another
    shape or not a ``(smooth, background)`` pair are a ValueError naming the function."""
    from optiacoustic.matching.contact import echo_end_ranges, echo_start_ranges
    from optiacoustic.matching.sonar_features import cfar_map, detect_sonar_features

    rng = np.random.default_rng(4)
    img = rng.exponential(1.0, (120, 60))
    img[40:46, 20:24] += 30.0  # a compact echo
    r, th = np.linspace(1.0, 6.0, 120), np.linspace(-0.4, 0.4, 60)
    maps = cfar_map(img)
    a = detect_sonar_features(img, r, th, range_resolution=0.04, beamwidth=0.014)
    b = detect_sonar_features(img, r, th, range_resolution=0.04, beamwidth=0.014, maps=maps)
    assert len(a) > 0 and np.array_equal(a.ranges, b.ranges) and np.array_equal(a.snr, b.snr)
    for fn in (echo_start_ranges, echo_end_ranges):
        assert np.array_equal(fn(img, r, [43], [21]), fn(img, r, [43], [21], maps=maps))
        with pytest.raises(ValueError, match=fn.__name__):
            fn(img, r, [43], [21], maps=(maps[0][:10], maps[1]))
    with pytest.raises(ValueError, match="detect_sonar_features"):
        detect_sonar_features(img, r, th, range_resolution=0.04, beamwidth=0.014, maps=maps[0])
