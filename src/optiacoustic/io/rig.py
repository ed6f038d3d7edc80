"""A sonar-camera rig from a static transform: ``/tf_static`` in a bag, or a YAML file.

The transform is the ROS one: with parent frame ``P`` and child frame ``C`` it maps child
coordinates to parent ones, ``p_P = R(q) p_C + t``. Our rig (DESIGN.md, thesis eq. 4.5)
is ``P_s = R P_o + t``: the transform from camera (child) to sonar (parent), expressed
in *our* sonar axes (X right, Y forward, Z up) and OpenCV camera axes (X right, Y down,
Z forward). Frames in ROS usually follow other axes, so each side names its axes:

- ``sonar_axes``: ``"rep103"`` (X forward, Y left, Z up; REP 103, the usual
  ``sonar_link``), ``"marine_acoustic"`` (Z forward, Y left, X down: the
  ``ProjectedSonarImage`` frame in which a beam at our azimuth ``theta`` points along
  ``(0, -sin theta, cos theta)``; with "X up" that frame would be left-handed) or ``"optiacoustic"`` (ours);
- ``camera_axes``: ``"optical"`` (OpenCV, the usual ``*_optical_frame``) or ``"rep103"``.

YAML form::

    parent: sonar            # the frame the transform maps into (sonar or camera)
    child: camera
    translation: [x, y, z]   # m, child origin in the parent frame
    rotation: [qx, qy, qz, qw]   # unit quaternion (or {x:, y:, z:, w:})
    sonar_axes: rep103
    camera_axes: optical
    camera_info: camera_info.yaml   # optional, relative to this file

If ``parent`` is the camera, the transform is inverted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import PinholeCamera
from ..rig import Rig
from .errors import ReadError, read_yaml_mapping

__all__ = ["read_rig", "rig_from_transform", "AXES"]

#: R_ours_from_theirs for each axis convention.
AXES = {
    "optiacoustic": np.eye(3),
    "rep103": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),          # ours X = -Y, Y = X, Z = Z
    "marine_acoustic": np.array([[0.0, -1, 0], [0, 0, 1], [-1, 0, 0]]),  # ours X = -Y, Y = Z, Z = -X
}
CAMERA_AXES = {
    "optical": np.eye(3),
    "rep103": np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]),  # optical X = -Y, Y = -Z, Z = X
}


def rig_from_transform(translation, quaternion_xyzw, camera: PinholeCamera, *, parent_is_sonar: bool = True,
                       sonar_axes: str = "rep103", camera_axes: str = "optical", sonar=None) -> Rig:
    """A :class:`Rig` from a ROS-style static transform (see the module docstring)."""
    from scipy.spatial.transform import Rotation

    if sonar_axes not in AXES:
        raise ValueError(f"sonar_axes must be one of {sorted(AXES)}, got {sonar_axes!r}")
    if camera_axes not in CAMERA_AXES:
        raise ValueError(f"camera_axes must be one of {sorted(CAMERA_AXES)}, got {camera_axes!r}")
    q = np.asarray(quaternion_xyzw, float)
    t = np.asarray(translation, float)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > 1e-3:
        raise ValueError(f"rotation: expected a unit quaternion (x, y, z, w), got {q.tolist()}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"translation: expected 3 finite numbers (m), got {t.tolist()}")
    R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    if not parent_is_sonar:  # camera <- sonar given: invert to sonar <- camera
        R, t = R.T, -R.T @ t
    M, C = AXES[sonar_axes], CAMERA_AXES[camera_axes]
    return Rig(M @ R @ C.T, M @ t, camera, sonar)


def read_rig(path, *, camera: PinholeCamera | None = None, sonar_frame: str | None = None,
             camera_frame: str | None = None, sonar_axes: str | None = None, camera_axes: str | None = None,
             topic: str = "/tf_static") -> Rig:
    """Read a sonar-camera :class:`Rig` from a YAML transform file or a bag's ``/tf_static``.

    Parameters
    ----------
    path : path-like
        A YAML file (see the module docstring) or a bag.
    camera : PinholeCamera, optional
        The camera's intrinsics; default the YAML's ``camera_info`` or the bag's
        ``CameraInfo`` message.
    sonar_frame, camera_frame : str, optional
        For bags: the frame ids to connect (default: the only transform on the topic).
    sonar_axes, camera_axes : str, optional
        Axis conventions of the two frames (default ``rep103`` and ``optical``).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    if p.suffix.lower() in (".yaml", ".yml"):
        return _rig_yaml(p, camera, sonar_axes, camera_axes)
    return _rig_bag(p, camera, sonar_frame, camera_frame, sonar_axes or "rep103", camera_axes or "optical", topic)


def _rig_yaml(p, camera, sonar_axes, camera_axes):
    from .camera_info import read_camera_info

    d = read_yaml_mapping(p, "a mapping with translation and rotation")
    allowed = {"parent", "child", "translation", "rotation", "quaternion", "sonar_axes", "camera_axes", "camera_info"}
    extra = set(d) - allowed
    if extra:
        raise ReadError(p, f"field '{sorted(extra)[0]}': unknown; expected {sorted(allowed)}")
    for k in ("translation",):
        if k not in d:
            raise ReadError(p, f"missing field '{k}'")
    q = d.get("rotation", d.get("quaternion"))
    if q is None:
        raise ReadError(p, "missing field 'rotation' (quaternion x, y, z, w)")
    if isinstance(q, dict):
        try:
            q = [q["x"], q["y"], q["z"], q["w"]]
        except KeyError as exc:
            raise ReadError(p, f"rotation: missing '{exc.args[0]}'") from None
    t = d["translation"]
    if isinstance(t, dict):
        t = [t.get("x"), t.get("y"), t.get("z")]
    parent = d.get("parent", "sonar")
    if parent not in ("sonar", "camera"):
        raise ReadError(p, f"parent must be 'sonar' or 'camera', got {parent!r}")
    if camera is None:
        if "camera_info" not in d:
            raise ReadError(p, "no camera intrinsics: pass camera= or add camera_info: FILE")
        camera = read_camera_info((p.parent / d["camera_info"]))
    try:
        return rig_from_transform(t, q, camera, parent_is_sonar=parent == "sonar",
                                  sonar_axes=sonar_axes or d.get("sonar_axes", "rep103"),
                                  camera_axes=camera_axes or d.get("camera_axes", "optical"))
    except (TypeError, ValueError) as exc:
        raise ReadError(p, str(exc)) from None


def _rig_bag(p, camera, sonar_frame, camera_frame, sonar_axes, camera_axes, topic):
    from .camera_info import camera_from_message
    from .rosbag import bag_topics, open_bag

    reader = open_bag(p)
    try:
        topics = bag_topics(reader)
        if topic not in topics:
            raise ReadError(p, f"no topic {topic!r}; topics: {sorted(topics)}")
        conns = [c for c in reader.connections if c.topic == topic]
        tfs = []
        for c, _, raw in reader.messages(connections=conns):
            tfs.extend(reader.deserialize(raw, c.msgtype).transforms)
        pick = []
        for tf in tfs:
            par, child = tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/")
            if sonar_frame is None and camera_frame is None:
                pick.append((tf, True))
            elif {par, child} == {sonar_frame, camera_frame}:
                pick.append((tf, par == sonar_frame))
        if len(pick) != 1:
            names = [f"{tf.header.frame_id} -> {tf.child_frame_id}" for tf in tfs]
            raise ReadError(p, f"{len(pick)} matching transforms (need one; pass sonar_frame= and camera_frame=). "
                               f"Transforms: {names}", topic=topic)
        tf, parent_is_sonar = pick[0]
        if camera is None:
            infos = [c for c in reader.connections if c.msgtype.endswith("CameraInfo")]
            for c, _, raw in (reader.messages(connections=infos) if infos else ()):
                camera = camera_from_message(reader.deserialize(raw, c.msgtype), f"{p}:{c.topic}")
                break
        if camera is None:
            raise ReadError(p, "no camera intrinsics: pass camera= (the bag has no CameraInfo)")
        tr, rq = tf.transform.translation, tf.transform.rotation
        return rig_from_transform([tr.x, tr.y, tr.z], [rq.x, rq.y, rq.z, rq.w], camera,
                                  parent_is_sonar=parent_is_sonar, sonar_axes=sonar_axes, camera_axes=camera_axes)
    finally:
        reader.close()
