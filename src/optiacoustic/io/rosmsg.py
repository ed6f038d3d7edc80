"""ROS message definitions shipped as text, and a rosbags typestore that knows them.

``rosbags`` has the standard ROS 1 and ROS 2 messages built in (``std_msgs``,
``geometry_msgs``, ``sensor_msgs/Image``, ``CompressedImage``, ``CameraInfo``,
``tf2_msgs/TFMessage``). The sonar messages of ``marine_acoustic_msgs`` (the ROS 1 and
ROS 2 package of apl-ocean-engineering/marine_msgs, version 2.x) are not, so their
definitions live here as the ``.msg`` text the package publishes and are registered at
run time with :func:`rosbags.typesys.get_types_from_msg`.

Conventions of ``ProjectedSonarImage`` (from the ``.msg`` comments):

- frame: Z forward (centre of the fan), X up; beams lie in the Y-Z plane. A beam at our
  azimuth ``theta`` (positive to starboard, docs/conventions.md) has direction
  ``(0, -sin theta, cos theta)``, so ``theta = atan2(-y, z)``;
- ``ranges``: centre of each range bin (m), not necessarily evenly spaced;
- ``image.data``: bytes of a ``(n_ranges, beam_count)`` row-major array (the beam index
  varies fastest), element type ``image.dtype`` (``DTYPE_*``), byte order
  ``image.is_bigendian``.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = [
    "MESSAGE_DEFINITIONS",
    "SONAR_IMAGE_DTYPES",
    "PROJECTED_SONAR_IMAGE",
    "typestore",
]

#: Full ROS type name of the sonar image message.
PROJECTED_SONAR_IMAGE = "marine_acoustic_msgs/msg/ProjectedSonarImage"

_PING_INFO = """\
# Center frequency of sonar in Hz; 0 if unavailable
float32 frequency
# Speed of sound (m/s) used to calculate ranges; 0 if unavailable
float32 sound_speed
# Sonar reported -3 dB beamwidths (rad); may be empty
float32[] tx_beamwidths
float32[] rx_beamwidths
"""

_SONAR_IMAGE_DATA = """\
bool is_bigendian
uint32 DTYPE_UINT8=0
uint32 DTYPE_INT8=1
uint32 DTYPE_UINT16=2
uint32 DTYPE_INT16=3
uint32 DTYPE_UINT32=4
uint32 DTYPE_INT32=5
uint32 DTYPE_UINT64=6
uint32 DTYPE_INT64=7
uint32 DTYPE_FLOAT32=8
uint32 DTYPE_FLOAT64=9
uint32 dtype
# number of beams in the image
uint32 beam_count
# pixel data, row-major with the beam index fastest
uint8[] data
"""

_PROJECTED_SONAR_IMAGE = """\
# Z forward (centre of the fan), X up; beams in the Y-Z plane.
# header stamp: time the ping was transmitted
std_msgs/Header header
marine_acoustic_msgs/PingInfo ping_info
geometry_msgs/Vector3[] beam_directions
# centre of each range bin (m); not necessarily evenly spaced
float32[] ranges
marine_acoustic_msgs/SonarImageData image
"""

_TF_MESSAGE = """\
geometry_msgs/TransformStamped[] transforms
"""

#: ROS type name -> ``.msg`` text of the messages rosbags does not ship (``TFMessage``
#: is built into its ROS 2 stores but not its ROS 1 store; it is registered only where absent).
MESSAGE_DEFINITIONS: dict[str, str] = {
    "tf2_msgs/msg/TFMessage": _TF_MESSAGE,
    "marine_acoustic_msgs/msg/PingInfo": _PING_INFO,
    "marine_acoustic_msgs/msg/SonarImageData": _SONAR_IMAGE_DATA,
    PROJECTED_SONAR_IMAGE: _PROJECTED_SONAR_IMAGE,
}

#: ``SonarImageData.dtype`` code -> numpy dtype (native byte order; see ``is_bigendian``).
SONAR_IMAGE_DTYPES: dict[int, np.dtype] = {
    0: np.dtype(np.uint8),
    1: np.dtype(np.int8),
    2: np.dtype(np.uint16),
    3: np.dtype(np.int16),
    4: np.dtype(np.uint32),
    5: np.dtype(np.int32),
    6: np.dtype(np.uint64),
    7: np.dtype(np.int64),
    8: np.dtype(np.float32),
    9: np.dtype(np.float64),
}


def dtype_code(dtype) -> int:
    """The ``SonarImageData.dtype`` code of a numpy dtype (byte order ignored)."""
    dt = np.dtype(dtype).newbyteorder("=")
    for code, d in SONAR_IMAGE_DTYPES.items():
        if d == dt:
            return code
    raise ValueError(f"ProjectedSonarImage cannot carry dtype {np.dtype(dtype)}; "
                     f"supported: {[str(d) for d in SONAR_IMAGE_DTYPES.values()]}")


@functools.lru_cache(maxsize=None)
def typestore(ros: int = 2):
    """A rosbags typestore with the standard messages and ``marine_acoustic_msgs``.

    Parameters
    ----------
    ros : {1, 2}
        ROS 1 (Noetic: headers carry ``seq``) or ROS 2 (Humble) built-in messages.

    Returns
    -------
    rosbags.typesys.store.Typestore
        Cached: the same object for the same ``ros``; do not register conflicting types in it.
    """
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    if ros not in (1, 2):
        raise ValueError(f"typestore: ros must be 1 or 2, got {ros!r}")
    store = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in MESSAGE_DEFINITIONS.items():
        if name in store.types:
            continue
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
