"""Noise and reverberation applied to a sonar image (thesis sec. 2.7).

Each cell's echo is the coherent sum of its seabed returns (bottom reverberation, whose
amplitude follows a bottom-type model of Table 2.2), its target returns (fully developed
speckle: circular Gaussian) and ambient/thermal noise (circular Gaussian, amplified with
range by the TVG):

    image = | sqrt(I_bottom) X e^{i psi} + sqrt(I_target) Z_t + sqrt(N(r)) Z_n |^2

with ``E[X^2] = 1``, ``Z ~ CN(0, 1)``, ``psi`` uniform. The two circular Gaussian terms
merge into one, ``sqrt(I_target + N) Z``, and its phase absorbs ``psi``; so a cell costs
one bottom amplitude and two normals. ``E[image] = I_bottom + I_target + N``: noise adds
power, reverberation and speckle only redistribute it (docs/physics.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .propagation import absorption_db_per_m

__all__ = ["NoiseModel"]

_MODELS = ("mixture", "rayleigh", "weibull", "k")


@dataclass(frozen=True)
class NoiseModel:
    """How ``SonarFrame.image`` departs from the noise-free ``intensity``. Every part switchable.

    Attributes
    ----------
    reverberation : {"mixture", "rayleigh", "weibull", "k"} or None
        Amplitude model of seabed returns (thesis: Rayleigh mixture). ``None`` leaves
        seabed returns unfluctuating.
    bottom_type : str, optional
        Bottom type of Table 2.2 for every seabed; default: each seabed body's own
        ``Material.bottom_type``.
    target_speckle : bool
        Fully developed (Rayleigh amplitude) speckle on non-seabed returns.
    noise_floor_db : float or None
        Ambient/thermal noise power, in dB relative to the reference level (the median
        positive noise-free echo of the frame, or ``reference_level``), at the median
        echo range. ``None`` switches the noise floor off.
    reference_level : float, optional
        Absolute reference for ``noise_floor_db`` in the image's units, to make the
        noise floor the same across frames.
    tvg_noise : bool
        With ideal TVG (the default propagation) the receiver noise is amplified by the
        TVG gain ``r^2 10^(2 alpha r / 10)``, so it rises with range; ``False`` keeps it flat.
    """

    reverberation: Optional[str] = "mixture"
    bottom_type: Optional[str] = None
    target_speckle: bool = True
    noise_floor_db: Optional[float] = -18.0
    reference_level: Optional[float] = None
    tvg_noise: bool = True

    def __post_init__(self):
        if self.reverberation is not None and self.reverberation not in _MODELS:
            raise ValueError(f"NoiseModel.reverberation: expected one of {_MODELS} or None, got {self.reverberation!r}")
        if self.noise_floor_db is not None and not np.isfinite(self.noise_floor_db):
            raise ValueError(f"NoiseModel.noise_floor_db: must be finite or None, got {self.noise_floor_db!r}")
        if self.reference_level is not None and not (np.isfinite(self.reference_level) and self.reference_level > 0):
            raise ValueError(f"NoiseModel.reference_level: must be > 0, got {self.reference_level!r}")
        if self.bottom_type is not None:
            from .distributions import BOTTOM_TYPES

            if self.bottom_type not in BOTTOM_TYPES:
                raise ValueError(f"NoiseModel.bottom_type: unknown {self.bottom_type!r}; expected one of {sorted(BOTTOM_TYPES)}")

    @classmethod
    def off(cls) -> "NoiseModel":
        """A model that changes nothing (``image == intensity``)."""
        return cls(reverberation=None, target_speckle=False, noise_floor_db=None)

    # ------------------------------------------------------------------ pieces
    def noise_power(self, intensity: np.ndarray, ranges: np.ndarray, frequency: float, propagation: str, water) -> np.ndarray:
        """Mean noise power per range bin, ``(n_bins,)``, in the image's units."""
        if self.noise_floor_db is None:
            return np.zeros(len(ranges), np.float32)
        # medians over every 7th cell: a stable reference at a seventh of the cost
        sub = intensity.reshape(-1)[::7]
        rows = np.arange(0, intensity.size, 7) // intensity.shape[1]
        pos = sub > 0
        if self.reference_level is not None:
            ref = self.reference_level
        else:
            ref = float(np.median(sub[pos])) if pos.any() else 1.0
        r_ref = float(np.median(ranges[rows[pos]])) if pos.any() else float(np.median(ranges))
        level = ref * 10.0 ** (self.noise_floor_db / 10.0)
        if propagation == "tvg" and self.tvg_noise:
            alpha = absorption_db_per_m(frequency, water)
            gain = (ranges / r_ref) ** 2 * 10.0 ** (2.0 * alpha * (ranges - r_ref) / 10.0)
        else:
            gain = np.ones_like(ranges)
        return (level * gain).astype(np.float32)

    def draw(self, shape: tuple, bottom_types, rng: np.random.Generator) -> "NoiseDraws":
        """Draw every random variate the image needs; independent of the echo itself.

        ``simulate_sonar`` runs this in a background thread while it scans the scene.
        The draws come in a fixed order, so a seed gives the same image.
        """
        from .distributions import bottom_model

        x = {}
        if self.reverberation is not None:
            for b in bottom_types:
                if b not in x:
                    x[b] = bottom_model(self.bottom_type or b, self.reverberation).sample(shape, rng, dtype=np.float32)
        z = rng.standard_normal((2,) + tuple(shape), dtype=np.float32)
        phase = None
        if self.reverberation is not None and not self.target_speckle:
            phase = rng.random(shape, dtype=np.float32) * np.float32(2 * np.pi)
        return NoiseDraws(z, x, phase)

    def apply(self, intensity: np.ndarray, *, spec, seabed_share: dict, rng: np.random.Generator | None = None,
              options, draws: "NoiseDraws | None" = None) -> np.ndarray:
        """The noisy image ``(n_bins, n_beams)`` float32 from the noise-free ``intensity``.

        ``seabed_share[bottom_type]`` is the share of each cell's echo returned by seabed
        bodies of that bottom type (``SonarFrame.seabed_share``). Pass either ``draws``
        (from :meth:`draw`) or ``rng``.
        """
        I = np.asarray(intensity, np.float32)
        shape = I.shape
        if draws is None:
            draws = self.draw(shape, list(seabed_share), rng)
        noise = self.noise_power(I, spec.ranges, spec.frequency, options.propagation, options.water)[:, None]
        bottom = np.zeros(shape, np.float32)
        amp_b = np.zeros(shape, np.float32)
        for btype, share in seabed_share.items():
            part = I * share
            bottom += part
            if self.reverberation is not None:
                amp_b += np.sqrt(part) * draws.x[btype]
        target = np.maximum(I - bottom, 0.0)
        if self.reverberation is None:
            if self.target_speckle:
                amp_b = np.sqrt(bottom)
            else:  # nothing fluctuates but the noise: the steady parts add in power
                if self.noise_floor_db is None:
                    return I.copy()
                amp_b = np.sqrt(I)
                target = np.zeros_like(I)
        gauss_power = target + noise if self.target_speckle else np.broadcast_to(noise, shape)
        s = np.sqrt(gauss_power * np.float32(0.5), dtype=np.float32)
        z = draws.z
        re = amp_b + s * z[0]
        im = s * z[1]
        if draws.phase is not None:
            # a steady target echo adds to the fluctuating bottom echo with an independent random phase
            amp_t = np.sqrt(target)
            re += amp_t * np.cos(draws.phase)
            im += amp_t * np.sin(draws.phase)
        re *= re
        im *= im
        re += im
        return re


@dataclass(frozen=True, eq=False)
class NoiseDraws:
    """Random variates of one frame: normals ``z`` (2, n_bins, n_beams), reverberation
    amplitudes ``x[bottom_type]`` (n_bins, n_beams) with ``E[x^2] = 1``, and the phases of
    steady target echoes (only when ``target_speckle`` is off)."""

    z: np.ndarray
    x: dict
    phase: Optional[np.ndarray]


@dataclass(frozen=True)
class ScattererNoise:
    """A device-like image: speckle from scatterer counts, background and gain before the device TVG.

    ``image = TVG(r) | sqrt(g I) f_s + sqrt(B(r)) f_n |^2`` with ``I`` the raw echo
    (simulate with ``SonarOptions(propagation="spreading")`` so that it carries the
    water's losses), ``g`` the source level and receiver gain, ``B`` the receiver noise
    and volume reverberation before the TVG (:class:`~optiacoustic.sonar.gain.DeviceGain`),
    ``f_s`` the unit-power speckle field of the seabed's scatterer counts
    (``sonar.speckle``: Poisson counts of mean ``density x cell area``, filtered by the
    pulse and the two-way azimuth amplitude pattern) and ``f_n`` the background's
    Gaussian field filtered the same way (docs/physics.md, "Speckle from scatterers").

    Attributes
    ----------
    density : float
        Seabed scatterers per square metre; ``inf``: fully developed (Rayleigh) speckle.
    gain : DeviceGain
        Source level, receiver noise, volume reverberation and the device's TVG.
    bottom_type : str, optional
        A Table 2.2 bottom type instead of scatterer counts: its reverberation amplitude
        (thesis, i.i.d. per cell) takes the place of ``f_s``.
    clusters_per_m2 : float
        Independent scatterer clusters per m^2: a cell's count is gamma-mixed Poisson of
        shape ``clusters_per_m2 x cell area`` (``sonar.speckle.cluster_ratio``); ``inf``: none.
    looks : float
        Effective number of independent looks the device averages per stored sample (>= 1).
    """

    density: float = float("inf")
    gain: "DeviceGain" = None  # type: ignore[assignment]
    bottom_type: Optional[str] = None
    clusters_per_m2: float = float("inf")  # issue 10: gamma clustering of the counts (inf: none)
    looks: float = 1.0  # issue 10: independent looks the device averages per sample
    needs_cell_area = True

    def __post_init__(self):
        from .gain import DeviceGain

        if self.gain is None:
            object.__setattr__(self, "gain", DeviceGain())
        if not isinstance(self.gain, DeviceGain):
            raise ValueError(f"ScattererNoise.gain: expected a DeviceGain, got {type(self.gain).__name__}")
        if not (self.density > 0):
            raise ValueError(f"ScattererNoise.density: must be > 0 scatterers/m^2 (or inf), got {self.density!r}")
        if not (self.clusters_per_m2 > 0):
            raise ValueError(f"ScattererNoise.clusters_per_m2: must be > 0 per m^2 (or inf), got {self.clusters_per_m2!r}")
        if not (np.isfinite(self.looks) and self.looks >= 1):
            raise ValueError(f"ScattererNoise.looks: must be a finite number >= 1, got {self.looks!r}")
        if self.bottom_type is not None:
            from .distributions import BOTTOM_TYPES

            if self.bottom_type not in BOTTOM_TYPES:
                raise ValueError(f"ScattererNoise.bottom_type: unknown {self.bottom_type!r}; expected one of {sorted(BOTTOM_TYPES)}")

    def draw(self, shape: tuple, bottom_types, rng: np.random.Generator):
        """The complex normals (drawn while the scene is scanned) and the generator for the
        counts, which depend on the cell areas known only after the scan."""
        return rng.standard_normal(tuple(shape) + (2,), dtype=np.float32), rng

    def kernels(self, spec):
        """Amplitude kernels along range (the pulse) and across beams (two-way ``F^2``)."""
        return _kernels(spec)

    def apply(self, intensity: np.ndarray, *, spec, seabed_share: dict, options, draws=None, rng=None,
              cell_area=None) -> np.ndarray:
        """The image ``(n_bins, n_beams)`` float32, linear intensity after the device's TVG.

        One complex white field carries both parts, ``w = sqrt(g I n / mu + B) z`` (``n``
        the Poisson counts of mean ``mu``, ``z ~ CN(0, 1)``): given the counts the two
        are independent circular Gaussians, so their sum is one with the summed power.
        It is filtered by the pulse and beam kernels and normalised by ``S2 = sum h^2``,
        so a uniform region has mean ``g I + B`` and the moments of :mod:`.speckle`.
        """
        from .propagation import absorption_db_per_m
        from .speckle import filter_complex

        I = np.asarray(intensity, np.float32)
        z, rng = draws if draws is not None else self.draw(I.shape, (), np.random.default_rng(rng))
        h_r, h_b = self.kernels(spec)
        g = self.gain
        alpha = absorption_db_per_m(spec.frequency, options.water) if options.propagation == "spreading" else 0.0
        back = g.background_raw(spec.ranges, alpha).astype(np.float32)[:, None]
        echo = I * np.float32(10.0 ** (g.gain_db / 10.0))
        if self.bottom_type is not None:
            from .distributions import bottom_model

            x = bottom_model(self.bottom_type, "mixture").sample(I.shape, rng, dtype=np.float32)
            power = echo * x * x + back  # Table 2.2 reverberation: i.i.d. amplitudes, as the thesis
            h_r, h_b = np.ones(1), np.ones(1)
        elif cell_area is None or not (np.isfinite(self.density) or np.isfinite(self.clusters_per_m2)):
            power = echo + back
        else:
            from .speckle import cluster_ratio

            area = np.asarray(cell_area, np.float64)
            with np.errstate(invalid="ignore"):  # inf x 0 outside the seabed: no texture there
                ratio = cluster_ratio(self.density * area, self.clusters_per_m2 * area, rng)
            power = echo * np.where(area > 0, ratio, np.float32(1.0)) + back
        # issue 10: the mean image ``echo + back`` is already blurred by the pulse and the beam
        # pattern (formation); filtering the field blurs its power a second time, so the
        # speckle is normalised by that filtered mean and multiplied by the image's own mean
        from .speckle import _filter, look_weights

        mean = echo + back
        expected = _filter(mean, np.asarray(h_r, np.float32) ** 2, np.asarray(h_b, np.float32) ** 2)
        amp = np.sqrt(power * np.float32(0.5))[..., None]
        out = np.zeros(I.shape, np.float32)
        for k, w in enumerate(look_weights(self.looks)):
            zk = z if k == 0 else rng.standard_normal(z.shape, dtype=np.float32)
            f = filter_complex(zk * amp, h_r, h_b)
            out += np.float32(w) * (f[..., 0] * f[..., 0] + f[..., 1] * f[..., 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            out *= np.where(expected > 0, mean / expected, 0.0).astype(np.float32)
        out *= g.tvg(spec.ranges).astype(np.float32)[:, None]
        return out


@functools.lru_cache(maxsize=32)
def _kernels(spec):
    from .speckle import beam_kernel, gaussian_pulse_kernel

    h_r = gaussian_pulse_kernel(spec.pulse_width / spec.bin_width)
    h_b = beam_kernel(spec.azimuth_pattern(), spec.beam_spacing)
    h_r.setflags(write=False)
    h_b.setflags(write=False)
    return h_r, h_b
