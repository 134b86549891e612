"""numpy arrays and poses to the packed wire formats of rim.proto, with checks that name the field.

Only what the client cannot encode is refused here (wrong shapes, a pose matrix that is not a rigid
transform). Values the server validates itself (NaN or Inf points, a non-unit quaternion) are sent
as given, so that the server's answer names the problem the same way for every client.
"""

from __future__ import annotations

import math
from typing import Any, Sequence, Tuple, Union

import numpy as np

from rim_client._stubs import rim_pb2
from rim_client.errors import invalid_argument

# A pose is world-from-sensor: a 4x4 homogeneous matrix, or (translation xyz, quaternion wxyz).
Pose = Union[np.ndarray, Tuple[Sequence[float], Sequence[float]]]

# How far the rotation block of a 4x4 pose may be from orthonormal. Poses from float32 pipelines
# carry ~1e-6 errors; anything near 1e-3 is not a rotation but, e.g., a scaled or sheared matrix.
_ROTATION_TOLERANCE = 1e-4


def as_points(points: Any, field: str) -> np.ndarray:
    """`points` as a C-contiguous little-endian float32 (N, 3) array."""
    try:
        array = np.asarray(points, dtype=np.float32)
    except (TypeError, ValueError) as error:
        raise invalid_argument(f"{field}: not a numeric (N, 3) array ({error})") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise invalid_argument(f"{field}: expected an (N, 3) array, got shape {array.shape}")
    return np.ascontiguousarray(array, dtype="<f4")


def pack_points(points: Any, field: str) -> bytes:
    """Packed float32 xyz triples, as rim.proto's `bytes` point fields carry them."""
    return as_points(points, field).tobytes()


def rotation_to_quaternion(rotation: np.ndarray) -> Tuple[float, float, float, float]:
    """A rotation matrix as a unit quaternion (w, x, y, z) with w >= 0.

    Shepperd's method: it divides by the largest of the four candidate components, so it stays
    accurate for rotations near 180 degrees where the trace alone would lose precision.
    """
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    norm = math.sqrt(sum(c * c for c in q))
    sign = -1.0 if q[0] < 0.0 else 1.0  # q and -q are the same rotation; report one of them
    return tuple(sign * c / norm for c in q)  # type: ignore[return-value]


def quaternion_to_rotation(quaternion: Sequence[float]) -> np.ndarray:
    """The 3x3 rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(c) for c in quaternion)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _matrix_pose(matrix: np.ndarray, field: str) -> Tuple[np.ndarray, Tuple[float, ...]]:
    translation = matrix[:3, 3]
    if not np.all(np.isfinite(matrix)):
        # The server names the non-finite component; a quaternion from NaNs is all NaN anyway.
        return translation, (math.nan,) * 4
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
        raise invalid_argument(f"{field}: the last row of a 4x4 pose must be (0, 0, 0, 1), "
                               f"got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    error = np.abs(rotation @ rotation.T - np.eye(3)).max()
    if error > _ROTATION_TOLERANCE or np.linalg.det(rotation) <= 0.0:
        raise invalid_argument(f"{field}: the 3x3 block of the 4x4 pose is not a rotation "
                               f"(|R R^T - I| = {error:.2g}, det = {np.linalg.det(rotation):.3g})")
    return translation, rotation_to_quaternion(rotation)


def pose_to_proto(pose: Pose, field: str = "pose") -> "rim_pb2.Pose":
    """A world-from-sensor pose as rim.v1.Pose.

    Accepts a 4x4 matrix or a pair (translation (3,), quaternion (4,) as w, x, y, z).
    """
    if isinstance(pose, (tuple, list)) and len(pose) == 2:
        try:
            translation = np.asarray(pose[0], dtype=np.float64).reshape(-1)
            quaternion = np.asarray(pose[1], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as error:
            raise invalid_argument(f"{field}: not numeric ({error})") from None
        if translation.shape != (3,) or quaternion.shape != (4,):
            raise invalid_argument(
                f"{field}: expected (translation of 3, quaternion w, x, y, z of 4), got sizes "
                f"({translation.size}, {quaternion.size})")
    else:
        try:
            matrix = np.asarray(pose, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise invalid_argument(f"{field}: not a numeric 4x4 matrix ({error})") from None
        if matrix.shape != (4, 4):
            raise invalid_argument(f"{field}: expected a 4x4 matrix or (translation, quaternion "
                                   f"wxyz), got an array of shape {matrix.shape}")
        translation, quaternion = _matrix_pose(matrix, field)
    message = rim_pb2.Pose()
    message.translation.x, message.translation.y, message.translation.z = (
        float(c) for c in translation)
    message.rotation.w, message.rotation.x, message.rotation.y, message.rotation.z = (
        float(c) for c in quaternion)
    return message


def box_to_proto(region: Any, field: str = "region") -> "rim_pb2.Box3":
    """An axis-aligned box ((min x, y, z), (max x, y, z)) as rim.v1.Box3."""
    try:
        corners = np.asarray(region, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise invalid_argument(f"{field}: not numeric ({error})") from None
    if corners.shape != (2, 3):
        raise invalid_argument(
            f"{field}: expected ((min x, y, z), (max x, y, z)), got shape {corners.shape}")
    if not np.all(np.isfinite(corners)) or np.any(corners[0] > corners[1]):
        raise invalid_argument(f"{field}: min must be finite and <= max, got {corners.tolist()}")
    box = rim_pb2.Box3()
    box.min.x, box.min.y, box.min.z = (float(c) for c in corners[0])
    box.max.x, box.max.y, box.max.z = (float(c) for c in corners[1])
    return box
