"""Sensor profiles: what the simulator needs to look like a real device, fitted from its frames.

``fit_profile(frames)`` estimates (docs/physics.md, "Fitting a sensor profile"):

* the **output encoding** of the stored values (``db``, ``amplitude``, ``root-amplitude``,
  ``linear``): the reading under which the seabed's normalised intensity is single-look
  speckle (contrast >= 1) and closest to a K distribution;
* the **seabed geometry and gain**: height, pitch and roll over a flat seabed, the
  elevation beam width, the echo scale, the range exponent left after the device's TVG,
  the receiver noise and the volume reverberation, by least squares of the analytic
  flat-seabed echo (:mod:`.seabed_echo`), blurred by the pulse and averaged over beams
  like the data, on the range profiles of beam groups (in dB); then, on frames simulated
  with the whole profile and measured like the data, the elevation width set by the seabed
  onset's width (:func:`_refine_onset`) and the height scaled so that the onset and the
  plateau's end sit where the data have them (:func:`_refine_position`);
* the **speckle**: range resolution and azimuth beam width from the autocorrelation
  lengths; the scatterers' clustering (texture shape per cell) and the device's looks
  from the one-point law (contrast and the gamma maximum-likelihood statistic, matched by
  simulating them with :mod:`.speckle` on the device's grid), the clustering then refined
  by simulating whole frames with the profile.

Uncertainties are one standard deviation: the larger of the least-squares covariance
(residual variance inflated by the residuals' correlation length) and a delete-a-block
jackknife over beam groups for the geometry and gain; for the speckle, the statistics'
spread over blocks of cells carried through the inverse Jacobian.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .beampattern import BeamPattern
from .gain import ENCODINGS, DeviceGain, decode, encode
from .realism import beam_groups, frame_statistics
from .seabed_echo import flat_seabed_echo, seabed_pose
from .spec import SonarSpec
from .speckle import check_scatterer_parameters

__all__ = ["SensorProfile", "fit_profile", "PROFILE_VERSION"]

PROFILE_VERSION = 1


@dataclass(frozen=True, eq=False)
class SensorProfile:
    """A device as the simulator should render it. Angles in rad inside, ``*_deg`` in YAML.

    Attributes
    ----------
    spec : SonarSpec
        The device's grid (beam table, range window), frequency, fitted beam patterns
        (``elevation_beam``, ``azimuth_beam``) and range resolution.
    encoding : str
        How the device stores intensity (:data:`gain.ENCODINGS`); ``full_scale`` the
        largest stored value (255 for 8-bit), ``db_range`` the dB span of ``db``.
    gain : DeviceGain
        Gain, receiver noise, volume reverberation and the device's TVG.
    density : float
        Seabed scatterers per m^2 (``inf``: fully developed speckle).
    clusters_per_m2 : float
        Independent scatterer clusters per m^2 (gamma-mixed counts, the seabed's texture;
        ``inf``: none); a cell's K shape is ``clusters_per_m2 x footprint``.
    looks : float
        Effective number of independent looks the device averages per stored sample.
    height, pitch, roll : float
        The sonar over the flat seabed z = 0 that explains the frames (m, rad); NaN
        when the frames do not show a seabed onset.
    uncertainty : dict
        One-sigma uncertainties of the fitted numbers (same units as the YAML).
    stats : dict
        The fitted frames' statistics (``realism.FrameStatistics.summary``).
    notes : tuple of str
        What the fit assumed.
    """

    spec: SonarSpec
    encoding: str = "linear"
    gain: DeviceGain = field(default_factory=DeviceGain)
    density: float = float("inf")
    clusters_per_m2: float = float("inf")
    looks: float = 1.0
    height: float = float("nan")
    pitch: float = float("nan")
    roll: float = 0.0
    full_scale: float = 255.0
    db_range: float = 80.0
    uncertainty: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    notes: tuple = ()
    device: str = ""

    def __post_init__(self):
        from .propagation import check_number

        if not isinstance(self.spec, SonarSpec):
            raise ValueError(f"SensorProfile.spec: expected a SonarSpec, got {type(self.spec).__name__}")
        if not isinstance(self.encoding, str) or self.encoding not in ENCODINGS:
            raise ValueError(f"SensorProfile.encoding: expected one of {ENCODINGS}, got {self.encoding!r}")
        if not isinstance(self.gain, DeviceGain):
            raise ValueError(f"SensorProfile.gain: expected a DeviceGain, got {type(self.gain).__name__}")
        check_scatterer_parameters("SensorProfile", self.density, self.clusters_per_m2, self.looks)
        # full_scale 0: values stored as floats (not rounded or clipped)
        check_number("SensorProfile.full_scale", self.full_scale, 0.0, 1e12)
        check_number("SensorProfile.db_range", self.db_range, 0.0, 1000.0, lo_open=True, unit="dB")
        # NaN: the frames showed no seabed onset (documented); otherwise a height over the seabed and an attitude
        for name, lo, hi, unit in (("height", 0.0, 1e4, "m"), ("pitch", -np.pi / 2, np.pi / 2, "rad"),
                                   ("roll", -np.pi, np.pi, "rad")):
            v = getattr(self, name)
            if not (name != "roll" and _is_nan(v)):
                check_number(f"SensorProfile.{name}", v, lo, hi, lo_open=name == "height", unit=unit)
        if not isinstance(self.device, str):
            raise ValueError(f"SensorProfile.device: expected a string, got {self.device!r}")

    # ------------------------------------------------------------------ use
    @property
    def seabed_pose(self):
        """The sonar's ``Pose`` over the seabed z = 0 (``None`` when the frames show no seabed onset)."""
        if not (np.isfinite(self.height) and np.isfinite(self.pitch)):
            return None
        return seabed_pose(self.height, self.pitch, self.roll)

    def options(self, water=None):
        from .formation import SonarOptions
        from .propagation import Seawater

        return SonarOptions(propagation="spreading", beam_model="aperture", water=water or Seawater())

    def noise(self):
        from .noise import ScattererNoise

        return ScattererNoise(density=self.density, gain=self.gain, clusters_per_m2=self.clusters_per_m2, looks=self.looks)

    def apply_to(self, spec: SonarSpec, options=None, noise=None):
        """``(spec, options, noise)`` for ``simulate_sonar``: the profile's beam patterns and
        range resolution on ``spec`` (its own grid kept); ``options`` / ``noise`` given win."""
        if not isinstance(spec, SonarSpec):
            raise TypeError(f"spec: expected a SonarSpec, got {type(spec).__name__}")
        spec = dataclasses.replace(spec, elevation_beam=self.spec.elevation_pattern(), azimuth_beam=self.spec.azimuth_pattern(),
                                   range_resolution=self.spec.range_resolution, frequency=self.spec.frequency,
                                   fov_elevation=self.spec.fov_elevation, beamwidth_azimuth=self.spec.beamwidth_azimuth)
        return spec, options or self.options(), self.noise() if noise is None else noise

    def simulation_spec(self) -> SonarSpec:
        """The device's spec with enough elevation samples to resolve the elevation main lobe."""
        from .formation import elevation_samples_for

        n = int(np.clip(elevation_samples_for(self.spec, "aperture", 24), 64, 512))
        return dataclasses.replace(self.spec, elevation_samples=n)

    def simulate(self, *, seed=None, pose=None, scene=None):
        """A frame of the flat seabed (reflectivity 1) at ``seabed_pose`` (or ``pose``) as this device."""
        from ..scene import Body, Material, Plane, Scene
        from .formation import simulate_sonar

        pose = pose if pose is not None else self.seabed_pose
        if pose is None:
            raise ValueError("SensorProfile.simulate: the profile has no seabed pose; pass pose=")
        if scene is None:
            size = 4 * self.spec.range_max + 10
            scene = Scene([Body("seabed", Plane(size=(size, size)), material=Material(reflectivity=1.0))])
        return simulate_sonar(scene, self.simulation_spec(), pose, seed=seed, profile=self)

    def to_device(self, image) -> np.ndarray:
        """Linear intensity -> the values the device would store (rounded and clipped when integer)."""
        v = encode(image, self.encoding, 1.0, self.db_range, self.full_scale)
        if self.full_scale > 0:
            v = np.clip(np.round(v), 0, self.full_scale)
        return v

    def from_device(self, values) -> np.ndarray:
        """Device values -> linear intensity (the profile's reading)."""
        return decode(values, self.encoding, 1.0, self.db_range, self.full_scale)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        from .frame import spec_to_dict

        sd = spec_to_dict(self.spec)
        for k in ("elevation_beam", "azimuth_beam"):
            sd[k] = getattr(self.spec, k).to_dict() if getattr(self.spec, k) is not None else None
        for k in ("fov_azimuth", "fov_elevation", "beamwidth_azimuth"):
            sd[k + "_deg"] = float(np.rad2deg(sd.pop(k)))
        if sd.get("beam_azimuths") is not None:
            sd["beam_azimuths_deg"] = [float(np.rad2deg(a)) for a in sd.pop("beam_azimuths")]
        else:
            sd.pop("beam_azimuths", None)
        if sd.get("bin_ranges") is None:
            sd.pop("bin_ranges", None)
        return {
            "optiacoustic_sensor_profile": PROFILE_VERSION,
            "device": self.device,
            "encoding": self.encoding,
            "full_scale": float(self.full_scale),
            "db_range": float(self.db_range),
            "density_per_m2": None if not np.isfinite(self.density) else float(self.density),
            "clusters_per_m2": None if not np.isfinite(self.clusters_per_m2) else float(self.clusters_per_m2),
            "looks": float(self.looks),
            "seabed": {"height": _num(self.height), "pitch_deg": _num(np.rad2deg(self.pitch)),
                       "roll_deg": _num(np.rad2deg(self.roll))},
            "gain": {k: _num(v) for k, v in self.gain.to_dict().items()},
            "spec": sd,
            "uncertainty": {k: _num(v) for k, v in self.uncertainty.items()},
            "stats": {k: _num(v) for k, v in self.stats.items()},
            "notes": list(self.notes),
        }

    def save(self, path) -> Path:
        """Write the profile as YAML (atomically)."""
        import yaml

        from .._atomic import write_text

        return write_text(path, yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=110))

    @classmethod
    def load(cls, path) -> "SensorProfile":
        """Read a profile YAML written by :meth:`save` (or a preset's name, ``SensorProfile.preset``).

        Read by the project's one configuration reader (``optiacoustic._config.load_config``: size
        limit, duplicate keys refused, UTF-8); a ValueError names the file and the field."""
        from .._config import load_config

        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"sensor profile {path}: no such file")
        data = load_config(path, what="sensor profile")
        return cls.from_dict(data, source=str(path))

    @classmethod
    def from_dict(cls, data, source: str = "sensor profile") -> "SensorProfile":
        """A profile from the mapping :meth:`to_dict` writes; a ValueError names ``source`` and the field."""
        from .spec import _is_number

        if not isinstance(data, dict) or "optiacoustic_sensor_profile" not in data:
            raise ValueError(f"{source}: not a sensor profile (no 'optiacoustic_sensor_profile' field)")
        version = data["optiacoustic_sensor_profile"]
        if not _is_number(version) or version != PROFILE_VERSION:
            raise ValueError(f"{source}: field 'optiacoustic_sensor_profile': version {version!r} is not supported "
                             f"(this optiacoustic reads version {PROFILE_VERSION})")
        unknown = sorted(set(data) - set(_PROFILE_FIELDS), key=str)
        if unknown:
            raise ValueError(f"{source}: field {unknown[0]!r}: unknown; a sensor profile has {list(_PROFILE_FIELDS)}")

        def mapping(key):
            v = data.get(key)
            if v is None:
                return {}
            if not isinstance(v, dict):
                raise ValueError(f"{source}: field '{key}': expected a mapping, got {v!r}")
            return v

        def number(key, v, default=None, none_is=None):
            if v is None:
                return none_is if default is None else default
            if not _is_number(v):  # `true` is not 1, "abc" not a number
                raise ValueError(f"{source}: field '{key}': expected a number{' or null' if none_is is not None else ''}, "
                                 f"got {v!r}")
            return float(v)

        def numbers(key):
            out = {}
            for k, v in mapping(key).items():
                if v is not None and not _is_number(v):
                    raise ValueError(f"{source}: field '{key}.{k}': expected a number or null, got {v!r}")
                out[str(k)] = _nan(v)
            return out

        spec_d = data.get("spec")
        if not isinstance(spec_d, dict):
            raise ValueError(f"{source}: field 'spec': expected a mapping, got {spec_d!r}")
        spec = SonarSpec.from_dict(dict(spec_d), source=f"{source}: spec")
        g = mapping("gain")
        try:
            gain = DeviceGain(**{str(k): v for k, v in g.items()})
        except TypeError:
            bad = sorted(set(map(str, g)) - {f.name for f in dataclasses.fields(DeviceGain)})
            raise ValueError(f"{source}: field 'gain.{bad[0] if bad else '?'}': unknown; gain has "
                             f"{[f.name for f in dataclasses.fields(DeviceGain)]}") from None
        except ValueError as exc:
            raise ValueError(f"{source}: field 'gain': {exc}") from None
        sb = mapping("seabed")
        unknown = sorted(set(map(str, sb)) - {"height", "pitch_deg", "roll_deg"})
        if unknown:
            raise ValueError(f"{source}: field 'seabed.{unknown[0]}': unknown; seabed has height, pitch_deg, roll_deg")
        notes = data.get("notes") or ()
        if not isinstance(notes, (list, tuple)) or not all(isinstance(n, str) for n in notes):
            raise ValueError(f"{source}: field 'notes': expected a list of strings, got {notes!r}")
        device = data.get("device", "")
        if device is None:
            device = ""
        if not isinstance(device, (str, int, float)) or isinstance(device, bool):
            raise ValueError(f"{source}: field 'device': expected a name, got {device!r}")
        encoding = data.get("encoding", "linear")
        if not isinstance(encoding, str):
            raise ValueError(f"{source}: field 'encoding': expected one of {ENCODINGS}, got {encoding!r}")
        kw = dict(spec=spec, encoding=encoding, gain=gain,
                  density=number("density_per_m2", data.get("density_per_m2"), none_is=float("inf")),
                  clusters_per_m2=number("clusters_per_m2", data.get("clusters_per_m2"), none_is=float("inf")),
                  looks=number("looks", data.get("looks"), 1.0),
                  height=number("seabed.height", sb.get("height"), none_is=float("nan")),
                  pitch=float(np.deg2rad(number("seabed.pitch_deg", sb.get("pitch_deg"), none_is=float("nan")))),
                  roll=float(np.deg2rad(number("seabed.roll_deg", sb.get("roll_deg"), none_is=0.0))),
                  full_scale=number("full_scale", data.get("full_scale"), 255.0),
                  db_range=number("db_range", data.get("db_range"), 80.0),
                  uncertainty=numbers("uncertainty"), stats=numbers("stats"), notes=tuple(notes), device=str(device))
        try:
            return cls(**kw)
        except ValueError as exc:  # "SensorProfile.height: ..." -> the file's field
            msg = str(exc)
            for attr, key in (("height", "seabed.height"), ("pitch", "seabed.pitch_deg"), ("roll", "seabed.roll_deg"),
                              ("density", "density_per_m2")):
                if msg.startswith(f"SensorProfile.{attr}:"):
                    if attr in ("pitch", "roll"):
                        msg = f"{np.rad2deg(kw[attr]):g} deg is outside " + (
                            "[-90, 90] deg" if attr == "pitch" else "[-180, 180] deg")
                    else:
                        msg = msg[len(f"SensorProfile.{attr}:"):].strip()
                    raise ValueError(f"{source}: field '{key}': {msg}") from None
            if msg.startswith("SensorProfile."):
                field_name = msg.split(":", 1)[0][len("SensorProfile."):]
                raise ValueError(f"{source}: field '{field_name}': {msg.split(':', 1)[1].strip()}") from None
            raise ValueError(f"{source}: {msg}") from None

    @classmethod
    def preset(cls, name: str) -> "SensorProfile":
        """A profile shipped with the package (``SensorProfile.preset_names()``)."""
        p = _PROFILE_DIR / f"{name}.yaml"
        if not p.exists():
            raise KeyError(f"unknown sensor profile {name!r}; profiles are {cls.preset_names()}")
        return cls.load(p)

    @staticmethod
    def preset_names() -> list[str]:
        return sorted(p.stem for p in _PROFILE_DIR.glob("*.yaml"))


_PROFILE_DIR = Path(__file__).resolve().parent.parent / "data" / "sonar_profiles"
#: The top-level fields of a profile file (:meth:`SensorProfile.to_dict`).
_PROFILE_FIELDS = ("optiacoustic_sensor_profile", "device", "encoding", "full_scale", "db_range", "density_per_m2",
                   "clusters_per_m2", "looks", "seabed", "gain", "spec", "uncertainty", "stats", "notes")


def _is_nan(x) -> bool:
    try:
        return bool(np.isnan(x))
    except TypeError:
        return False


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def _nan(x, default=float("nan")):
    return default if x is None else float(x)


# =========================================================================== fitting
def _values(frame, encoding):
    raw = getattr(frame, "raw", None)
    if raw is None:
        return np.asarray(frame.image, float)
    return decode(raw, encoding)


def _candidate_encodings(frame) -> list[str]:
    raw = getattr(frame, "raw", None)
    if raw is None:
        return ["linear"]
    enc = str(getattr(frame, "encoding", "")).lower()
    if "db" in enc:
        return ["db"]
    return ["amplitude", "root-amplitude", "linear"]


def _k_cdf(z, nu):
    """CDF of a unit-mean K-distributed intensity of shape ``nu`` (exponential when inf)."""
    from scipy.special import gammaln, kv

    z = np.maximum(np.asarray(z, float), 1e-12)  # K_nu overflows at 0: the CDF there is ~0 anyway
    if not np.isfinite(nu) or nu > 200:
        return 1 - np.exp(-z)
    x = 2 * np.sqrt(nu * z)
    with np.errstate(over="ignore", invalid="ignore"):
        tail = 2 * np.exp((nu / 2) * np.log(nu * z) - gammaln(nu)) * kv(nu, x)
    return np.clip(1 - np.nan_to_num(tail), 0, 1)


def _choose_encoding(frames, region):
    """Encoding whose normalised seabed intensity is single-look speckle closest to a K law."""
    from scipy.stats import kstest

    cands = _candidate_encodings(frames[0])
    scores = {}
    for enc in cands:
        st = frame_statistics([_values(f, enc) for f in frames], frames[0].ranges, frames[0].azimuths, region=region)
        c = st.contrast
        if not np.isfinite(c):
            continue
        z = st.normalised
        z = z[:: max(1, z.size // 50000)]
        ks = kstest(z / z.mean(), lambda x: _k_cdf(x, st.k_shape)).statistic
        scores[enc] = (c >= 0.97, -ks, st)
    if not scores:
        return cands[0], None, {}
    best = max(scores, key=lambda e: scores[e][:2])
    return best, scores[best][2], {e: {"contrast": float(v[2].contrast), "ks_to_k": float(-v[1])} for e, v in scores.items()}


def _tvg_water_absorption(spec):
    from .propagation import absorption_db_per_m

    return float(absorption_db_per_m(spec.frequency))


#: 10 / ln 10: dB per neper of intensity
_DB = 10.0 / np.log(10.0)
# Private measurement switches of the polish (docs/physics.md 4.5, "The intensity-domain fit,
# measured"): read by tests/sonar/profile_gain_monte_carlo.py, off in the shipped estimator.
_DEVIANCE = [False]  # gamma-deviance residuals instead of dB differences
_LOGBIAS = [False]  # dB residuals with each bin's derived log bias removed
_LOSS = ["soft_l1", 3.0]  # the polish's robust loss and its scale, dB


def _log_bias_db(stats, idx):
    """Expected ``10 log10 m - 10 log10 E m`` of the groups' profiles at bins ``idx``, dB, for a
    gamma-distributed mean of shape ``k = N_eff / CV^2`` (docs/derivations.md): ``CV^2`` from the
    groups' mean squares (smoothed along range), ``N_eff`` the group's beams over their
    correlation spread, times the frames."""
    from scipy.special import digamma

    from .realism import _smooth1

    w = max(5, len(stats.ranges) // 100)
    m = _smooth1(np.asarray(stats.group_profiles, float), w, 0)
    m2 = _smooth1(np.asarray(stats.group_sq_profiles, float), w, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cv2 = np.where(m > 0, np.maximum(m2 / np.square(m) - 1.0, 1e-3), 1.0)[idx]
    rho = np.nan_to_num(np.clip(np.asarray(stats.corr_beam, float)[1:], 0.0, 1.0))

    def spread(n):
        lags = np.arange(1, min(len(rho), int(n) - 1) + 1) if n > 1 else np.arange(0)
        return 1.0 + 2.0 * float(np.sum((1.0 - lags / n) * rho[: lags.size]))

    n_eff = np.array([nb / spread(nb) for nb in stats.group_beams]) * stats.n_images
    k = n_eff[None, :] / cv2
    return _DB * (digamma(k) - np.log(k))


def _fit_geometry(stats, spec, alpha, azimuths=None, pulse_bins=None):
    """Least squares of the flat-seabed echo + background on the beam groups' range profiles (dB).

    The model is measured the way the data are: the analytic echo of every range bin,
    blurred along range by the pulse (Gaussian power of FWHM ``pulse_bins``, as the image
    formation does), averaged over beams of each group (up to 4 per group) like the
    groups' profiles, then sampled at the fitted ranges. Without the blur and the
    averaging the sharp nulls of the elevation pattern and the onset's curvature across a
    group pull the fit low: 3-7 % in height and width, 1-2 deg in pitch on simulated
    seabeds (docs/physics.md 4.4).
    """
    from scipy.ndimage import gaussian_filter1d
    from scipy.optimize import least_squares

    r_all = stats.ranges
    n_sub = max(1, len(r_all) // 160)
    idx = np.arange(0, len(r_all), n_sub)
    r = r_all[idx]
    prof = stats.group_profiles[idx]
    ok = (r > 0) & np.all(prof > 0, axis=1)
    r, prof, idx = r[ok], prof[ok], idx[ok]
    az = stats.group_azimuths
    data_db = 10 * np.log10(prof)
    if _LOGBIAS[0] and stats.group_sq_profiles is not None:
        data_db = data_db - _log_bias_db(stats, idx)
    c, f = spec.sound_speed, spec.frequency
    r0 = 1.0
    G = prof.shape[1]
    if azimuths is None:
        az_cols, seg = az, np.arange(G)
    else:
        groups = beam_groups(len(azimuths))
        picks = [g[np.unique(np.round(np.linspace(0, len(g) - 1, min(len(g), 4))).astype(int))] for g in groups]
        az_cols = np.asarray(azimuths, float)[np.concatenate(picks)]
        seg = np.repeat(np.arange(len(picks)), [len(p) for p in picks])
    counts = np.bincount(seg, minlength=G).astype(float)
    sigma = max((spec.pulse_width / spec.bin_width if pulse_bins is None else float(pulse_bins)) / 2.3548, 0.5)

    def seabed(h, pitch, roll, pat):
        E = flat_seabed_echo(r_all, az_cols, h, pitch, roll, pat)
        E = gaussian_filter1d(E, sigma, axis=0, mode="constant", truncate=3.5)
        Eg = np.zeros((E.shape[0], G))
        np.add.at(Eg.T, seg, E.T)
        return (Eg / counts)[idx]

    cheap = [False]  # the starts use the echo at the groups' centres, unblurred; the polish the full model

    def model_lin(x):
        h, pitch, roll, lbw, a_db, kexp, n_db, v_db = x
        pat = BeamPattern.from_beamwidth(float(np.exp(lbw)), f, c)
        E = flat_seabed_echo(r, az, h, pitch, roll, pat) if cheap[0] else seabed(h, pitch, roll, pat)
        rk = (r / r0) ** kexp
        tvg = (r / r0) ** (kexp + 2.0) * 10 ** (2 * alpha * (r - r0) / 10)
        out = 10 ** (a_db / 10) * rk[:, None] * E + (10 ** (n_db / 10) * tvg + 10 ** (v_db / 10) * rk)[:, None]
        return np.maximum(out, 1e-30)

    def model(x):
        return 10 * np.log10(model_lin(x))

    has_onset = bool(np.isfinite(stats.onset_r10))

    def misfit(x):
        """Residuals (n_bins, n_groups) in dB-like units: the starts take the difference of the
        dB; the polish the signed gamma deviance residual of the measured mean against the
        model's mean intensity (docs/derivations.md, "Fitting the range profile in the
        intensity domain"), whose estimating equation is unbiased for any number of looks."""
        if cheap[0] or not _DEVIANCE[0]:
            return model(x) - data_db
        mu = model_lin(x)
        q = prof / mu
        return _DB * np.sign(q - 1.0) * np.sqrt(2.0 * np.maximum(q - 1.0 - np.log(q), 0.0))

    def resid(x):
        res = misfit(x).ravel()
        if has_onset:
            return res
        # no onset in the window: the seabed lies in the elevation main lobe (inside its
        # -3 dB edges) from the window's start to its end
        h, pitch, _, lbw = x[:4]
        half = 0.5 * np.exp(lbw)
        dep = np.arcsin(np.clip(h / np.array([max(spec.range_min, h), spec.range_max]), 0, 1)) - pitch
        excess = np.maximum(0.0, np.abs(dep) - half)
        return np.append(res, 100.0 * excess * np.sqrt(res.size))

    bg = stats.background_level if np.isfinite(stats.background_level) else float(np.percentile(prof, 5))
    peak_i = int(np.argmax(prof.mean(1)))
    r_peak = r[peak_i]
    bw0 = spec.fov_elevation
    lo = [0.05, np.deg2rad(-10), np.deg2rad(-45), np.log(np.deg2rad(0.5)), -200, -6, -200, -200]
    hi = [0.99 * spec.range_max, np.deg2rad(85), np.deg2rad(45), np.log(np.deg2rad(60)), 200, 6, 200, 200]
    if not has_onset:  # roll cannot be seen without an onset: hold it at 0
        lo[2], hi[2] = -1e-6, 1e-6
        # nor the elevation width: the profile of a seabed inside the main lobe is explained by
        # any width (a stated sigma of hundreds of degrees), and which one the starts reached
        # changed with a 0.07 dB offset of the data (on the ARIS sample: 18.3 deg at height
        # 0.75 m, or 2.6 deg at 0.10 m); hold the device's nominal width
        lbw_nom = float(np.log(np.clip(spec.fov_elevation, np.deg2rad(0.6), np.deg2rad(59.0))))
        lo[3], hi[3] = lbw_nom - 1e-6, lbw_nom + 1e-6
    best = None
    cheap[0] = True
    for pitch0 in np.deg2rad([8, 20, 40]):
        if has_onset:
            h0 = r_peak * np.sin(pitch0)
        else:
            pitch0 = 0.3 * pitch0
            h0 = spec.range_min * np.sin(pitch0)
        h0 = float(np.clip(h0, lo[0] * 1.01, hi[0] * 0.99))
        pat = BeamPattern.from_beamwidth(bw0, f, c)
        E0 = float(seabed(h0, pitch0, 0.0, pat)[peak_i].mean())
        a0 = 10 * np.log10(max(prof.max(), 1e-30) / max(E0, 1e-30))
        x0 = np.array([h0, pitch0, 0.0, np.log(bw0), np.clip(a0, -190, 190), 0.0,
                       10 * np.log10(max(bg, 1e-30)), 10 * np.log10(max(bg, 1e-30)) - 10])
        x0 = np.clip(x0, np.array(lo) + 1e-6, np.array(hi) - 1e-6)
        try:
            sol = least_squares(resid, x0, bounds=(lo, hi), loss="soft_l1", f_scale=3.0, x_scale="jac", max_nfev=120)
        except ValueError:
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    cheap[0] = False
    if best is None:  # every start was refused (a window or a profile that no seabed explains)
        raise ValueError(f"the seabed's geometry cannot be fitted: no start of the fit is feasible for the window "
                         f"{spec.range_min:.3g}-{spec.range_max:.3g} m and the frames' echo profile")
    # typical scales of the parameters: with x_scale="jac" the polish crawls along the
    # valley where height, pitch and width trade off
    x_typ = np.array([0.01, 0.01, 0.01, 0.02, 1.0, 0.05, 1.0, 1.0])
    try:
        best = least_squares(resid, best.x, bounds=(lo, hi), loss=_LOSS[0], f_scale=_LOSS[1], x_scale=x_typ, max_nfev=100,
                             method="dogbox")
    except ValueError:
        pass
    # (a polish on relative residuals of the linear profiles, unbiased for pure speckle, was
    # tried: on the real Oculus ping its asymmetry lifted the background by 30 dB; the dB fit stays)

    def resid_cols(x, cols=slice(None)):
        res = misfit(x)[:, cols].ravel()
        return np.append(res, resid(x)[data_db.size:]) if not has_onset else res

    # delete-one-group jackknife: the groups' profiles carry speckle and texture fluctuations
    # correlated along range that the least-squares covariance, which takes residuals as
    # independent, does not see
    # (delete-a-block: 8 blocks of neighbouring groups, each left out once)
    G = prof.shape[1]
    jk = []
    for blk in np.array_split(np.arange(G), min(8, G)):
        keep = ~np.isin(np.arange(G), blk)
        try:
            jk.append(least_squares(resid_cols, best.x, bounds=(lo, hi), loss=_LOSS[0], f_scale=_LOSS[1], x_scale=x_typ, method="dogbox",
                                    max_nfev=30, kwargs={"cols": keep}).x)
        except ValueError:
            continue
    jk = np.asarray(jk)
    sd_jk = np.sqrt((len(jk) - 1) / len(jk) * ((jk - jk.mean(0)) ** 2).sum(0)) if len(jk) > 2 else np.zeros(best.x.size)
    x = best.x
    J = best.jac
    res = best.fun
    dof = max(1, res.size - x.size)
    s2 = float(np.sum(res**2) / dof)
    infl = max(1.0, 2.0 * stats.corr_length_range / n_sub)  # residuals are correlated over the speckle grain
    try:
        cov = np.linalg.pinv(J.T @ J) * s2 * infl
        sd = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sd = np.full(x.size, np.inf)
    sd = np.maximum(sd, sd_jk)
    # a parameter the profile does not depend on (e.g. a volume reverberation 100 dB under the
    # noise) has a zero Jacobian column, which pinv turns into a zero variance: undetermined
    col = np.sqrt(np.sum(np.asarray(J, float) ** 2, axis=0))
    sd = np.where(col <= 1e-9 * max(float(np.max(col)), 1e-300), np.inf, sd)
    s2 = float(np.mean((model(x) - data_db) ** 2))  # reported: rms misfit in dB
    return x, sd, has_onset, model(x), r, float(np.sqrt(s2))


def _invert(fn, target, lo, hi):
    """Solve ``fn(x) = target`` on a log grid then refine (monotone ``fn``); clamps at the ends."""
    xs = np.geomspace(lo, hi, 40)
    ys = np.array([fn(x) for x in xs])
    if target <= ys[0]:
        return float(xs[0]), True
    if target >= ys[-1]:
        return float(xs[-1]), True
    i = int(np.flatnonzero(ys >= target)[0])
    t = (target - ys[i - 1]) / (ys[i] - ys[i - 1])
    return float(np.exp(np.log(xs[i - 1]) + t * (np.log(xs[i]) - np.log(xs[i - 1])))), False


def _range_resolution_bins(stats):
    """Range resolution (bins) whose analytic range correlation length is the measured one."""
    from .speckle import analytic_autocorrelation, correlation_length, gaussian_pulse_kernel

    lags = np.arange(13)

    def len_range(res_bins):
        return correlation_length(analytic_autocorrelation(np.inf, gaussian_pulse_kernel(res_bins), [1.0], lags, 0))

    return _invert(len_range, stats.corr_length_range, 0.3, 40.0)


def _texture_field(shape, cluster_shape, looks, h_r, h_b, u_tex, normals):
    """Bare speckle of clustered scatterers and ``looks`` on a patch, from fixed random numbers
    (common random numbers: the statistics are smooth in the parameters)."""
    from scipy.stats import gamma

    from .speckle import _filter, look_weights

    T = gamma.ppf(u_tex, cluster_shape) / cluster_shape if np.isfinite(cluster_shape) and cluster_shape < 1e4 else np.ones(shape)
    amp = np.sqrt(T)
    out = np.zeros(shape)
    for k, w in enumerate(look_weights(looks)):
        re = _filter(amp * normals[k, 0], h_r, h_b)
        im = _filter(amp * normals[k, 1], h_r, h_b)
        out += w * (re * re + im * im)
    return out


def _fit_speckle(stats, spec, height, rng):
    """Range resolution, azimuth beam width, scatterer clustering and device looks from the speckle.

    The correlation lengths give the range resolution and the azimuth beam width (analytic,
    :mod:`.speckle`). The one-point law of the normalised intensity gives the clustering
    shape per cell ``nu_c`` and the looks ``L`` by indirect inference: two statistics, the
    contrast and the maximum-likelihood gamma shape's sufficient statistic
    ``log mean(z) - mean(log z)`` (``speckle.speckle_statistics``, ``scipy.stats.gamma.fit``),
    are matched between the data and bare fields simulated on the device's grid with the
    same kernels and the same local-mean normalisation (``scipy.optimize.least_squares``
    on common random numbers). Uncertainties: the statistics' spread over 8 blocks of cells
    carried through the inverse Jacobian.
    """
    from scipy.ndimage import uniform_filter
    from scipy.optimize import least_squares

    from .speckle import analytic_autocorrelation, beam_kernel, correlation_length, gaussian_pulse_kernel, speckle_statistics

    lags = np.arange(13)
    L_b = stats.corr_length_beam

    def len_beam(bw):
        k = beam_kernel(BeamPattern.from_beamwidth(bw, spec.frequency, spec.sound_speed), spec.beam_spacing)
        return correlation_length(analytic_autocorrelation(np.inf, [1.0], k, lags, 1))

    res_bins, res_clamped = _range_resolution_bins(stats)
    bw, bw_clamped = _invert(len_beam, L_b, 0.1 * spec.beam_spacing, 30 * spec.beam_spacing)
    h_r = gaussian_pulse_kernel(res_bins)
    h_b = beam_kernel(BeamPattern.from_beamwidth(bw, spec.frequency, spec.sound_speed), spec.beam_spacing)
    n_bins, n_beams = stats.region.shape
    w_r = max(5, n_bins // 100)
    w_b = max(3, n_beams // 24)
    shape = (min(n_bins, 400), n_beams)
    crng = np.random.default_rng(12345)
    u_tex = crng.random(shape)
    normals = crng.standard_normal((8, 2) + shape)  # up to 8 looks

    def sim_stats(log_nu, looks):
        f = _texture_field(shape, float(np.exp(log_nu)), float(min(looks, 8.0)), h_r, h_b, u_tex, normals)
        m = uniform_filter(f, (w_r * 3, w_b), mode="nearest")
        with np.errstate(invalid="ignore", divide="ignore"):
            z = (f / m)[w_r * 2: -w_r * 2, w_b // 2 + 1: -(w_b // 2 + 1)]
        st = speckle_statistics(z.ravel())
        return np.array([st["contrast"], st["log_ratio"]])

    z = stats.normalised
    meas = speckle_statistics(z)
    target = np.array([meas["contrast"], meas["log_ratio"]])
    blocks = [speckle_statistics(b) for b in np.array_split(z, 8)]
    bs = np.array([[b["contrast"], b["log_ratio"]] for b in blocks if np.isfinite(b["contrast"])])
    cov_t = np.cov(bs.T) / len(bs) if len(bs) > 2 else np.full((2, 2), np.nan)
    lo, hi = np.array([np.log(0.01), 1.0]), np.array([np.log(1e4), 8.0])
    # coarse grid, then a least-squares polish from its best point
    grid = [(a, b) for a in np.log([0.05, 0.3, 2.0, 1e3]) for b in (1.0, 2.0, 4.0)]
    gerr = [float(np.sum(((sim_stats(a, b) - target) / 0.01) ** 2)) for a, b in grid]
    x0 = np.clip(np.array(grid[int(np.nanargmin(gerr))]), lo + 1e-6, hi - 1e-6)
    sol = least_squares(lambda p: (sim_stats(*p) - target) / np.array([0.01, 0.01]), x0, bounds=(lo, hi),
                        diff_step=np.array([0.05, 0.05]), max_nfev=25)
    log_nu, looks = sol.x
    try:
        Jinv = np.linalg.pinv(sol.jac * 0.01)  # d(params)/d(stats)
        cov_p = Jinv @ cov_t @ Jinv.T
        sd_log_nu, sd_looks = np.sqrt(np.maximum(np.diag(cov_p), 0))
    except (np.linalg.LinAlgError, ValueError):
        sd_log_nu, sd_looks = np.nan, np.nan
    achieved = sim_stats(log_nu, looks)
    nu_c = float(np.exp(log_nu))
    # typical seabed area of a grid cell in the speckle region (flat seabed; median: cells
    # near the nadir range r ~ h have huge footprints and few echoes)
    rows = np.repeat(stats.ranges[:, None], stats.region.shape[1], 1)[stats.region]
    rows = rows[rows > 0]
    if rows.size and np.isfinite(height) and height > 0:
        rr = np.maximum(rows, 1.05 * height)
        area = float(np.median(rr * spec.beam_spacing * spec.bin_width * rr / np.sqrt(rr**2 - height**2)))
    elif rows.size:
        area = float(np.median(rows * spec.beam_spacing * spec.bin_width))
    else:
        area = float("nan")
    at_bound = nu_c >= 0.99e4
    clusters = np.inf if at_bound or not np.isfinite(area) else nu_c / area
    return dict(res_bins=res_bins, res_clamped=res_clamped, bw=bw, bw_clamped=bw_clamped,
                cluster_shape=nu_c, cluster_shape_sd_rel=float(sd_log_nu), clusters=clusters,
                clusters_sd=float(sd_log_nu * clusters) if np.isfinite(clusters) else np.nan,
                looks=float(looks), looks_sd=float(sd_looks), cell_area=area, measured=meas,
                matched=achieved.tolist(), gamma_shape=meas["gamma_shape"])


def fit_profile(frames, *, region=None, encoding: str | None = None, device: str = "",
                refine_density: bool = True) -> SensorProfile:
    """Fit a :class:`SensorProfile` to real (or simulated) frames.

    Parameters
    ----------
    frames : frame or sequence of frames
        Measured (``MeasuredSonarFrame``, with ``.raw``) or simulated frames of one
        device, all on the same grid.
    region : bool array ``(n_bins, n_beams)`` or (r_min, r_max) tuple, optional
        Where the speckle statistics are taken (default: the seabed cells found, local
        mean 10 dB over the background).
    encoding : str, optional
        Force the stored values' reading (:data:`gain.ENCODINGS`); default: chosen.
    device : str, optional
        Name written into the profile (default the spec's name).
    refine_density : bool
        Refine, by simulating frames with the whole profile, the elevation width (onset
        width), the height and echo gain (onset and plateau-end positions) and the scatterer
        clustering (the texture); about 30 simulations, off for a quick fit.
    """
    if not isinstance(frames, (list, tuple)):
        frames = [frames]
    if not frames:
        raise ValueError("fit_profile: no frames")
    f0 = frames[0]
    for i, f in enumerate(frames):
        if np.shape(f.image) != np.shape(f0.image):
            raise ValueError(f"fit_profile: frame {i} has shape {np.shape(f.image)}, frame 0 {np.shape(f0.image)}")
    spec = f0.spec
    n_bins, n_beams = np.shape(f0.image)
    if region is not None and not (isinstance(region, np.ndarray) and region.dtype == bool):
        try:
            r_lo, r_hi = (float(v) for v in region)
        except (TypeError, ValueError):
            raise ValueError(f"fit_profile: region must be a bool mask {(n_bins, n_beams)} or (r_min, r_max), got {region!r}") from None
        w_lo, w_hi = float(f0.ranges[0]), float(f0.ranges[-1])
        if not (np.isfinite(r_lo) and np.isfinite(r_hi) and r_lo < r_hi):
            raise ValueError(f"fit_profile: region (r_min, r_max) = ({r_lo:g}, {r_hi:g}) m: expected finite ranges "
                             f"with r_min < r_max")
        if r_hi < w_lo or r_lo > w_hi:
            raise ValueError(f"fit_profile: region {r_lo:g}-{r_hi:g} m lies outside the frames' range window "
                             f"{w_lo:.4g}-{w_hi:.4g} m")
        region = np.broadcast_to(((f0.ranges >= r_lo) & (f0.ranges <= r_hi))[:, None], (n_bins, n_beams)).copy()
    elif region is not None and region.shape != (n_bins, n_beams):
        raise ValueError(f"fit_profile: region mask shape {region.shape}, expected {(n_bins, n_beams)}")
    notes = []
    if encoding is None:
        encoding, stats, tried = _choose_encoding(frames, region)
        if len(tried) > 1:
            notes.append("encoding chosen among " + ", ".join(f"{e} (contrast {v['contrast']:.3g}, KS to K {v['ks_to_k']:.3g})"
                                                               for e, v in tried.items()))
    else:
        if encoding not in ENCODINGS:
            raise ValueError(f"fit_profile: encoding must be one of {ENCODINGS}, got {encoding!r}")
        stats = None
    if stats is None:
        stats = frame_statistics([_values(f, encoding) for f in frames], f0.ranges, f0.azimuths, region=region)
    if stats.normalised.size < 100:  # the texture fit needs speckle cells (realism.frame_statistics)
        raise ValueError(
            f"fit_profile: {stats.normalised.size} speckle cells in the frames: the texture is taken where the local mean is "
            f"10 dB over the background ({stats.background_level:.3g}, read before the seabed's onset at {stats.onset_r10:.3g} m)"
            + (" inside the given region" if region is not None else "")
            + "; the frames' window must hold echo-free water before the seabed's echo and speckled seabed after it")
    alpha = _tvg_water_absorption(spec)
    res0, _ = _range_resolution_bins(stats)
    x, sd, has_onset, _, _, rms_db = _fit_geometry(stats, spec, alpha, azimuths=f0.azimuths, pulse_bins=res0)
    h, pitch, roll, lbw, a_db, kexp, n_db, v_db = x
    if not has_onset:
        notes.append("no seabed onset in the frames: roll held at 0 and the elevation width at the device's nominal "
                     f"{np.rad2deg(spec.fov_elevation):.3g} deg (their stated sigmas are what they would be if fitted); "
                     "height and pitch weakly determined")
    sp = _fit_speckle(stats, spec, h, np.random.default_rng(0))
    el = BeamPattern.from_beamwidth(float(np.exp(lbw)), spec.frequency, spec.sound_speed)
    az = BeamPattern.from_beamwidth(sp["bw"], spec.frequency, spec.sound_speed)
    fitted_spec = dataclasses.replace(spec, elevation_beam=el, azimuth_beam=az, fov_elevation=float(np.exp(lbw)),
                                      beamwidth_azimuth=float(sp["bw"]), range_resolution=float(sp["res_bins"] * spec.bin_width))
    from .formation import azimuth_kernel, azimuth_mixing

    ksum = float(azimuth_mixing(fitted_spec).sum(1).max()) if fitted_spec.beam_azimuths is not None else float(azimuth_kernel(fitted_spec).sum())
    gain = DeviceGain(gain_db=float(a_db - 10 * np.log10(ksum)), noise_db=float(n_db), volume_db=float(v_db),
                      spreading_db=float(10 * (kexp + 2.0)), absorption_db_per_m=alpha)
    if sp["res_clamped"]:
        notes.append("range correlation at the limit of the grid: range resolution clamped")
    if sp["bw_clamped"]:
        notes.append("beam correlation at the limit of the grid: azimuth beam width clamped")
    notes.append("TVG absorption assumed equal to the water's (Ainslie-McColm at the device frequency); "
                 "spreading_db is the effective TVG exponent that explains the profile")
    # one sigma: the larger of the least-squares covariance and the jackknife over beam groups
    # (the model is measured like the data, blurred by the pulse and averaged over each
    # group's beams, so no systematic term is added; docs/physics.md 4.4)
    unc = {
        "height": sd[0], "pitch_deg": np.rad2deg(sd[1]), "roll_deg": np.rad2deg(sd[2]),
        "elevation_beamwidth_deg": np.rad2deg(np.exp(lbw) * sd[3]), "gain_db": sd[4], "spreading_db": 10 * sd[5],
        "noise_db": sd[6], "volume_db": sd[7], "clusters_per_m2": sp["clusters_sd"], "looks": sp["looks_sd"],
        "profile_rms_db": rms_db,
    }
    summary = stats.summary()
    summary.update(cluster_shape_per_cell=sp["cluster_shape"], cell_area_m2=sp["cell_area"],
                   gamma_ml_shape=sp["gamma_shape"], log_ratio=sp["measured"]["log_ratio"])
    notes.append(f"speckle: clustering shape {sp['cluster_shape']:.3g} per cell, {sp['looks']:.3g} looks, matched "
                 f"(contrast, log mean - mean log) = ({sp['measured']['contrast']:.3g}, {sp['measured']['log_ratio']:.3g}) "
                 f"with ({sp['matched'][0]:.3g}, {sp['matched'][1]:.3g}) on bare fields")
    full_scale = 255.0 if getattr(f0, "raw", None) is not None and np.asarray(f0.raw).dtype == np.uint8 else 0.0
    prof = SensorProfile(
        spec=fitted_spec, encoding=encoding, gain=gain, density=float("inf"), clusters_per_m2=float(sp["clusters"]),
        looks=float(sp["looks"]), height=float(h), pitch=float(pitch),
        roll=float(roll), full_scale=full_scale, uncertainty=unc, stats=summary, notes=tuple(notes),
        device=device or spec.name,
    )
    if refine_density and has_onset and np.isfinite(stats.onset_width):
        prof = _refine_geometry(prof, stats, f0)
    if refine_density and np.isfinite(prof.clusters_per_m2) and np.isfinite(stats.contrast):
        prof = _refine_clusters(prof, stats, f0)
    return prof


def _with_elevation_width(prof: SensorProfile, width: float) -> SensorProfile:
    """``prof`` with the elevation -3 dB width ``width`` (rad) and the pitch moved so that the
    pattern's lower edge (pitch + width / 2 below the horizontal: where the seabed's echo sets
    in) stays where the fit put it."""
    sp = prof.spec
    old = sp.elevation_pattern()
    el = BeamPattern.from_beamwidth(float(width), sp.frequency, sp.sound_speed, pedestal=old.pedestal)
    pitch = prof.pitch + 0.5 * (sp.fov_elevation - width)
    return dataclasses.replace(prof, spec=dataclasses.replace(sp, elevation_beam=el, fov_elevation=float(width)),
                               pitch=float(pitch))


#: Seeds of the frames simulated to refine a profile (fixed: the refinement is deterministic).
_REFINE_SEEDS = (201, 202, 203)


def _refine_onset(prof: SensorProfile, stats, frame, factors=(0.8, 0.9, 1.0, 1.1, 1.2)) -> SensorProfile:
    """Set the elevation width (its lower edge kept) to the one whose simulated frames have the
    measured seabed onset width (10-90 %, ``realism.frame_statistics``).

    The least squares of :func:`_fit_geometry` fit the whole range profile in dB: the
    background and the far side of the main lobe outnumber the onset's few bins, and on the
    real Oculus ping the fitted pattern's rise came out 12 % wider than the data's (mean over
    16 seeds; docs/physics.md 4.4). The onset width is measured on noisy profiles (the 90 %
    crossing sits near a speckled peak), so it is matched on frames simulated with the whole
    profile and measured the same way (indirect inference), not on the noise-free model: the
    width is scaled by ``factors`` (3 seeds each), a line is fitted to onset width against
    log width, and solved for the measured onset width (kept inside the factors' span).
    Uncertainty: the measured onset width's standard error (spread over beam groups) and
    the line's own, carried through its slope; a weak slope gives a large uncertainty.
    """
    target = float(stats.onset_width)
    sp = prof.spec
    w0 = float(sp.fov_elevation)
    if not (np.isfinite(prof.height) and np.isfinite(prof.pitch)) or prof.pitch + 0.5 * max(factors) * w0 >= np.deg2rad(85.0):
        return prof
    xs, ys = [], []
    for fac in factors:
        p = _with_elevation_width(prof, fac * w0)
        for seed in _REFINE_SEEDS:
            img = p.from_device(p.to_device(p.simulate(seed=seed).image))
            y = frame_statistics(img, frame.ranges, frame.azimuths).onset_width
            if np.isfinite(y):
                xs.append(np.log(fac))
                ys.append(y)
    xs, ys = np.asarray(xs), np.asarray(ys)
    if xs.size < 6 or np.unique(xs).size < 3:
        return prof
    A = np.stack([np.ones_like(xs), xs], 1)
    coef, *_ = np.linalg.lstsq(A, ys, rcond=None)
    b0, b1 = coef
    if not b1 > 0:  # the onset does not widen with the beam here: nothing to learn from it
        return prof
    lo, hi = np.log(min(factors)), np.log(max(factors))
    x = float(np.clip((target - b0) / b1, lo, hi))
    res = ys - A @ coef
    s2 = float(res @ res / max(1, xs.size - 2))
    cov = s2 * np.linalg.inv(A.T @ A)
    # sd of x = (target - b0) / b1: the target's and the line's, by the delta method
    g = np.array([-1.0 / b1, -(target - b0) / b1**2])
    sd_x = float(np.sqrt(max(0.0, (_onset_width_sd(stats) / b1) ** 2 + g @ cov @ g)))
    width = float(w0 * np.exp(x))
    out = _with_elevation_width(prof, width)
    unc = dict(prof.uncertainty)
    if np.isfinite(sd_x):
        sd_w = float(np.rad2deg(width) * sd_x)
        unc["elevation_beamwidth_deg"] = sd_w
        unc["pitch_deg"] = float(np.hypot(unc.get("pitch_deg", 0.0) or 0.0, 0.5 * sd_w))
    clamp = " (at the end of the span tried)" if x in (lo, hi) else ""
    notes = prof.notes + (f"elevation width set by the seabed onset on simulated frames: {np.rad2deg(w0):.3g} -> "
                          f"{np.rad2deg(width):.3g} deg{clamp}, lower edge kept (pitch {np.rad2deg(prof.pitch):.3g} -> "
                          f"{np.rad2deg(out.pitch):.3g} deg); measured onset width {target:.3g} m, simulated "
                          f"{b0:.3g} m at the whole-profile fit's width",)
    return dataclasses.replace(out, uncertainty=unc, notes=notes)


def _refine_geometry(prof: SensorProfile, stats, frame) -> SensorProfile:
    """The simulation refinements of the seabed geometry, in order: the height from the
    onset's and the plateau end's positions (:func:`_refine_position`, 2 rounds), the
    elevation width from the onset's width with its lower edge held (:func:`_refine_onset`),
    then one more round of the height, since the new width moves the plateau's end.

    The order, measured on the real Oculus ping (8 seeds, offsets simulated - real):
    width then height gave onset r10 / r90 +1.1 / +2.3 cm, plateau end +0.7 cm and an
    onset 14 % too wide (the height scales it); height then width +0.5 / +0.4 cm, -2.7 cm
    and +1 %; the last round of the height shares out the plateau end's offset.
    """
    prof = _refine_position(prof, stats, frame)
    prof = _refine_onset(prof, stats, frame)
    return _refine_position(prof, stats, frame, iterations=1)


def _scaled_height(prof: SensorProfile, scale: float) -> SensorProfile:
    """``prof`` with the height times ``scale`` (attitude and patterns kept): every range of
    the flat seabed's echo (onset, plateau, its end) scales by ``scale``."""
    return dataclasses.replace(prof, height=float(prof.height * scale))


def _position_stats(prof: SensorProfile, frame, seeds) -> np.ndarray:
    """``(onset centre, plateau end, mean intensity over the seabed's echo)`` per seed, of frames
    simulated with ``prof`` and measured like the data (device encoding, ``frame_statistics``)."""
    out = []
    for seed in seeds:
        img = prof.from_device(prof.to_device(prof.simulate(seed=seed).image))
        st = frame_statistics(img, frame.ranges, frame.azimuths)
        c = 0.5 * (st.onset_r10 + st.onset_r90)
        sel = (frame.ranges >= st.onset_r10) & (frame.ranges <= st.plateau_end)
        level = float(st.profile[sel].mean()) if sel.any() else np.nan
        out.append((c, st.plateau_end, level))
    return np.asarray(out, float)


def _group_position_se(stats) -> tuple[float, float]:
    """Standard errors of the onset centre and of the plateau end (medians over beam groups)."""
    from .realism import _onset, _smooth1

    prof = stats.group_profiles
    sm = _smooth1(prof, max(5, prof.shape[0] // 100), 0)
    ons = np.array([_onset(sm[:, k], stats.ranges) for k in range(prof.shape[1])])
    out = []
    for v in (0.5 * (ons[:, 0] + ons[:, 1]), ons[:, 3]):
        v = v[np.isfinite(v)]
        if v.size < 3:
            out.append(np.nan)
            continue
        iqr = np.subtract(*np.percentile(v, [75, 25]))
        out.append(float(1.253 * (iqr / 1.349) / np.sqrt(v.size)))
    return out[0], out[1]


def _refine_position(prof: SensorProfile, stats, frame, iterations: int = 2, seeds=_REFINE_SEEDS) -> SensorProfile:
    """Scale the height so that frames simulated with the profile put the seabed's onset
    (centre of the 10-90 % rise) and the plateau's end (far 50 % crossing) where the
    measured frames have them; rescale the gain to the measured mean echo over that span.

    Why: the least squares of :func:`_fit_geometry` fit the whole profile in dB, where the
    background and any weak precursor before the seabed (on the real Oculus ping: a band of
    returns 15-20 dB under the plateau at 0.65-0.75 m) weigh as much as the seabed's own
    echo, and the model's main lobe (a peaked two-way aperture pattern) cannot take the real
    lobe's flat top. On that ping the simulated onset came out 6-8 cm early and the plateau
    ended 10 cm early, both by the same ratio (about 1.09): a flat seabed's echo ranges are
    ``h / sin(depression)``, so a height error scales them all alike, whereas a pitch or width
    error moves the onset and the plateau's end by different ratios. On frames simulated
    with the model the fit assumes the least squares recover the height (docs/physics.md
    4.4) and this step stays within its uncertainty of 1.

    Indirect inference like :func:`_refine_onset`: ``iterations`` rounds of simulated frames
    (``seeds``), each multiplying the height by the geometric mean of the two ratios
    measured / simulated (kept within 0.7-1.4). Uncertainty of the height: the measured
    positions' standard errors (spread over beam groups), the simulated ones' (spread over
    seeds) and half the disagreement of the two ratios (what one scale cannot explain), in
    quadrature with the least squares' own.
    """
    target = np.array([0.5 * (stats.onset_r10 + stats.onset_r90), stats.plateau_end])
    if not (np.all(np.isfinite(target)) and np.isfinite(prof.height) and np.isfinite(prof.pitch)):
        return prof
    scale, sims, ratios = 1.0, None, None
    for _ in range(iterations):
        sims = _position_stats(_scaled_height(prof, scale), frame, seeds)
        m = np.nanmean(sims[:, :2], 0)
        if not np.all(np.isfinite(m)):
            return prof
        ratios = target / m
        scale = float(np.clip(scale * np.sqrt(ratios[0] * ratios[1]), 0.7, 1.4))
    out = _scaled_height(prof, scale)
    # gain: the mean echo over the seabed's span, measured against the last simulated frames
    sel = (stats.ranges >= stats.onset_r10) & (stats.ranges <= stats.plateau_end)
    level_sim = float(np.nanmean(sims[:, 2]))
    gain = prof.gain
    if sel.any() and np.isfinite(level_sim) and level_sim > 0:
        d_db = float(10 * np.log10(stats.profile[sel].mean() / level_sim))
        gain = dataclasses.replace(gain, gain_db=float(gain.gain_db + d_db))
    se_t = np.array(_group_position_se(stats))
    se_s = sims[:, :2].std(0, ddof=1) / np.sqrt(len(seeds)) if len(seeds) > 1 else np.full(2, np.nan)
    rel = np.sqrt(se_t**2 + se_s**2) / target
    sd_log = 0.5 * np.sqrt(np.sum(rel**2))  # of the mean of the two log ratios
    mismatch = 0.5 * abs(np.log(ratios[0] / ratios[1]))
    sd_log = float(np.hypot(sd_log, mismatch)) if np.isfinite(sd_log) else float(mismatch)
    unc = dict(prof.uncertainty)
    # the least squares' own sigma (kept apart so that a second round replaces, not adds, its term)
    old = unc.setdefault("height_least_squares", unc.get("height", 0.0) or 0.0)
    unc["height_least_squares"] = float(scale * old)
    unc["height"] = float(np.hypot(scale * old, out.height * sd_log))
    unc["height_scale_sd"] = sd_log
    notes = prof.notes + (f"height set by the seabed's onset and plateau end on simulated frames: {prof.height:.4g} -> "
                          f"{out.height:.4g} m (scale {scale:.4g}; last ratios measured / simulated: onset centre "
                          f"{ratios[0]:.4g}, plateau end {ratios[1]:.4g}); gain {prof.gain.gain_db:.4g} -> "
                          f"{gain.gain_db:.4g} dB",)
    return dataclasses.replace(out, gain=gain, uncertainty=unc, notes=notes)


def _onset_width_sd(stats) -> float:
    """Standard error of a frame's onset width (median over beam groups): the groups' spread."""
    from .realism import _onset, _smooth1

    prof = stats.group_profiles
    n_bins = prof.shape[0]
    sm = _smooth1(prof, max(5, n_bins // 100), 0)
    ons = np.array([_onset(sm[:, k], stats.ranges) for k in range(prof.shape[1])])
    w = ons[:, 1] - ons[:, 0]
    w = w[np.isfinite(w)]
    if w.size < 3:
        return float("nan")
    # the median's standard error, from the interquartile range (robust to odd groups)
    iqr = np.subtract(*np.percentile(w, [75, 25]))
    return float(1.253 * (iqr / 1.349) / np.sqrt(w.size))


def _refine_clusters(prof: SensorProfile, stats, frame, iterations: int = 4) -> SensorProfile:
    """Adjust the clustering (texture) until frames simulated with the whole profile (geometry,
    patterns, gain, noise, encoding) have the measured speckle contrast; looks kept.

    The bare-field estimate has a uniform mean and no background; the full model has
    neither. Secant steps in log clusters on the contrast of simulated frames (2 seeds).
    """
    target = stats.contrast

    def contrast(log_k):
        p = dataclasses.replace(prof, clusters_per_m2=float(np.exp(log_k)))
        cs = []
        for seed in (101, 102):
            img = p.from_device(p.to_device(p.simulate(seed=seed).image))
            cs.append(frame_statistics(img, frame.ranges, frame.azimuths).contrast)
        return float(np.mean(cs))

    x_start = np.log(prof.clusters_per_m2)
    x0 = x_start
    c_start = c0 = contrast(x0)
    x1 = x0 + (0.5 if c0 > target else -0.5)  # fewer clusters, more contrast
    c1 = contrast(x1)
    for _ in range(iterations):
        if not (np.isfinite(c0) and np.isfinite(c1)) or c1 == c0:
            break
        x2 = float(np.clip(x1 + (target - c1) * (x1 - x0) / (c1 - c0), x1 - 2.0, x1 + 2.0))
        x0, c0, x1, c1 = x1, c1, x2, contrast(x2)
        if abs(c1 - target) < 0.01 * target:
            break
    if not np.isfinite(c1) or abs(c1 - target) > abs(c_start - target):
        return prof
    unc = dict(prof.uncertainty)
    rel = prof.uncertainty.get("clusters_per_m2", np.nan) / prof.clusters_per_m2
    unc["clusters_per_m2"] = float(rel * np.exp(x1)) if np.isfinite(rel) else np.nan
    notes = prof.notes + (f"clustering refined by simulating the profile: contrast {c1:.3g} for the measured {target:.3g} "
                          f"(bare-field estimate gave {c_start:.3g})",)
    return dataclasses.replace(prof, clusters_per_m2=float(np.exp(x1)), uncertainty=unc, notes=notes)
