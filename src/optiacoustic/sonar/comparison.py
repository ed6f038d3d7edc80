"""Real frames against frames simulated with a fitted sensor profile: numbers and side-by-side figures.

``compare(real_frames, profile)`` simulates one frame per real frame (the flat seabed at
the profile's seabed pose, seeds 0, 1, ...), passes both through the device's encoding
(rounded and clipped as stored) and the same statistics (:mod:`.realism`), and scores
them against the targets of issue 10:

* onset width within +-25 %, background flat within +-1 dB, speckle contrast within
  10 %, two-sample KS distance <= 0.05, correlation lengths within 20 %.

``write_report(folder, ...)`` draws the real and simulated fans side by side, the range
profiles, histograms and autocorrelations overlaid, and writes the numbers as JSON and
Markdown.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .realism import FrameStatistics, frame_statistics, ks_distance

__all__ = ["Comparison", "compare", "write_report", "TARGETS"]

#: Targets of issue 10: (statistic, kind, bound).
TARGETS = {
    "onset_width": ("relative", 0.25),
    "background_flatness_db": ("absolute_max", 1.0),
    "speckle_contrast": ("relative", 0.10),
    "ks_distance": ("absolute_max", 0.05),
    "corr_length_range": ("relative", 0.20),
    "corr_length_beam": ("relative", 0.20),
}


@dataclass(frozen=True, eq=False)
class Comparison:
    """One real frame against its simulated twin."""

    index: int
    real: FrameStatistics
    sim: FrameStatistics
    real_image: np.ndarray
    sim_image: np.ndarray
    ks: float

    def scores(self) -> dict:
        """Per target: real value, simulated value, relative error (or value) and whether it is met."""
        out = {}
        pairs = {
            "onset_width": (self.real.onset_width, self.sim.onset_width),
            "background_flatness_db": (self.real.background_flatness_db, self.sim.background_flatness_db),
            "speckle_contrast": (self.real.contrast, self.sim.contrast),
            "corr_length_range": (self.real.corr_length_range, self.sim.corr_length_range),
            "corr_length_beam": (self.real.corr_length_beam, self.sim.corr_length_beam),
        }
        for name, (a, b) in pairs.items():
            kind, bound = TARGETS[name]
            if not (np.isfinite(a) and np.isfinite(b)):
                out[name] = {"real": _n(a), "sim": _n(b), "error": None, "met": None}
                continue
            if kind == "relative":
                err = (b - a) / a if a != 0 else np.inf
                met = abs(err) <= bound
            else:  # the simulated background must be flat where the real one is
                err = b
                met = (b <= bound) if a <= bound else None
            out[name] = {"real": _n(a), "sim": _n(b), "error": _n(err), "met": None if met is None else bool(met)}
        out["ks_distance"] = {"real": None, "sim": None, "error": _n(self.ks), "met": bool(self.ks <= TARGETS["ks_distance"][1])}
        return out

    def positions(self) -> dict:
        """Where the seabed's echo sits (m): onset 10 % / 90 % and plateau end, real, simulated and
        the offset simulated - real (reported; the targets of issue 10 are the shapes)."""
        out = {}
        for name in ("onset_r10", "onset_r90", "plateau_end"):
            a, b = getattr(self.real, name), getattr(self.sim, name)
            out[name] = {"real": _n(a), "sim": _n(b), "offset": _n(b - a)}
        return out


def _n(x):
    return None if x is None or not np.isfinite(x) else float(x)


def compare(real_frames, profile, *, seed: int = 0) -> list[Comparison]:
    """Simulate a twin of each real frame with ``profile`` and compare their statistics."""
    out = []
    for k, fr in enumerate(real_frames):
        raw = getattr(fr, "raw", None)
        real = profile.from_device(raw) if raw is not None else np.asarray(fr.image, float)
        sim_frame = profile.simulate(seed=seed + k)
        sim = profile.from_device(profile.to_device(sim_frame.image))
        if sim.shape != real.shape:
            raise ValueError(f"compare: frame {k} has shape {real.shape}, the profile's grid {sim.shape}")
        st_r = frame_statistics(real, fr.ranges, fr.azimuths)
        st_s = frame_statistics(sim, fr.ranges, fr.azimuths)
        out.append(Comparison(k, st_r, st_s, real, sim, ks_distance(st_r.normalised, st_s.normalised, seed=k)))
    return out


def _db(x):
    return 10 * np.log10(np.maximum(np.asarray(x, float), 1e-30))


def write_report(folder, comparisons: list[Comparison], profile, real_frames, *, fitted_on=(0,)) -> list[Path]:
    """Figures (PNG), ``comparison.json`` and ``comparison.md`` in ``folder``; returns the paths."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from .._atomic import savefig, write_json, write_text
    from .display import polar_to_fan

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for c in comparisons:
        fr = real_frames[c.index]
        spec = fr.spec
        ref = float(np.percentile(c.real_image, 99.5))
        lo_db = _db(ref) - 50
        fig, ax = plt.subplots(2, 3, figsize=(16, 10))
        for a, img, title in ((ax[0, 0], c.real_image, "real"), (ax[0, 1], c.sim_image, "simulated (profile)")):
            fan = polar_to_fan(np.asarray(img, np.float32), spec, width=500)
            d = np.where(fan.mask, _db(fan.data), np.nan)
            im = a.imshow(d, extent=fan.extent, vmin=lo_db, vmax=_db(ref), cmap="copper")
            a.set_title(f"{title}, frame {c.index} (dB)")
            a.set_xlabel("x_s (m)")
            a.set_ylabel("y_s (m)")
        fig.colorbar(im, ax=ax[0, 1], shrink=0.7)
        a = ax[0, 2]
        a.plot(c.real.ranges, _db(c.real.profile), lw=0.8, label="real")
        a.plot(c.sim.ranges, _db(c.sim.profile), lw=0.8, label="simulated")
        for st, col in ((c.real, "C0"), (c.sim, "C1")):
            for r_, ls in ((st.onset_r10, ":"), (st.onset_r90, ":"), (st.plateau_end, "--")):
                if np.isfinite(r_):
                    a.axvline(r_, color=col, ls=ls, lw=0.8)
        a.set_xlabel("range (m)")
        a.set_ylabel("mean intensity (dB)")
        a.set_title("range profile (mean over beams)\nonset 10/90 % dotted, plateau end dashed", fontsize=10)
        a.legend()
        a = ax[1, 0]
        hi = np.percentile(np.concatenate([c.real.normalised, c.sim.normalised]), 99.9)
        bins = np.linspace(0, hi, 80)
        a.hist(c.real.normalised, bins, density=True, histtype="step", label="real")
        a.hist(c.sim.normalised, bins, density=True, histtype="step", label="simulated")
        a.set_yscale("log")
        a.set_xlabel("intensity / local mean")
        a.set_title(f"speckle (contrast {c.real.contrast:.3f} real, {c.sim.contrast:.3f} sim; KS {c.ks:.3f})")
        a.legend()
        for a, key, name in ((ax[1, 1], "corr_range", "range (samples)"), (ax[1, 2], "corr_beam", "beams")):
            a.plot(getattr(c.real, key), "o-", label="real")
            a.plot(getattr(c.sim, key), "s-", label="simulated")
            a.axhline(0.5, color="0.6", lw=0.6)
            a.set_xlabel(f"lag ({name})")
            a.set_title("autocorrelation of normalised intensity")
            a.legend()
        how = f"profile fitted on frame(s) {list(fitted_on)}" if fitted_on else "profile given (not fitted on this log)"
        fig.suptitle(f"{profile.device}: {how}")
        fig.tight_layout()
        paths.append(savefig(fig, folder / f"frame_{c.index:03d}.png", dpi=80))
        plt.close(fig)
    table = [{"frame": c.index, "fitted_on": c.index in fitted_on, **{k: v for k, v in c.scores().items()},
              "positions_m": c.positions()} for c in comparisons]
    paths.append(write_json(folder / "comparison.json", {"device": profile.device, "fitted_on": list(fitted_on),
                                                         "frames": table}))
    lines = [f"# {profile.device}: real vs simulated", "",
             f"Profile fitted on frame(s) {list(fitted_on)}; encoding `{profile.encoding}`.", "",
             "| frame | statistic | real | simulated | error | target met |", "|---|---|---|---|---|---|"]
    for row in table:
        for k in TARGETS:
            s = row[k]
            lines.append(f"| {row['frame']}{' (fit)' if row['fitted_on'] else ''} | {k} | {_fmt(s['real'])} | "
                         f"{_fmt(s['sim'])} | {_fmt(s['error'])} | {s['met']} |")
    lines += ["", "Where the seabed's echo sits (m; offset = simulated - real):", "",
              "| frame | position | real | simulated | offset |", "|---|---|---|---|---|"]
    for row in table:
        for k, v in row["positions_m"].items():
            lines.append(f"| {row['frame']} | {k} | {_fmt(v['real'])} | {_fmt(v['sim'])} | {_fmt(v['offset'])} |")
    paths.append(write_text(folder / "comparison.md", "\n".join(lines) + "\n"))
    return paths


def _fmt(x):
    return "-" if x is None else f"{x:.4g}"
