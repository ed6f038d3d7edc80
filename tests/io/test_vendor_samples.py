"""The real ARIS and Oculus samples decode to what their own documentation says."""

import numpy as np
import pytest

from optiacoustic.io import open_sonar
from optiacoustic.io.aris import beam_table
from optiacoustic.sonar.frame import SonarImageLike


def test_aris_sample_matches_sdk_description(aris_sample):
    r = open_sonar(aris_sample)
    # README: ARIS 1200, telephoto lens, 6 frames of 48 beams x 2000 samples, about 3.3-23.4 m
    assert len(r) == 6
    info = r.info()
    assert info["system"] == "ARIS 1200" and info["telephoto"] and info["beam_table"].endswith("Telephoto_48.h")
    f = r[0]
    assert f.raw.shape == (2000, 48) and f.raw.dtype == np.uint8 and f.image.dtype == np.float32
    assert f.ranges[0] == pytest.approx(3.3, abs=0.05) and f.ranges[-1] == pytest.approx(23.4, abs=0.05)
    # SDK: WindowStart = SampleStartDelay * 1e-6 * c / 2, sample length = SamplePeriod * 1e-6 * c / 2
    c = f.meta["sound_speed"]
    assert f.ranges[0] == pytest.approx(f.meta["sample_start_delay_us"] * 1e-6 * c / 2, rel=1e-12)
    assert np.allclose(np.diff(f.ranges), f.meta["sample_period_us"] * 1e-6 * c / 2)
    # the header's own (float) window agrees to its rounding
    assert f.ranges[0] == pytest.approx(f.meta["window_start_header"], abs=0.05)
    # telephoto table: +-7.339 deg centres, non-uniform spacing, left to right
    assert np.rad2deg(f.azimuths[[0, -1]]) == pytest.approx([-7.339, 7.339], abs=1e-9)
    d = np.diff(f.azimuths)
    assert np.all(d > 0) and d.max() - d.min() > np.deg2rad(0.01)
    assert np.array_equal(f.azimuths, beam_table(48, True)[0])
    # times: PC clock in June 2013, increasing frame to frame
    t = np.array([fr.time for fr in r])
    assert 1.37e9 < t[0] < 1.372e9 and np.all(np.diff(t) > 0)
    # dB bytes: 0..255 -> 0..80 dB
    assert f.image.max() == pytest.approx(10 ** (int(f.raw.max()) * 80 / 255 / 10), rel=1e-5)
    assert isinstance(f, SonarImageLike) and f.fan(width=64).data.shape[1] == 64


def test_aris_columns_are_reversed_sdk_beams(aris_sample):
    """SDK: beam 0 is the right-most; our column 0 is the left-most."""
    f = open_sonar(aris_sample)[1]
    data = np.fromfile(aris_sample, np.uint8, count=2000 * 48, offset=1024 + 1 * (1024 + 96000) + 1024)
    assert np.array_equal(f.raw, data.reshape(2000, 48)[:, ::-1])


def test_aris_tables_all_models():
    for n, tele in [(48, False), (96, False), (64, False), (128, False), (48, True), (96, True)]:
        az, name = beam_table(n, tele)
        assert az.shape == (n,) and np.all(np.diff(az) > 0) and abs(az[0] + az[-1]) < np.deg2rad(0.5), name
        assert np.rad2deg(az[-1]) < 16.0


def test_oculus_sample_matches_liboculus_description(oculus_sample):
    r = open_sonar(oculus_sample)
    # README: 2.1 MHz, 256 beams x 703 ranges, 2.84 mm range resolution, 2 m range, 8-bit, gamma 127
    assert len(r) == 1
    f = r[0]
    assert f.raw.shape == (703, 256) and f.raw.dtype == np.uint8
    assert f.meta["frequency"] == pytest.approx(2.1e6, rel=0.01)
    assert f.meta["range_resolution"] == pytest.approx(2.84e-3, abs=5e-6)
    assert f.meta["gamma"] == 127 and f.meta["data_bits"] == 8 and f.meta["range"] == 2.0
    assert f.ranges[-1] == pytest.approx(2.0, abs=0.01)
    # M1200d high-frequency: about 60 deg aperture; bearings in 1/100 deg, increasing
    assert np.rad2deg(f.azimuths[-1] - f.azimuths[0]) == pytest.approx(60.0, abs=1.0)
    assert np.all(np.diff(f.azimuths) > 0)
    raw_bearings = np.frombuffer(oculus_sample.read_bytes()[122:122 + 512], "<i2")
    assert np.array_equal(f.azimuths, np.deg2rad(raw_bearings / 100.0))
    # image rows start at imageOffset 2048 and are 256 bytes each
    assert np.array_equal(f.raw, np.frombuffer(oculus_sample.read_bytes()[2048:2048 + 703 * 256], np.uint8).reshape(703, 256))
    # the seabed: the far half of the image is brighter than the nearest 20 cm (water column)
    near = f.image[f.ranges < 0.2].mean()
    far = f.image[(f.ranges > 0.8) & (f.ranges < 1.4)].mean()
    assert far > 5 * near
    assert np.isnan(f.time)
