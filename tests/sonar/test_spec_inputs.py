"""SonarSpec from Python and from files: bad fields are named, presets are ValueErrors (and still KeyErrors)."""

import numpy as np
import pytest

from optiacoustic import SonarSpec
from optiacoustic.sonar.spec import UnknownPresetError


@pytest.mark.parametrize("data, words", [
    ({"bin_ranges": 5}, "field 'bin_ranges': expected a list of ranges (m), got 5"),
    ({"bin_ranges": ["1", "2"]}, "field 'bin_ranges'"),
    ({"unverified": 5}, "field 'unverified': expected a list of field names, got 5"),
    ({"unverified": [1]}, "field 'unverified'"),
    ({"preset": ["blueview-p900-90"]}, "field 'preset': unknown sonar preset ['blueview-p900-90']"),
    ({"preset": "nope"}, "field 'preset': unknown sonar preset 'nope'; presets are ['blueview-p900-45'"),
    ({"fov_azimuth_deg": True}, "field 'fov_azimuth_deg': expected a number, got True"),
    ({"fov_elevation_deg": "20"}, "field 'fov_elevation_deg': expected a number, got '20'"),
    ({"range_max": True}, "SonarSpec.range_max: must be a finite number > 0, got True"),
    ({"name": 5}, "SonarSpec.name: must be a string"),
])
def test_from_dict_names_the_field(data, words):
    with pytest.raises(ValueError) as e:
        SonarSpec.from_dict(data, "rig.yaml: field 'sonar'")
    msg = str(e.value)
    assert msg.startswith("rig.yaml: field 'sonar': ") and words in msg, msg


def test_unknown_preset_is_a_value_error_that_is_still_a_key_error():
    with pytest.raises(ValueError, match=r"^unknown sonar preset 'x'; presets are \[") as e:
        SonarSpec.preset("x")
    assert isinstance(e.value, KeyError) and isinstance(e.value, UnknownPresetError)
    with pytest.raises(ValueError, match="unknown sonar preset"):
        SonarSpec.preset(["blueview-p900-90"])


def test_preset_overrides_name_an_unknown_field():
    with pytest.raises(ValueError, match=r"SonarSpec.preset\('aris-3000-128'\): unknown field 'nbeams'"):
        SonarSpec.preset("aris-3000-128", nbeams=3)
    s = SonarSpec.preset("aris-3000-128", n_beams=64)
    assert s.n_beams == 64 and s.name == "aris-3000-128"


@pytest.mark.parametrize("kw, field", [({"range_max": True}, "range_max"), ({"range_min": False}, "range_min"),
                                       ({"frequency": "900e3"}, "frequency"), ({"unverified": "abc"}, "unverified"),
                                       ({"elevation_beam": "x"}, "elevation_beam"), ({"bin_ranges": 5}, "bin_ranges")])
def test_constructor_refuses_bools_and_strings(kw, field):
    with pytest.raises(ValueError, match=rf"^SonarSpec.{field}:"):
        SonarSpec(**kw)


def test_valid_values_keep_working():
    s = SonarSpec.from_dict({"preset": "blueview-p900-90", "fov_elevation_deg": 14, "unverified": ["frequency"],
                             "range_max": 30})
    assert s.fov_elevation == pytest.approx(np.deg2rad(14)) and s.unverified == ("frequency",) and s.range_max == 30
    t = SonarSpec.from_dict({"bin_ranges": [1.0, 1.5, 2.5, 4.0]})
    np.testing.assert_allclose(t.ranges, [1.0, 1.5, 2.5, 4.0])
