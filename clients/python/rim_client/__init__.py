"""Python client of the rim neural-SDF mapping service.

    import rim_client
    client = rim_client.Client("localhost:50051")
    session = client.create_session("robot_1", overrides={"train.iterations": 10})
    summary = session.stream((points_S, T_world_sensor) for points_S, T_world_sensor in scans)
    result = session.query(points_W, gradient=True)   # result.sdf, .gradient, .observed
    tiles = session.mesh_tiles(since=0)               # Draco-encoded mesh tiles

Install with pip, which also generates the gRPC stubs (clients/python/README.md).
"""

from rim_client.client import Client
from rim_client.convert import quaternion_to_rotation, rotation_to_quaternion
from rim_client.errors import RimError
from rim_client.results import (Ack, MeshTile, QueryResult, Rejection, SaveResult, ServerInfo,
                                SessionInfo, StreamSummary)
from rim_client.session import Frame, Session

__all__ = [
    "Ack", "Client", "Frame", "MeshTile", "QueryResult", "Rejection", "RimError", "SaveResult",
    "ServerInfo", "Session", "SessionInfo", "StreamSummary", "quaternion_to_rotation",
    "rotation_to_quaternion",
]
