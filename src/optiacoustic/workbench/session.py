"""The workbench's state: one source pair, the current rig, the matches (with undo), calibration views.

One :class:`Session` per server (the workbench is a single-user local app). Every change goes
through a method that takes the lock, pushes the previous matches on the undo stack and bumps
``version``; reads never change anything. Matches are stored as measurements: the camera
pixel ``(u, v)`` and the sonar ``(range, azimuth)`` (m, rad).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, replace

import numpy as np

from ..rig import Rig
from . import compute
from .images import FAN_WIDTH, fan_display
from .sources import Pair

__all__ = ["Match", "Session", "MAX_MATCHES", "MAX_VIEWS", "MAX_CORNERS"]

MAX_MATCHES = 2000
MAX_VIEWS = 50
# grid corners over all calibration views: the calibration's memory grows faster than their
# count (0.44 GB at 1 330 corners, 7.2 GB at 10 780; 24 GB killed the server), and it runs
# under the session's lock; a grid of 30 x 30 corners in each of two views fits
MAX_CORNERS = 2000
_UNDO_DEPTH = 200


@dataclass(frozen=True)
class Match:
    """A camera pixel and a sonar measurement of the same point."""

    u: float
    v: float
    range: float
    azimuth: float


@dataclass
class Session:
    """Everything the page can change, behind one lock."""

    pair: Pair
    rig: Rig = None
    matches: list = field(default_factory=list)
    views: list = field(default_factory=list)
    sigmas: compute.Sigmas = None
    calibration: object = None
    calibration_report: dict = None
    version: int = 0
    fan_width: int = FAN_WIDTH
    seabed: object = None  # a SeabedPlane from the navigation for the matcher (real soft-beam pairs), or None

    def __post_init__(self):
        self.lock = threading.RLock()
        self._undo: list = []
        self.set_pair(self.pair)

    # ------------------------------------------------------------------ source
    def set_pair(self, pair: Pair, *, same_source: bool = False) -> None:
        """Show another pair. ``same_source`` (another frame of the same log or dataset) keeps the
        calibration views, the calibration and an applied rig, so that grid views can be
        collected over frames; the matches always start afresh."""
        with self.lock:
            keep = same_source and getattr(self, "fan", None) is not None
            calibrated = keep and self.rig is not self.pair.rig
            self.pair = pair
            self.rig = self.rig if calibrated else pair.rig
            spec = pair.spec
            if self.sigmas is None:
                self.sigmas = compute.Sigmas(1.0, float(getattr(spec, "range_resolution", 0) or spec.bin_width),
                                             float(getattr(spec, "beamwidth_azimuth", 0) or spec.beam_spacing) / 2)
            self.fan = fan_display(pair.sonar_image, spec, self.fan_width)
            self.fan_small = fan_display(pair.sonar_image, spec, 256)
            self.matches, self._undo = [], []
            if not keep:
                self.views = []
                self.calibration = self.calibration_report = None
            self.version += 1

    # ------------------------------------------------------------------ matches
    def _push(self):
        self._undo.append(list(self.matches))
        del self._undo[:-_UNDO_DEPTH]
        self.version += 1

    def match_from_display(self, camera_px, sonar_px) -> Match:
        """A match from a camera pixel and a fan-image pixel (validated)."""
        u, v = (float(a) for a in camera_px)
        c = self.rig.camera
        if not (-0.5 <= u <= c.width - 0.5 and -0.5 <= v <= c.height - 0.5):
            raise ValueError(f"camera point ({u:.1f}, {v:.1f}) px is outside the {c.width} x {c.height} image")
        r, th = compute.sonar_measurement(self.fan, self.pair.spec, *sonar_px)
        return Match(u, v, r, th)

    def add(self, m: Match) -> int:
        with self.lock:
            if len(self.matches) >= MAX_MATCHES:
                raise ValueError(f"at most {MAX_MATCHES} matches")
            self._push()
            self.matches.append(m)
            return len(self.matches) - 1

    def _index(self, i: int) -> int:
        if not 0 <= i < len(self.matches):
            raise KeyError(f"no match {i} (there are {len(self.matches)})")
        return i

    def move(self, i: int, camera_px=None, sonar_px=None) -> None:
        with self.lock:
            old = self.matches[self._index(i)]
            cam = (old.u, old.v) if camera_px is None else camera_px
            son = tuple(compute.fan_pixels(self.fan, old.range, old.azimuth)) if sonar_px is None else sonar_px
            new = self.match_from_display(cam, son)
            if sonar_px is None:
                new = replace(new, range=old.range, azimuth=old.azimuth)  # keep the exact measurement
            if new == old:  # nothing moved: no undo step, no new version (clients would refetch for nothing)
                return
            self._push()
            self.matches[i] = new

    def delete(self, i: int) -> None:
        with self.lock:
            self._index(i)
            self._push()
            del self.matches[i]

    def replace_all(self, matches) -> None:
        with self.lock:
            if len(matches) > MAX_MATCHES:
                raise ValueError(f"at most {MAX_MATCHES} matches, got {len(matches)}")
            if list(matches) == self.matches:  # e.g. clearing no matches: no undo step, no new version
                return
            self._push()
            self.matches = list(matches)

    def undo(self) -> bool:
        with self.lock:
            if not self._undo:
                return False
            self.matches = self._undo.pop()
            self.version += 1
            return True

    def arrays(self, matches=None):
        ms = self.matches if matches is None else matches
        px = np.array([[m.u, m.v] for m in ms], float).reshape(-1, 2)
        r = np.array([m.range for m in ms], float)
        th = np.array([m.azimuth for m in ms], float)
        return px, r, th

    # ------------------------------------------------------------------ settings, rig
    def set_sigmas(self, sigmas: compute.Sigmas) -> None:
        with self.lock:
            self.sigmas = sigmas
            self.version += 1

    def set_rig(self, rig: Rig) -> None:
        with self.lock:
            self.rig = rig
            self.version += 1

    # ------------------------------------------------------------------ calibration
    def add_view(self, view) -> int:
        with self.lock:
            if len(self.views) >= MAX_VIEWS:
                raise ValueError(f"at most {MAX_VIEWS} calibration views")
            if view.n < 4:
                raise ValueError(f"a calibration view needs at least 4 grid corners, this one has {view.n}")
            total = sum(v.n for v in self.views) + view.n
            if total > MAX_CORNERS:
                raise ValueError(f"at most {MAX_CORNERS} grid corners over all calibration views; this view's "
                                 f"{view.n} would make {total}")
            self.views.append(view)
            self.version += 1
            return len(self.views) - 1

    def delete_view(self, i: int) -> None:
        with self.lock:
            if not 0 <= i < len(self.views):
                raise KeyError(f"no calibration view {i} (there are {len(self.views)})")
            del self.views[i]
            self.version += 1

    def run_calibration(self) -> dict:
        with self.lock:
            if not self.views:
                raise ValueError("no calibration views: add the grid matches of a view, or import view CSVs")
            res, report = compute.calibrate(self.pair.rig, list(self.views), self.sigmas)
            self.calibration, self.calibration_report = (res if res else None), report
            self.version += 1
            return report

    def apply_calibration(self) -> None:
        with self.lock:
            if self.calibration is None:
                raise ValueError("no successful calibration to apply: run one first")
            self.set_rig(self.calibration.rig(self.pair.rig.camera, self.pair.spec))

    # ------------------------------------------------------------------ views of the state
    def state(self) -> dict:
        with self.lock:
            rig, fan, spec, cam = self.rig, self.fan, self.pair.spec, self.rig.camera
            sp = compute.fan_pixels(fan, *self.arrays()[1:]) if self.matches else np.zeros((0, 2))
            from ..frames import euler_xyz_from_rotation, R_SONAR_FROM_CAMERA_FORWARD

            return {
                "version": self.version,
                "source": {"name": self.pair.name, "kind": self.pair.kind, "description": self.pair.description,
                           "frame": self.pair.frame, "n_frames": self.pair.n_frames},
                "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                           "cy": cam.cy},
                "sonar": {"name": getattr(spec, "name", ""), "n_beams": spec.n_beams, "n_bins": spec.n_bins,
                          "fov_azimuth_deg": float(np.rad2deg(spec.fov_azimuth)),
                          "fov_elevation_deg": float(np.rad2deg(spec.fov_elevation)),
                          "range_min": float(spec.range_min), "range_max": float(spec.range_max)},
                "fan": {"width": int(fan.data.shape[1]), "height": int(fan.data.shape[0]),
                        "extent": [float(e) for e in fan.extent], "pixel_size": float(fan.pixel_size)},
                "rig": {"R": np.round(rig.R, 9).tolist(), "t": np.round(rig.t, 6).tolist(),
                        "baseline_m": rig.baseline, "vergence_deg": float(np.rad2deg(rig.vergence)),
                        "rotation_about_sonar_xyz_deg": np.round(np.rad2deg(euler_xyz_from_rotation(
                            rig.R @ R_SONAR_FROM_CAMERA_FORWARD.T)), 4).tolist(),
                        "calibrated": rig is not self.pair.rig},
                "sigmas": {"pixel": self.sigmas.pixel, "range": self.sigmas.range,
                           "azimuth_deg": float(np.rad2deg(self.sigmas.azimuth))},
                "matches": [{"index": i, "camera": [m.u, m.v], "sonar": np.round(sp[i], 3).tolist(),
                             "range": m.range, "azimuth_deg": float(np.rad2deg(m.azimuth))}
                            for i, m in enumerate(self.matches)],
                "can_undo": bool(self._undo),
                "views": [{"index": i, "n": int(v.n)} for i, v in enumerate(self.views)],
                "calibration": self.calibration_report,
            }
