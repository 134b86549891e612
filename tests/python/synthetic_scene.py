"""An analytic test scene for the Python client tests: the ground plane z = 0 and one box, seen by a
simulated LiDAR whose rays are intersected with the scene in closed form (numpy, no randomness)."""

from __future__ import annotations

import math
from typing import List, Tuple

import numpy as np

GROUND_Z = 0.0
# The same box as tests/integration/server_e2e_test.cc: 0.6 m deep, 1.2 m wide, 1.3 m tall.
BOX_MIN = np.array([1.0, -0.6, -0.1])
BOX_MAX = np.array([1.6, 0.6, 1.2])
SENSOR_HEIGHT_M = 1.0


def box_sdf(points: np.ndarray) -> np.ndarray:
    """Exact signed distance of the box alone at (N, 3) points."""
    centre = (BOX_MIN + BOX_MAX) / 2
    half = (BOX_MAX - BOX_MIN) / 2
    q = np.abs(points - centre) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def sdf(points: np.ndarray) -> np.ndarray:
    """Exact signed distance of the scene (ground half-space union box) at (N, 3) points."""
    return np.minimum(points[:, 2] - GROUND_Z, box_sdf(points))


def yaw_pose(x: float, y: float, z: float, yaw_rad: float) -> np.ndarray:
    """The 4x4 world-from-sensor pose of a level sensor at (x, y, z) turned by `yaw_rad`."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = (x, y, z)
    return pose


def trajectory(frames: int) -> List[np.ndarray]:
    """A straight drive along x from -0.5 to 0.4 m at sensor height, with a small yaw wobble."""
    poses = []
    for i in range(frames):
        t = i / (frames - 1) if frames > 1 else 0.0
        yaw = math.radians(3.0) * math.sin(1.3 * i)
        poses.append(yaw_pose(-0.5 + 0.9 * t, 0.0, SENSOR_HEIGHT_M, yaw))
    return poses


def lidar_directions(beams: int = 16, columns: int = 360, elev_min_deg: float = -60.0,
                     elev_max_deg: float = 15.0) -> np.ndarray:
    """Unit ray directions (beams * columns, 3) in the sensor frame, ring-major."""
    elevation = np.radians(np.linspace(elev_min_deg, elev_max_deg, beams))
    azimuth = 2.0 * np.pi * np.arange(columns) / columns
    e, a = np.meshgrid(elevation, azimuth, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)


def raycast(origin_w: np.ndarray, directions_w: np.ndarray) -> np.ndarray:
    """Distance along each unit direction to the first surface; inf where nothing is hit."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dz = directions_w[:, 2]
        t_ground = np.where(dz < -1e-9, (GROUND_Z - origin_w[2]) / dz, np.inf)
        # Slab test: the ray is inside the box between the largest entry and smallest exit.
        inverse = 1.0 / directions_w
        t1 = (BOX_MIN - origin_w) * inverse
        t2 = (BOX_MAX - origin_w) * inverse
        t_enter = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf).max(axis=1)
        t_exit = np.nan_to_num(np.maximum(t1, t2), nan=np.inf).min(axis=1)
    t_box = np.where((t_exit >= t_enter) & (t_enter > 0.0), t_enter, np.inf)
    return np.minimum(t_ground, t_box)


def simulate_scan(pose: np.ndarray, max_range_m: float = 6.0) -> np.ndarray:
    """The LiDAR's hits from `pose`, (N, 3) float32 in the SENSOR frame."""
    directions_s = lidar_directions()
    directions_w = directions_s @ pose[:3, :3].T
    distance = raycast(pose[:3, 3], directions_w)
    hit = distance <= max_range_m
    return (directions_s[hit] * distance[hit, None]).astype(np.float32)


def to_world(pose: np.ndarray, points_s: np.ndarray) -> np.ndarray:
    return points_s.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]


def yaw_quaternion(pose: np.ndarray) -> Tuple[np.ndarray, Tuple[float, float, float, float]]:
    """(translation, quaternion w, x, y, z) of a yaw-only pose, computed independently of the
    client's matrix conversion."""
    yaw = math.atan2(pose[1, 0], pose[0, 0])
    return pose[:3, 3].copy(), (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
