"""Speed of the opti-acoustic geometry: closed forms, epipolar curves, maximum likelihood, stereo.

Every rate is points per second on the thesis setting (0.25 m baseline, points about 3 m
ahead, noise 2 px / 2 cm / 0.03 rad), the median of repeated runs after a warm-up. The
reference, measured in the same run over the same points, is the plain numpy rigid transform
``R p + t`` of ``(N, 3)`` points (``einsum``; ``P @ R.T`` goes through threaded BLAS, whose
speed swings tens of times with the machine's load, so it is shown but not used); ``refine``'s per-point LM is also compared with
``refine(solver="scipy")``, scipy's ``least_squares`` on the same batched problem (one sparse
block-diagonal Jacobian), on clean data and with 1% gross outliers.
"""

from __future__ import annotations


import numpy as np

from _timing import median_ms

TITLE = "Opti-acoustic geometry (ch. 4-5)"
DESCRIPTION = ("Points per second of the closed forms, epipolar curves, maximum-likelihood refinement and "
               "stereo triangulation, as ratios to a plain numpy rigid transform `R p + t` (einsum) of the same "
               "points, measured in the same run.")


def _setting(n, seed=0):
    from optiacoustic import PinholeCamera, Rig
    from optiacoustic.geometry import projection as pr

    cam = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
    rig = Rig.toed_in(cam, baseline=0.25, vergence=float(np.arctan(0.25 / 3.0)))
    rng = np.random.default_rng(seed)
    P = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n), rng.uniform(2.7, 3.3, n)], -1)
    p = pr.project(rig, P)
    e = rng.standard_normal((n, 4)) * [2.0, 2.0, 0.02, 0.03]
    return rig, P, p.pixels + e[:, :2], p.ranges + e[:, 2], p.azimuths + e[:, 3]


def run() -> list[dict]:
    from optiacoustic.geometry import epipolar as ep
    from optiacoustic.geometry import reconstruct as rc
    from optiacoustic.geometry import stereo as st

    rows = []
    sig = dict(sigma_pixel=2.0, sigma_range=0.02, sigma_azimuth=0.03)

    def add(name, n, seconds, ref_rate, ref_name, note):
        rate = n / seconds
        rows.append(dict(name=name, value=rate, unit="points/s", reference=ref_name, ratio=rate / ref_rate, note=note))

    n = 1_000_000
    rig, P, px, r, th = _setting(n)
    # The reference: the rigid transform R p + t of the same points in plain numpy. einsum (no BLAS)
    # rather than P @ R.T, whose multi-threaded BLAS path swings 40x with the machine's load.
    ref = n / (median_ms(lambda: np.einsum("ij,nj->ni", rig.R, P) + rig.t) / 1e3)
    rows.append(dict(name="reference: numpy R p + t (einsum)", value=ref, unit="points/s", reference="itself",
                     ratio=1.0, note=f"{n} points (N, 3)"))
    refname = "numpy R p + t (einsum)"
    mm = n / (median_ms(lambda: P @ rig.R.T + rig.t) / 1e3)
    rows.append(dict(name="numpy P @ R.T + t (BLAS)", value=mm, unit="points/s", reference=refname, ratio=mm / ref,
                     note="threaded BLAS: unstable under load"))
    add("range_solution (exact root)", n, (median_ms(lambda: rc.range_solution(rig, px, r)) / 1e3), ref, refname,
        f"{n} matches; target >= 5e6/s")
    add("azimuth_solution", n, (median_ms(lambda: rc.azimuth_solution(rig, px, th)) / 1e3), ref, refname,
        f"{n} matches; target >= 5e6/s")
    add("combined_solution (BLUE)", n, (median_ms(lambda: rc.combined_solution(rig, px, r, th, **sig)) / 1e3), ref, refname,
        f"{n} matches, with first-order variances")
    add("epipolar.sonar_range r(theta)", n, (median_ms(lambda: ep.sonar_range(rig, px, th)) / 1e3), ref, refname,
        f"{n} (pixel, azimuth) pairs")
    m = 200_000
    add("epipolar.conic", m, (median_ms(lambda: ep.conic(rig, r[:m], th[:m])) / 1e3), ref, refname,
        f"{m} sonar points -> 3x3 conics")

    m = 100_000
    add("refine direct (batched LM)", m, (median_ms(lambda: rc.refine(rig, px[:m], r[:m], th[:m], **sig), 3) / 1e3), ref,
        refname, f"{m} matches; target >= 1e5/s")
    add("refine indirect (constrained GN)", m,
        (median_ms(lambda: rc.refine(rig, px[:m], r[:m], th[:m], **sig, method="indirect"), 3) / 1e3), ref, refname,
        f"{m} matches")
    # The same batched problem through one scipy least_squares call (block-sparse Jacobian), on clean
    # data and with 1% gross outliers (wrong matches), which a shared trust region has to carry.
    for label, bad in (("clean", 0.0), ("1% outliers", 0.01)):
        k = 50_000
        rr = r[:k].copy()
        pp = px[:k].copy()
        out = np.random.default_rng(5).choice(k, int(bad * k), replace=False)
        rr[out] += np.random.default_rng(6).uniform(-1, 1, out.size)
        pp[out] += np.random.default_rng(7).uniform(-30, 30, (out.size, 2))
        t_sp = (median_ms(lambda: rc.refine(rig, pp, rr, th[:k], **sig, solver="scipy"), 2) / 1e3)
        t_lm = (median_ms(lambda: rc.refine(rig, pp, rr, th[:k], **sig), 2) / 1e3)
        rows.append(dict(name=f"refine direct, {label}: batched LM vs scipy", value=k / t_lm, unit="points/s",
                         reference="refine(solver='scipy'): least_squares trf+lsmr, block-sparse jac, same points",
                         ratio=t_sp / t_lm, note=f"{k} matches; scipy {k / t_sp:.3g} points/s"))

    stereo = st.StereoRig.from_rig(rig)
    sp_ = st.project(stereo, P[:m])
    add("stereo triangulate_linear (batched SVD)", m, (median_ms(lambda: st.triangulate_linear(stereo, sp_.pixels1, sp_.pixels2), 3) / 1e3),
        ref, refname, f"{m} pairs")
    add("stereo triangulate_optimal (batched LM)", m,
        (median_ms(lambda: st.triangulate_optimal(stereo, sp_.pixels1 + 1.0, sp_.pixels2 - 1.0, sigma_pixel=2.0), 3) / 1e3),
        ref, refname, f"{m} pairs")
    return rows


if __name__ == "__main__":
    for row in run():
        print(f"{row['name']:50s} {row['value']:12.4g} {row['unit']:9s} ratio {row['ratio']:.3g}  {row['note']}")
