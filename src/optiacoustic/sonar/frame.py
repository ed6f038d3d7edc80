"""Results of a sonar simulation: the frame, its ground truth and its per-ray data."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..frames import Pose
from .display import FanImage, polar_to_fan
from .spec import SonarSpec

__all__ = ["SonarFrame", "SonarGroundTruth", "SonarRays", "FanImage"]


@dataclass(frozen=True, eq=False)
class SonarRays:
    """Per-ray data of the scan (thesis sec. 2.6.1, the 512 x 750 matrices of Fig. 2.4-2.7).

    Every array is ``(elevation_samples, n_beams)``: row = elevation sample (bottom to
    top of the aperture), column = beam.

    Attributes
    ----------
    range : distance to the hit (m); ``inf`` on a miss.
    energy : the ray's echo energy (reflectivity x cos(incidence) x beam weight x dphi).
    body : id of the body hit; ``-1`` on a miss.
    cos_incidence : cosine of the angle between the ray and the surface normal.
    footprint_lo, footprint_hi : range interval (m) the ray's elevation cell covers on
        its tangent plane; NaN on a miss.
    beam_index, elevation : beam index and elevation (rad) of each ray.
    elevation_lo, elevation_hi : the elevation cell each ray stands for (rad); cells are
        ``elevation_step`` wide except at visibility edges, where they end at the edge.
    elevation_step : nominal angular width of a ray's elevation cell (rad).
    """

    range: np.ndarray
    energy: np.ndarray
    body: np.ndarray
    cos_incidence: np.ndarray
    footprint_lo: np.ndarray
    footprint_hi: np.ndarray
    beam_index: np.ndarray
    elevation: np.ndarray
    elevation_lo: np.ndarray
    elevation_hi: np.ndarray
    elevation_step: float


class SonarGroundTruth:
    """What the sonar image does not say. Maps are ``(n_bins, n_beams)`` like the image.

    The maps are computed on first access and cached (the shadow needs extra rays), so a
    frame costs nothing for truth it is never asked for.

    Attributes
    ----------
    body : int16
        Body id of the strongest single contribution to each cell; ``-1`` where nothing
        echoes. Names are ``SonarFrame.body_names``.
    elevation_min, elevation_max : float32
        Span of elevation angles (rad) of the rays that echo in each cell: the ambiguity
        the sonar cannot resolve and a camera can. NaN where nothing echoes.
    shadow : bool
        Acoustic shadow: cells that a surface would echo into but for an occluder in
        front of it (sec. 2.6.2.2).
    range_map : float32, ``(elevation_samples, n_beams)``
        Range of each ray's first hit (m), ``inf`` on a miss: the scan's depth map.
    """

    def __init__(self, range_map: np.ndarray, compute_maps, compute_shadow):
        self.range_map = range_map
        self._compute_maps = compute_maps
        self._compute_shadow = compute_shadow
        self._maps = None
        self._shadow = None

    def _get_maps(self):
        if self._maps is None:
            self._maps = self._compute_maps()
            for a in self._maps:
                a.setflags(write=False)
        return self._maps

    @property
    def body(self) -> np.ndarray:
        return self._get_maps()[0]

    @property
    def elevation_min(self) -> np.ndarray:
        return self._get_maps()[1]

    @property
    def elevation_max(self) -> np.ndarray:
        return self._get_maps()[2]

    @property
    def shadow(self) -> np.ndarray:
        if self._shadow is None:
            self._shadow = self._compute_shadow(self.elevation_min)
            self._shadow.setflags(write=False)
        return self._shadow


@dataclass(frozen=True, eq=False)
class SonarFrame:
    """One simulated sonar frame.

    Attributes
    ----------
    spec : SonarSpec
    pose : Pose
        Sonar pose in the world.
    intensity : float32 ``(n_bins, n_beams)``
        Noise-free echo: elevation-integrated returns per metre of range in each
        (bin, beam) cell. Row = range bin (near to far), column = beam (left to right).
    image : float32 ``(n_bins, n_beams)``
        ``intensity`` with noise and reverberation, same units.
    ground_truth : SonarGroundTruth
        Per-cell truth, computed on first access.
    rays : SonarRays
        Per-ray data of the scan.
    body_names : tuple of str
        Body ids -> names.
    seabed_share : dict of str -> float32 ``(n_bins, n_beams)``
        For each bottom type present, the share of each cell's echo returned by seabed
        bodies of that type (what the reverberation model acts on); the rest is target.
    """

    spec: SonarSpec
    pose: Pose
    intensity: np.ndarray
    image: np.ndarray
    ground_truth: SonarGroundTruth
    rays: SonarRays
    body_names: tuple[str, ...]
    seabed_share: dict

    @property
    def ranges(self) -> np.ndarray:
        """Range-bin centres (m), ``(n_bins,)``."""
        return self.spec.ranges

    @property
    def azimuths(self) -> np.ndarray:
        """Beam-centre azimuths (rad), ``(n_beams,)``."""
        return self.spec.azimuths

    def fan(self, which: Literal["image", "intensity"] = "image", *, width: int = 800) -> FanImage:
        """The image resampled to the fan (``cv2.remap`` through a cached map; sec. 2.6.2.4)."""
        if which not in ("image", "intensity"):
            raise ValueError(f"fan: which must be 'image' or 'intensity', got {which!r}")
        return polar_to_fan(getattr(self, which), self.spec, width=width)

    def save_npz(self, path) -> Path:
        """Write intensity, image, ranges, azimuths, pose and ground truth to an ``.npz``."""
        path = Path(path)
        data = dict(
            intensity=self.intensity,
            image=self.image,
            ranges=self.ranges,
            azimuths=self.azimuths,
            pose_R=self.pose.R,
            pose_t=self.pose.t,
            body_names=np.array(self.body_names),
            ray_range=self.rays.range,
            ray_energy=self.rays.energy,
            ray_body=self.rays.body,
            ray_elevation=self.rays.elevation[:, 0],
        )
        gt = self.ground_truth
        data.update(
            gt_body=gt.body,
            gt_elevation_min=gt.elevation_min,
            gt_elevation_max=gt.elevation_max,
            gt_shadow=gt.shadow,
            gt_range_map=gt.range_map,
        )
        from .._atomic import save_npz

        return save_npz(path, **data)
