"""Regenerate the simulated calibration sequence of this folder.

A rig (BlueView P900-90 sonar, 600 x 400 px camera with a 50 mm lens on a 36 x 24 mm
sensor) whose camera sits 25 cm to the sonar's left, 2 cm ahead and 5 cm up, turned 2.3 deg
towards the sonar's axis and pitched 3 deg down, looks at a 7 x 5 corner planar grid (10 cm
squares) in 8 random poses 1.5-3 m away. Each view's corners are written as
``view_NN.csv`` (u, v in px; range in m; azimuth in deg) with Gaussian noise of 0.5 px,
5 mm and 0.1 deg. ``truth.yaml`` holds the rig that made them.

    python examples/calibration/make_example.py
"""

from pathlib import Path

import numpy as np
import yaml

from optiacoustic import PinholeCamera, Rig, SonarSpec
from optiacoustic._atomic import write_text
from optiacoustic.geometry.calibrate import save_view, simulate_views

HERE = Path(__file__).resolve().parent
POSITION = [-0.25, 0.02, 0.05]
ROTATION_DEG = [-3.0, 0.0, -2.3]  # about the sonar's x (pitch), y, z (vergence)
NOISE = dict(sigma_pixel=0.5, sigma_range=0.005, sigma_azimuth=float(np.deg2rad(0.1)))


def main():
    truth = {"sonar": "blueview-p900-90",
             "camera": {"width_px": 600, "height_px": 400, "sensor_mm": [36, 24], "focal_mm": 50},
             "camera_in_sonar": {"position": POSITION, "rotation_deg": ROTATION_DEG}}
    rig = Rig.from_dict(truth, "truth")
    assert isinstance(rig.camera, PinholeCamera) and isinstance(rig.sonar, SonarSpec)
    views, _ = simulate_views(rig, 8, seed=2024, **NOISE)
    for k, v in enumerate(views):
        save_view(HERE / f"view_{k + 1:02d}.csv", v,
                  header=f"simulated view {k + 1} of a 7 x 5 planar grid; noise 0.5 px, 5 mm, 0.1 deg")
    write_text(HERE / "truth.yaml", "# the rig that made the views\n" + yaml.safe_dump(truth, sort_keys=False,
                                                                                      default_flow_style=None))
    print(f"wrote {len(views)} views to {HERE}")


if __name__ == "__main__":
    main()
