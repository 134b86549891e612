"""Plain result types of the rim client, converted from the wire messages."""

from __future__ import annotations

import dataclasses
from typing import Dict, List, Optional, Tuple

import numpy as np

from rim_client._stubs import rim_pb2
from rim_client.errors import code_name

Vec3 = Tuple[float, float, float]


def _vec3(v: "rim_pb2.Vec3") -> Vec3:
    return (v.x, v.y, v.z)


def _metres(value: float) -> float:
    """A float32 field as the shortest decimal that is the same float32: 0.2, not 0.2000000030.

    Sent back as a float32 field (resolution_m) it is the same value again, and it compares
    equal to the literal a caller writes.
    """
    return float(str(np.float32(value)))


@dataclasses.dataclass(frozen=True)
class ServerInfo:
    """What a server is and the limits it enforces."""

    version: str
    build: str  # "cpu" or "cuda"
    device: str
    libtorch_version: str
    max_sessions: int
    max_points_per_scan: int
    max_query_points: int  # larger query batches go through StreamQuerySdf
    queue_length: int
    host_memory_budget_bytes: int
    presets: Tuple[str, ...]

    @classmethod
    def from_proto(cls, m: "rim_pb2.ServerInfo") -> "ServerInfo":
        return cls(m.version, m.build, m.device, m.libtorch_version, m.max_sessions,
                   m.max_points_per_scan, m.max_query_points, m.queue_length,
                   m.host_memory_budget_bytes, tuple(m.presets))


def _parse_config(text: str) -> Dict[str, str]:
    """The server lists the effective config as "key = value" lines."""
    config = {}
    for line in text.splitlines():
        key, sep, value = line.partition("=")
        if sep:
            config[key.strip()] = value.strip()
    return config


@dataclasses.dataclass(frozen=True)
class SessionInfo:
    """The state of one robot's mapping session."""

    robot_id: str
    preset: str
    config: Dict[str, str]  # every effective config value, by dotted name
    accepted_frames: int
    rejected_frames: int
    integrated_frames: int
    queue_depth: int
    iterations_per_frame: int
    map_version: int
    buffer_points: int
    submaps_active: int
    submaps_frozen: int
    submaps_on_disk: int
    host_memory_bytes: int
    decoder_frozen: bool
    last_loss: float
    # The levels of detail its mesh tiles come in (cell size, metres), finest first: what
    # Session.mesh_tiles and Session.watch take as resolution_m.
    mesh_levels_m: Tuple[float, ...] = ()

    @classmethod
    def from_proto(cls, m: "rim_pb2.SessionInfo") -> "SessionInfo":
        return cls(m.robot_id, m.preset, _parse_config(m.config), m.accepted_frames,
                   m.rejected_frames, m.integrated_frames, m.queue_depth, m.iterations_per_frame,
                   m.map_version, m.buffer_points, m.submaps_active, m.submaps_frozen,
                   m.submaps_on_disk, m.host_memory_bytes, m.decoder_frozen, m.last_loss,
                   tuple(_metres(level) for level in m.mesh_levels_m))


@dataclasses.dataclass(frozen=True)
class SaveResult:
    """Where SaveSession wrote its checkpoint (relative to the server's data directory)."""

    checkpoint: str
    map_version: int


@dataclasses.dataclass(frozen=True)
class Ack:
    """One ScanAck: state is "ACCEPTED", "INTEGRATED" or "REJECTED"."""

    sequence: int
    state: str
    reason: str
    code: str  # gRPC status code name of a rejection, "OK" otherwise
    queue_depth: int
    lag_frames: int
    iterations: int
    map_version: int

    @classmethod
    def from_proto(cls, m: "rim_pb2.ScanAck") -> "Ack":
        return cls(m.sequence, rim_pb2.ScanAck.State.Name(m.state), m.reason, code_name(m.code),
                   m.queue_depth, m.lag_frames, m.iterations, m.map_version)


@dataclasses.dataclass(frozen=True)
class Rejection:
    """A scan the server did not take (or could not train): its sequence number and why."""

    sequence: int
    code: str
    reason: str


@dataclasses.dataclass
class StreamSummary:
    """The outcome of Session.stream, complete once every accepted scan was integrated."""

    sent: int = 0
    accepted: int = 0
    integrated: int = 0
    rejected: int = 0
    rejections: List[Rejection] = dataclasses.field(default_factory=list)
    map_version: int = 0
    max_lag_frames: int = 0
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """True when every scan sent was accepted and integrated."""
        return self.rejected == 0 and self.integrated == self.sent


@dataclasses.dataclass(frozen=True)
class QueryResult:
    """Signed distances at a batch of points, in the order they were given.

    `sdf` is the signed Euclidean distance to the nearest mapped surface (positive in free
    space), bounded by the session's query.max_distance_m; where `saturated` is True no surface
    lies that near and the value means "at least this far". `gradient` has unit length and points
    away from the nearest surface (zero where saturated). Where `observed` is False the map never
    saw that place: planners should treat it as unknown, not as free.
    """

    sdf: np.ndarray  # (N,) float32, metres
    gradient: Optional[np.ndarray]  # (N, 3) float32 when asked for, else None
    observed: np.ndarray  # (N,) bool
    map_version: int
    server_seconds: float  # summed over the batches the query was split into
    saturated: Optional[np.ndarray] = None  # (N,) bool


@dataclasses.dataclass(frozen=True)
class MeshTile:
    """One sub-map's mesh, Draco-encoded (decode with any Draco decoder)."""

    key: Tuple[int, int, int]  # sub-map index
    version: int
    bounds: Tuple[Vec3, Vec3]  # (min, max) corners, metres, world frame
    draco: bytes
    vertex_count: int
    face_count: int
    # The level of detail it was meshed at (mesh cell size, metres; one of
    # SessionInfo.mesh_levels_m). Positions are quantised to within max(1 mm, resolution_m / 50).
    resolution_m: float = 0.0

    @classmethod
    def from_proto(cls, m: "rim_pb2.MeshTile") -> "MeshTile":
        return cls((m.key_x, m.key_y, m.key_z), m.version,
                   (_vec3(m.bounds.min), _vec3(m.bounds.max)), bytes(m.draco), m.vertex_count,
                   m.face_count, _metres(m.resolution_m))
