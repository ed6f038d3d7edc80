"""The thesis model's output is what it was before the aperture model existed (``beam_model="thesis"``).

``data/thesis_model_reference.json`` was written by the code before this change (commit ea36db4's
formation): sums, SHA-256 digests and a grid of sampled pixels of thesis scene 1.
"""

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from optiacoustic import Pose, scenes
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar

REF = json.loads((Path(__file__).parent / "data" / "thesis_model_reference.json").read_text())


@pytest.mark.parametrize("name, options", [
    ("tvg", SonarOptions(beam_model="thesis")),
    ("spreading_az", SonarOptions(propagation="spreading", azimuth_pattern=True)),
])
def test_thesis_model_output_is_unchanged(name, options):
    sc = scenes.get(REF["scene"])
    spec = dataclasses.replace(SonarSpec.preset(REF["preset"]), n_beams=REF["n_beams"], n_bins=REF["n_bins"],
                               elevation_samples=REF["elevation_samples"])
    f = simulate_sonar(sc, spec, Pose.look_at(REF["eye"], REF["target"]), seed=REF["seed"], options=options)
    ref = REF["results"][name]
    # sampled pixels compare exactly (float32 values stored as float64)
    np.testing.assert_array_equal(f.intensity[::37, ::11].astype(float).ravel(), ref["intensity_sample"])
    np.testing.assert_array_equal(f.image[::37, ::11].astype(float).ravel(), ref["image_sample"])
    assert f.intensity.astype(float).sum() == pytest.approx(ref["intensity_sum"], rel=1e-12)
    assert f.image.astype(float).sum() == pytest.approx(ref["image_sum"], rel=1e-12)
    # and on this platform's numpy/Embree, bit for bit
    assert hashlib.sha256(f.intensity.tobytes()).hexdigest() == ref["intensity_sha"]
    assert hashlib.sha256(f.image.tobytes()).hexdigest() == ref["image_sha"]
