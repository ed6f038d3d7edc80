"""Draw the documentation figures: docs/img/frames.png (conventions) and the README picture.

Run with ``make docs-figures`` (or ``.venv/bin/python docs/make_figures.py``).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from optiacoustic._atomic import savefig  # noqa: E402

HERE = Path(__file__).resolve().parent
IMG = HERE / "img"


def _arrow(ax, o, v, color, label, off=1.08):
    ax.quiver(*o, *v, color=color, arrow_length_ratio=0.12, linewidth=2)
    ax.text(*(o + off * np.asarray(v)), label, color=color, fontsize=11, fontweight="bold")


def frames_figure(path: Path) -> None:
    from optiacoustic import PinholeCamera, Rig
    from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD, sonar_from_spherical

    fig = plt.figure(figsize=(13, 6))
    # --- left: the rig, both frames drawn in the sonar frame
    ax = fig.add_subplot(121, projection="3d")
    rig = Rig.toed_in(PinholeCamera.from_sensor(), baseline=0.25, vergence=np.deg2rad(8))
    o_s = np.zeros(3)
    L = 0.18
    for v, lab in zip(np.eye(3) * L, ("X_s (right)", "Y_s (forward)", "Z_s (up)")):
        _arrow(ax, o_s, v, "tab:red", lab)
    o_c = rig.t
    for v, lab in zip(rig.R.T * L, ("X_o (right)", "Y_o (down)", "Z_o (optical axis)")):
        _arrow(ax, o_c, v, "tab:blue", lab)
    # the sonar's fan: 90 x 20 deg, drawn to 0.6 m
    th = np.linspace(-np.pi / 4, np.pi / 4, 30)
    for ph in (-np.deg2rad(10), np.deg2rad(10)):
        arc = sonar_from_spherical(0.6, th, ph)
        ax.plot(*arc.T, color="tab:orange", lw=1)
    for t_ in (th[0], th[-1]):
        for ph in (-np.deg2rad(10), np.deg2rad(10)):
            ax.plot(*np.stack([o_s, sonar_from_spherical(0.6, t_, ph)]).T, color="tab:orange", lw=0.8)
    ax.plot(*np.stack([o_s, o_c]).T, "k--", lw=1)
    ax.text(*(o_c / 2 + [0.0, 0.0, 0.1]), "t", fontsize=12)
    ax.set_xlim(-0.35, 0.35)
    ax.set_ylim(-0.1, 0.6)
    ax.set_zlim(-0.25, 0.25)
    ax.set_box_aspect((0.7, 0.7, 0.5))
    ax.view_init(elev=24, azim=-62)
    ax.set_title("Rig: P_s = R P_o + t  (R = R_sonar_from_camera)")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])

    # --- right: a sonar point's range, azimuth and elevation, and the fan image
    ax2 = fig.add_subplot(122, projection="3d")
    r, th0, ph0 = 1.0, np.deg2rad(30), np.deg2rad(20)
    P = sonar_from_spherical(r, th0, ph0)
    for v, lab in zip(np.eye(3) * 0.5, ("X", "Y (boresight)", "Z")):
        _arrow(ax2, np.zeros(3), v, "tab:red", lab)
    ax2.plot(*np.stack([np.zeros(3), P]).T, "k-", lw=2)
    ax2.scatter(*P, color="k")
    ax2.text(*(P * 1.05), "P", fontsize=12)
    Pg = np.array([P[0], P[1], 0.0])
    ax2.plot(*np.stack([P, Pg]).T, "k:", lw=1)
    ax2.plot(*np.stack([np.zeros(3), Pg]).T, "k:", lw=1)
    a = np.linspace(0, th0, 20)
    ax2.plot(0.35 * np.sin(a), 0.35 * np.cos(a), 0 * a, color="tab:green", lw=2)
    ax2.text(0.2, 0.4, 0, "theta = atan2(X, Y)", color="tab:green")
    b = np.linspace(0, ph0, 20)
    ax2.plot(0.6 * np.cos(b) * np.sin(th0), 0.6 * np.cos(b) * np.cos(th0), 0.6 * np.sin(b), color="tab:purple", lw=2)
    ax2.text(0.35, 0.55, 0.2, "phi = atan2(Z, hypot(X, Y))", color="tab:purple")
    ax2.text(0.05, 0.05, 0.35, "r = |P|", color="k")
    ax2.set_xlim(-0.2, 0.8)
    ax2.set_ylim(0, 1)
    ax2.set_zlim(-0.1, 0.6)
    ax2.view_init(elev=18, azim=-52)
    ax2.set_title("Sonar measurement: (r, theta); elevation phi is lost.\nFan image: (x_s, y_s) = r (sin theta, cos theta)")
    ax2.set_xticks([])
    ax2.set_yticks([])
    ax2.set_zticks([])
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    plt.close(fig)
    assert np.allclose(R_SONAR_FROM_CAMERA_FORWARD @ [0, 0, 1], [0, 1, 0])


def readme_figure(path: Path) -> None:
    from optiacoustic import Pose, SonarSpec, scenes, simulate_sonar
    from optiacoustic.sonar.display import to_display

    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    frame = simulate_sonar(scene, spec, Pose.look_at(scene.view.eye, scene.view.target), seed=1)
    ref = np.percentile(frame.intensity[frame.intensity > 0], 99.5)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    for ax, which, title in zip(axes, ("intensity", "image"), ("noise-free echo", "with reverberation and noise")):
        fan = frame.fan(which, width=1000)
        ax.imshow(to_display(fan.data, reference=ref), extent=fan.extent, cmap="copper")
        ax.set_xlim(-8, 8)
        ax.set_ylim(3, 15)
        ax.set_title(f"BlueView P900-90, scene 1: {title}")
        ax.set_xlabel("x_s (m)")
        ax.set_ylabel("y_s (m)")
    fig.tight_layout()
    savefig(fig, path, dpi=90)
    plt.close(fig)


def main() -> None:
    IMG.mkdir(parents=True, exist_ok=True)
    frames_figure(IMG / "frames.png")
    readme_figure(IMG / "sonar_scene1.png")
    print("wrote", IMG / "frames.png", IMG / "sonar_scene1.png")


if __name__ == "__main__":
    main()
