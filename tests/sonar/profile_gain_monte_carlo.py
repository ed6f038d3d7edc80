"""Monte Carlo of the sensor-profile fit's gain chain on single simulated frames (not collected by pytest).

Measures the bias of ``spreading_db`` and ``noise_db`` and the ratio of the stated sigma to the
seed-to-seed sd over seeds of ``test_profile.py``'s simulated seabed, for the shipped dB polish
or the gamma-deviance polish (docs/derivations.md, "Fitting the range profile in the intensity
domain"). About 25 s per seed per core::

    PYTHONPATH=src python tests/sonar/profile_gain_monte_carlo.py --seeds 100:116 --residuals deviance --loss linear
"""

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _one(args):
    seed, residuals, loss, f_scale = args
    from test_profile import _simulate

    from optiacoustic.sonar import profile as P

    P._DEVIANCE[0] = residuals == "deviance"
    P._LOGBIAS[0] = residuals == "db-corrected"
    P._LOSS[:] = [loss, f_scale]
    p = P.fit_profile(_simulate(seed), refine_density=False)
    u = p.uncertainty
    return dict(seed=seed, spreading_db=p.gain.spreading_db, spreading_sd=float(u["spreading_db"]),
                noise_db=p.gain.noise_db, noise_sd=float(u["noise_db"]), height=p.height, height_sd=float(u["height"]))


def main():
    from test_profile import GAIN

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="100:116")
    ap.add_argument("--residuals", choices=("db", "db-corrected", "deviance"), default="db")
    ap.add_argument("--loss", default="soft_l1")
    ap.add_argument("--f-scale", type=float, default=3.0)
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    lo, hi = (int(v) for v in a.seeds.split(":"))
    with ProcessPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(_one, [(s, a.residuals, a.loss, a.f_scale) for s in range(lo, hi)]))
    for r in rows:
        print(json.dumps(r))
    for name, true in (("spreading", GAIN.spreading_db), ("noise", GAIN.noise_db)):
        e = np.array([r[f"{name}_db"] for r in rows]) - true
        s = np.array([r[f"{name}_sd"] for r in rows])
        se = e.std(ddof=1) / np.sqrt(e.size)
        print(f"{name}_db: bias {e.mean():+.3f} +- {se:.3f} dB (z {e.mean() / se:+.2f}), sd {e.std(ddof=1):.3f}, "
              f"stated {s.mean():.3f} (ratio {s.mean() / e.std(ddof=1):.2f}), n {e.size}")


if __name__ == "__main__":
    main()
