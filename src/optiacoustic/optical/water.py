"""Optical properties of water: absorption, scattering and the volume scattering function.

Per colour channel (R, G, B) a :class:`Water` holds the absorption coefficient ``a``, the
scattering coefficient ``b`` and a normalised phase function ``p(psi)``; the attenuation
is ``c = a + b`` (thesis eq. 3.4) and the volume scattering function (VSF) is
``beta(psi) = b p(psi)`` so that ``2 pi int_0^pi beta(psi) sin(psi) dpsi = b`` (eq. 3.2).

The phase function is a per-channel mixture of four normalised shapes
(docs/derivations.md (ch. 3), sec. 1):

* ``water``: molecular (Einstein-Smoluchowski) scattering, ``(1 + 0.835 cos^2 psi) / 16.06``
  (Morel 1974; the thesis's eq. 3.5 gives only its wavelength dependence and drops the
  angular factor);
* ``small``, ``large``: Kopelevich's small (< 1 um, mineral) and large (biological)
  particle shapes (Kopelevich 1983, tabulated in Mobley 1994), eq. 3.6;
* ``hg``: Henyey-Greenstein with asymmetry ``g``, the usual alternative.

Channel wavelengths are R = 650, G = 550, B = 450 nm unless a preset says otherwise.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["PhaseFunction", "Water", "KOPELEVICH_B_SMALL", "KOPELEVICH_B_LARGE", "JERLOV_KD"]

#: Default channel wavelengths (nm) for R, G, B.
RGB_NM = (650.0, 550.0, 450.0)

# --------------------------------------------------------------------------- Kopelevich
#: Kopelevich's particle VSFs per unit volume concentration (m^-1 sr^-1 per cm^3/m^3 = ppm)
#: at 550 nm, scattering angle in degrees (Mobley 1994, Light and Water, Table 3.14, as
#: reproduced in the IceCube clsim resource ``PhaseFunctionKopelevicTwoComponent.txt``).
_KOP_DEG = np.array([0.001, 0.5, 1, 1.5, 2, 4, 6, 10, 15, 30, 45, 60, 75, 90, 105, 120, 135, 150, 180.0])
_KOP_SMALL = np.array([5.3, 5.3, 5.2, 5.2, 5.1, 4.6, 3.9, 2.5, 1.3, 0.29, 0.098, 0.041, 0.020, 0.012,
                       0.0086, 0.0074, 0.0074, 0.0075, 0.0081])
_KOP_LARGE = np.array([140.0, 98, 46, 26, 15, 3.6, 1.1, 0.2, 0.05, 0.0028, 0.00062, 0.00038, 0.00020,
                       0.000063, 0.000044, 0.000029, 0.00002, 0.00002, 0.00007])
#: Kopelevich's specific scattering coefficients at 550 nm (m^-1 per ppm): b_s* and b_l*
#: (Mobley 1994, p. 119). Our log-linear integration of the tables above gives 1.325 and
#: 0.325 (1 % and 4 % off): the tables give the *shape*, these numbers the *magnitude*.
KOPELEVICH_B_SMALL = 1.34
KOPELEVICH_B_LARGE = 0.312
#: Spectral exponents of eq. (3.6): small particles (lambda0/lambda)^1.7, large ^0.3,
#: molecular water (eq. 3.5) ^4.32; lambda0 = 550 nm.
_EXP_SMALL, _EXP_LARGE, _EXP_WATER = 1.7, 0.3, 4.32
#: Molecular scattering of (sea) water at 550 nm (m^-1), Mobley 1994 p. 119 / Morel 1974.
B_WATER_550 = 0.0017
#: Integral of (1 + 0.835 cos^2) over the sphere: 2 pi (2 + 2 * 0.835 / 3) = 16.064.
_ES_NORM = 2 * np.pi * (2 + 2 * 0.835 / 3)


def molecular_scattering(wavelength_nm) -> np.ndarray:
    """Molecular scattering coefficient of water ``b_w = 0.0017 (550 / lambda)^4.32`` (m^-1)."""
    return B_WATER_550 * (550.0 / np.asarray(wavelength_nm, float)) ** _EXP_WATER


def _log_interp(psi, nodes, values):
    return np.exp(np.interp(psi, nodes, np.log(values)))


@functools.lru_cache(maxsize=None)
def _kopelevich_norms() -> tuple[float, float, float, float]:
    """Sphere integrals of the two tables and their backscatter fractions (independent quadrature)."""
    from scipy.integrate import quad

    nodes = np.deg2rad(_KOP_DEG)
    out = []
    for tab in (_KOP_SMALL, _KOP_LARGE):
        f = lambda x, t=tab: 2 * np.pi * float(_log_interp(x, nodes, t)) * np.sin(x)  # noqa: E731
        parts = [quad(f, nodes[i], nodes[i + 1], limit=200)[0] for i in range(len(nodes) - 1)]
        total = sum(parts) + 2 * np.pi * tab[0] * (1 - np.cos(nodes[0]))  # the 0..0.001 deg cap
        back = sum(p for p, lo in zip(parts, nodes[:-1]) if lo >= np.pi / 2 - 1e-12)
        out += [total, back / total]
    return tuple(out)


# --------------------------------------------------------------------------- phase function
_COMPONENTS = ("water", "small", "large", "hg")


@dataclass(frozen=True)
class PhaseFunction:
    """A per-channel mixture of normalised phase functions ``p(psi)`` (sr^-1).

    Parameters
    ----------
    weights : array_like, shape (4, 3)
        Share of each component in each channel's scattering: rows ``water``
        (Einstein-Smoluchowski), ``small``, ``large`` (Kopelevich particle shapes),
        ``hg`` (Henyey-Greenstein); columns R, G, B. Each column sums to 1 (a channel
        without scattering may use any valid column).
    g : float
        Asymmetry parameter of the Henyey-Greenstein component, ``-1 < g < 1``.

    Every component integrates to 1 over the sphere, so ``int p dOmega = 1`` per channel.
    """

    weights: tuple = ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    g: float = 0.924

    def __post_init__(self):
        w = np.asarray(self.weights, float)
        if w.shape != (4, 3) or not np.all(np.isfinite(w)):
            raise ValueError(f"PhaseFunction.weights: expected 4 x 3 finite numbers (water, small, large, hg) x (R, G, B), "
                             f"got shape {w.shape}")
        if np.any(w < 0) or np.any(np.abs(w.sum(0) - 1) > 1e-6):
            raise ValueError(f"PhaseFunction.weights: must be >= 0 and each channel (column) must sum to 1, "
                             f"got column sums {np.round(w.sum(0), 6).tolist()}")
        if not (isinstance(self.g, (int, float, np.floating)) and np.isfinite(self.g) and -1 < self.g < 1):
            raise ValueError(f"PhaseFunction.g: must be in (-1, 1), got {self.g!r}")
        object.__setattr__(self, "weights", tuple(tuple(float(x) for x in row) for row in w))
        object.__setattr__(self, "g", float(self.g))

    # construction ---------------------------------------------------------------
    @classmethod
    def molecular(cls) -> "PhaseFunction":
        """Pure-water (Einstein-Smoluchowski) scattering in every channel."""
        return cls()

    @classmethod
    def henyey_greenstein(cls, g: float) -> "PhaseFunction":
        """Henyey-Greenstein with asymmetry ``g`` in every channel."""
        return cls(((0, 0, 0), (0, 0, 0), (0, 0, 0), (1, 1, 1)), g)

    @classmethod
    def from_parts(cls, b_water, b_small, b_large, b_hg=(0.0, 0.0, 0.0), g: float = 0.924) -> "PhaseFunction":
        """Mixture weighted by each component's scattering coefficient ``(3,)`` (m^-1)."""
        parts = np.array([b_water, b_small, b_large, b_hg], float)
        tot = parts.sum(0)
        w = np.where(tot > 0, parts / np.where(tot > 0, tot, 1.0), np.array([[1.0], [0.0], [0.0], [0.0]]))
        return cls(tuple(map(tuple, w)), g)

    # evaluation -----------------------------------------------------------------
    def components(self, cos_psi) -> np.ndarray:
        """The four normalised shapes at ``cos_psi`` (...,): array ``(..., 4)`` (sr^-1)."""
        mu = np.clip(np.asarray(cos_psi, float), -1.0, 1.0)
        psi = np.arccos(mu)
        ns, _, nl, _ = _kopelevich_norms()
        nodes = np.deg2rad(_KOP_DEG)
        w = np.asarray(self.weights)
        out = np.zeros(mu.shape + (4,))
        out[..., 0] = (1 + 0.835 * mu * mu) / _ES_NORM
        if np.any(w[1] > 0):
            out[..., 1] = _log_interp(psi, nodes, _KOP_SMALL) / ns
        if np.any(w[2] > 0):
            out[..., 2] = _log_interp(psi, nodes, _KOP_LARGE) / nl
        if np.any(w[3] > 0):
            g = self.g
            out[..., 3] = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)
        return out

    def __call__(self, cos_psi) -> np.ndarray:
        """``p(psi)`` per channel: ``cos_psi`` (...,) -> ``(..., 3)`` (sr^-1)."""
        comp = self.components(cos_psi)
        w = np.asarray(self.weights)
        out = np.zeros(comp.shape[:-1] + (3,))
        for k in range(4):  # four shapes, each vectorised over all angles
            if np.any(w[k] > 0):
                out += comp[..., k, None] * w[k]
        return out

    def fraction_within(self, psi_max: float) -> np.ndarray:
        """Share of scattered light deflected by less than ``psi_max`` (rad), per channel ``(3,)``."""
        from scipy.integrate import quad

        if not 0 <= psi_max <= np.pi:
            raise ValueError(f"psi_max: expected an angle in [0, pi], got {psi_max!r}")
        nodes = np.deg2rad(_KOP_DEG)
        brk = np.concatenate([[0.0], nodes[nodes < psi_max], [psi_max]])
        comp = []
        for k in range(4):
            f = lambda x, k=k: 2 * np.pi * float(self.components(np.cos(x))[k]) * np.sin(x)  # noqa: E731
            comp.append(sum(quad(f, brk[i], brk[i + 1], limit=100)[0] for i in range(len(brk) - 1)))
        return np.asarray(comp) @ np.asarray(self.weights)


# --------------------------------------------------------------------------- Jerlov
#: Jerlov's downwelling diffuse attenuation K_d (m^-1) at 650, 550, 450 nm for his water
#: types: N. G. Jerlov, Marine Optics, 2nd ed. (1976), Table XXVII, as reproduced in a
#: public table of that work. The Jerlov presets are derived from these (see Water.preset).
JERLOV_KD: dict[str, tuple[float, float, float]] = {
    "I": (0.36, 0.063, 0.019),
    "IA": (0.37, 0.067, 0.026),
    "IB": (0.375, 0.072, 0.036),
    "II": (0.40, 0.089, 0.068),
    "III": (0.445, 0.12, 0.135),
    "1C": (0.45, 0.12, 0.25),
    "3C": (0.46, 0.19, 0.39),
    "5C": (0.54, 0.30, 0.56),
    "7C": (0.63, 0.46, 0.89),
    "9C": (0.76, 0.63, 1.6),
}
#: Pure-water absorption (m^-1) at 650, 550, 450 nm: Pope & Fry (1997).
A_WATER_POPE_FRY = (0.340, 0.0565, 0.00922)
#: Particle backscatter ratio b_bp / b_p of Petzold's average particle phase function (Mobley 1994).
B_BP_RATIO = 0.0183
#: Kd = 1.04 (a + b_b) for a zenith sun just below the surface (Gordon 1989's 1.0395).
_GORDON = 1.0395


def jerlov_iops(kd_rgb) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Absorption and scattering consistent with a Jerlov ``K_d`` triple (650, 550, 450 nm).

    Derivation (docs/derivations.md (ch. 3), sec. 6): ``K_d = 1.04 (a + b_b)``
    (Gordon 1989), Case-1 particle scattering ``b_p = 0.30 C^0.62 (550 / lambda)``
    (Gordon & Morel 1983) with backscatter ratio 0.0183 (Petzold), and the chlorophyll
    ``C`` (mg m^-3) fixed by the blue excess absorption ``0.06 C^0.65 (1 + 0.2)``
    (Prieur & Sathyendranath 1981 / Morel 1991 at 440 nm, used at 450 nm).

    Returns
    -------
    a, b_water, b_particles : ndarray (3,)
        Per channel (m^-1).
    chlorophyll : float
        The fitted chlorophyll concentration (mg m^-3).
    """
    from scipy.optimize import brentq

    kd = np.asarray(kd_rgb, float)
    lam = np.asarray(RGB_NM)
    aw = np.asarray(A_WATER_POPE_FRY)
    bw = molecular_scattering(lam)
    cdom440 = 1 + 0.2 * np.exp(-0.014 * (450 - 440))

    def bp(C):
        return 0.30 * C ** 0.62 * (550 / lam)

    def blue_residual(C):
        return _GORDON * (aw[2] + 0.5 * bw[2] + B_BP_RATIO * bp(C)[2] + 0.06 * C ** 0.65 * cdom440) - kd[2]

    C = float(brentq(blue_residual, 1e-5, 1e4, xtol=1e-12))
    b_p = bp(C)
    a = kd / _GORDON - 0.5 * bw - B_BP_RATIO * b_p
    return a, bw, b_p, C


def _particle_split(b_p) -> tuple[np.ndarray, np.ndarray]:
    """Split particle scattering into Kopelevich small + large so that b_bp / b_p = 0.0183."""
    _, fs, _, fl = _kopelevich_norms()
    share_small = (B_BP_RATIO - fl) / (fs - fl)
    return share_small * np.asarray(b_p), (1 - share_small) * np.asarray(b_p)


# --------------------------------------------------------------------------- Water
def _rgb(x, name: str) -> tuple[float, float, float]:
    try:
        arr = np.asarray(x, float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"Water.{name}: expected 3 numbers (R, G, B), got {x!r}") from None
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3:
        raise ValueError(f"Water.{name}: expected 3 numbers (R, G, B), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"Water.{name}: must be finite, got {arr.tolist()}")
    if np.any(arr < 0):
        raise ValueError(f"Water.{name}: coefficients must be >= 0 (m^-1), got {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Water:
    """Inherent optical properties of a water body, per colour channel (R, G, B).

    Parameters
    ----------
    a : array_like (3,)
        Absorption coefficient (m^-1), eq. (3.1).
    b : array_like (3,)
        Scattering coefficient (m^-1), eq. (3.2)-(3.3).
    phase : PhaseFunction
        Angular distribution of the scattering: ``beta(psi) = b p(psi)``.
    name, source : str
        Preset name and where its numbers come from.
    wavelengths_nm : (3,) floats
        Wavelengths the channels stand for.
    doubtful : tuple of str
        Values that could not be verified against their source, or are derived.

    Attributes
    ----------
    c : ndarray (3,)
        Beam attenuation ``a + b`` (m^-1), eq. (3.4).

    Raises
    ------
    ValueError
        A negative or non-finite coefficient, or a phase that is not a PhaseFunction.
    """

    a: tuple = (0.0, 0.0, 0.0)
    b: tuple = (0.0, 0.0, 0.0)
    phase: PhaseFunction = field(default_factory=PhaseFunction)
    name: str = "custom"
    source: str = ""
    wavelengths_nm: tuple = RGB_NM
    doubtful: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "a", _rgb(self.a, "a"))
        object.__setattr__(self, "b", _rgb(self.b, "b"))
        if not isinstance(self.phase, PhaseFunction):
            raise ValueError(f"Water.phase: expected a PhaseFunction, got {type(self.phase).__name__}")
        object.__setattr__(self, "wavelengths_nm", _rgb(self.wavelengths_nm, "wavelengths_nm"))
        object.__setattr__(self, "doubtful", tuple(self.doubtful))

    # ------------------------------------------------------------------ properties
    @property
    def c(self) -> np.ndarray:
        """Beam attenuation coefficient ``a + b`` (m^-1), ``(3,)``."""
        return np.asarray(self.a) + np.asarray(self.b)

    @property
    def albedo(self) -> np.ndarray:
        """Single-scattering albedo ``b / c`` per channel (0 where ``c = 0``)."""
        c = self.c
        return np.where(c > 0, np.asarray(self.b) / np.where(c > 0, c, 1.0), 0.0)

    def vsf(self, cos_psi) -> np.ndarray:
        """Volume scattering function ``beta(psi)`` (m^-1 sr^-1): ``(...,) -> (..., 3)``."""
        return self.phase(cos_psi) * np.asarray(self.b)

    def transmittance(self, distance) -> np.ndarray:
        """Narrow-beam transmittance ``exp(-c L)`` over ``distance`` (m): ``(...,) -> (..., 3)``."""
        return np.exp(-np.asarray(distance, float)[..., None] * self.c)

    # ------------------------------------------------------------------ variants
    def with_henyey_greenstein(self, g: float, *, keep_molecular: bool = True) -> "Water":
        """The same ``a`` and ``b`` with the particle part scattering by Henyey-Greenstein(``g``).

        With ``keep_molecular=False`` the whole VSF is Henyey-Greenstein.
        """
        w = np.asarray(self.phase.weights)
        if keep_molecular:
            new = np.stack([w[0], np.zeros(3), np.zeros(3), w[1] + w[2] + w[3]])
        else:
            new = np.stack([np.zeros(3), np.zeros(3), np.zeros(3), np.ones(3)])
        return replace(self, phase=PhaseFunction(tuple(map(tuple, new)), g), name=f"{self.name}+hg({g:g})")

    def scaled(self, factor: float) -> "Water":
        """``a`` and ``b`` multiplied by ``factor`` (same phase function): more or less turbid."""
        if not (np.isfinite(factor) and factor >= 0):
            raise ValueError(f"factor: must be finite and >= 0, got {factor!r}")
        return replace(self, a=tuple(factor * np.asarray(self.a)), b=tuple(factor * np.asarray(self.b)),
                       name=f"{self.name}x{factor:g}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def kopelevich(cls, v_small: float, v_large: float, a, *, wavelengths_nm=RGB_NM, name: str = "kopelevich",
                   source: str = "Kopelevich (1983) two-component particle model, eq. (3.6)") -> "Water":
        """Water whose scattering follows Kopelevich's model (eq. 3.6).

        ``b(lambda) = b_w(lambda) + 1.34 v_s (550/lambda)^1.7 + 0.312 v_l (550/lambda)^0.3``
        with the volume concentrations ``v_small`` and ``v_large`` of small and large
        particles in cm^3/m^3 (ppm), and ``b_w`` the molecular term (eq. 3.5).
        """
        for nm, v in (("v_small", v_small), ("v_large", v_large)):
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{nm}: particle volume concentration must be finite and >= 0 (ppm), got {v!r}")
        lam = np.asarray(_rgb(wavelengths_nm, "wavelengths_nm"))
        bw = molecular_scattering(lam)
        bs = KOPELEVICH_B_SMALL * v_small * (550 / lam) ** _EXP_SMALL
        bl = KOPELEVICH_B_LARGE * v_large * (550 / lam) ** _EXP_LARGE
        return cls(a, tuple(bw + bs + bl), PhaseFunction.from_parts(bw, bs, bl), name=name, source=source,
                   wavelengths_nm=tuple(lam))

    @staticmethod
    def preset_names() -> list[str]:
        """Names accepted by :meth:`preset`."""
        return ["thesis", "pure-water", "clear"] + [f"jerlov-{k}" for k in JERLOV_KD]

    @classmethod
    def preset(cls, name: str) -> "Water":
        """A named water type.

        ``thesis``
            The thesis's c = (0.41, 0.066, 0.018) m^-1 (sec. 3.4), which it gives without
            a split. We split it as molecular scattering plus a trace of Kopelevich
            particles (v_s = v_l = 0.002 ppm, b = 0.0035, 0.0050, 0.0085 m^-1) and
            ``a = c - b``; then a(B) = 0.0095 equals pure-water absorption at 450 nm
            (Pope & Fry 0.0092) and a(R) = 0.407 pure water at about 660 nm.
        ``pure-water``
            Thesis Table 3.2 (Smith & Baker 1981) at 670 / 530 / 470 nm (the rows nearest
            650 / 550 / 450): a = (0.4346, 0.0505, 0.0130), b = (0.0006, 0.0017, 0.0027);
            molecular phase function.
        ``clear``
            No water at all (a = b = 0): renders the clear image.
        ``jerlov-I`` ... ``jerlov-9C``
            Jerlov's oceanic (I, IA, IB, II, III) and coastal (1C, 3C, 5C, 7C, 9C) types.
            DERIVED, not tabulated: ``a`` and ``b`` at 650 / 550 / 450 nm are computed by
            :func:`jerlov_iops` from Jerlov's K_d (1976, Table XXVII), so that they
            reproduce his K_d exactly through K_d = 1.04 (a + b_b). Solonenko & Mobley
            (2015) tabulate a and b for these types but could not be consulted offline:
            replace these values with theirs when you can. The coastal types' scattering is
            doubtful (probably too high, by up to ~2x for 7C-9C): the Case-1 relations used
            attribute their blue absorption, mostly CDOM, to particles.
        """
        if not isinstance(name, str):
            raise ValueError(f"water: expected a preset name, got {type(name).__name__}")
        key = name.strip()
        low = key.lower()
        if low == "thesis":
            b_part = cls.kopelevich(0.002, 0.002, (0.0, 0.0, 0.0))
            c = np.array([0.41, 0.066, 0.018])
            return replace(
                b_part, a=tuple(c - np.asarray(b_part.b)), name="thesis",
                source="thesis sec. 3.4: c = (0.41, 0.066, 0.018) m^-1; split a = c - b with b = molecular + "
                       "Kopelevich particles v_s = v_l = 0.002 ppm (our choice; the thesis gives only c)",
                doubtful=("a/b split (the thesis gives only c)",))
        if low in ("pure-water", "pure_water", "purewater"):
            return cls((0.4346, 0.0505, 0.0130), (0.0006, 0.0017, 0.0027), PhaseFunction.molecular(),
                       name="pure-water", wavelengths_nm=(670.0, 530.0, 470.0),
                       source="thesis Table 3.2 (Smith & Baker 1981, pure water) at 670, 530, 470 nm")
        if low == "clear":
            return cls((0, 0, 0), (0, 0, 0), name="clear", source="no attenuation, no scattering")
        if low.startswith("jerlov"):
            jt = key[6:].lstrip("-_ ").upper()
            if jt in JERLOV_KD:
                a, bw, b_p, C = jerlov_iops(JERLOV_KD[jt])
                bs, bl = _particle_split(b_p)
                return cls(tuple(a), tuple(bw + b_p), PhaseFunction.from_parts(bw, bs, bl), name=f"jerlov-{jt}",
                           source=f"derived from Jerlov (1976) Table XXVII K_d = {JERLOV_KD[jt]} m^-1 "
                                  f"(650/550/450 nm) with Case-1 bio-optical relations (chlorophyll {C:.3g} mg/m^3); "
                                  "see jerlov_iops",
                           doubtful=("a and b are derived from K_d, not Solonenko & Mobley (2015)'s table",)
                           + (("b: coastal scattering probably overestimated",) if jt.endswith("C") else ()))
        raise ValueError(f"water: unknown water type {name!r}; known types are {cls.preset_names()}")

    def summary(self) -> str:
        r = lambda v: ", ".join(f"{x:.4g}" for x in v)  # noqa: E731
        return f"{self.name}: a = ({r(self.a)}), b = ({r(self.b)}), c = ({r(self.c)}) m^-1"


def as_water(water) -> Water:
    """``None`` -> the thesis water; a name -> the preset; a Water -> itself."""
    if water is None:
        return Water.preset("thesis")
    if isinstance(water, str):
        return Water.preset(water)
    if isinstance(water, Water):
        return water
    raise ValueError(f"water: expected a Water, a preset name or None, got {type(water).__name__}")
