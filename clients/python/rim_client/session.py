"""rim_client.Session: one robot's mapping session on a server."""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Iterable, Iterator, List, Optional, Sequence, Union

import grpc
import numpy as np

from rim_client._connection import Connection
from rim_client._stubs import rim_pb2
from rim_client.convert import Pose, as_points, box_to_proto, pose_to_proto
from rim_client.errors import RimError, invalid_argument
from rim_client.results import (Ack, MeshTile, QueryResult, Rejection, SaveResult, SessionInfo,
                                StreamSummary)

@dataclasses.dataclass
class Frame:
    """One posed scan.

    Attributes:
        points: (N, 3) ray end points in the sensor frame, metres.
        pose: world-from-sensor, a 4x4 matrix or (translation, quaternion w, x, y, z).
        timestamp_s: capture time; None stamps the frame with the time it is sent.
        origins: optional (N, 3) ray origins in the sensor frame, one per point.
    """

    points: Any
    pose: Pose
    timestamp_s: Optional[float] = None
    origins: Any = None


# Session.stream takes Frames or plain tuples (points, pose) / (points, pose, timestamp_s).
FrameLike = Union[Frame, Sequence[Any]]


def _as_frame(item: FrameLike, index: int) -> Frame:
    if isinstance(item, Frame):
        return item
    if isinstance(item, (tuple, list)) and len(item) in (2, 3):
        return Frame(*item)
    raise invalid_argument(f"frame {index}: expected a Frame or a tuple (points, pose) or "
                           f"(points, pose, timestamp_s), got {type(item).__name__}")


class Session:
    """A robot's mapping session. Get one from Client.create_session, session or load_session.

    Calls carry the metadata "x-robot-id: <robot>" so that a proxy can route by robot.
    A Session is meant for one thread at a time; use one per thread for concurrent work.
    """

    def __init__(self, client: Connection, robot_id: str, info: Optional[SessionInfo] = None):
        self._client = client
        self.robot_id = robot_id
        self.last_info = info
        # Sequence numbers grow over the whole life of this handle, across stream() calls, so
        # that acks and server logs never show two scans with the same number.
        self._next_sequence = 0

    def __repr__(self) -> str:
        return f"Session(robot_id={self.robot_id!r}, server={self._client.address!r})"

    # -- session state ---------------------------------------------------------------------------

    def get(self) -> SessionInfo:
        """The session's current state (frames, queue, map version, memory)."""
        request = rim_pb2.GetSessionRequest(robot_id=self.robot_id)
        self.last_info = SessionInfo.from_proto(
            self._client._unary(self._client._stub.GetSession, request, self.robot_id))
        return self.last_info

    def save(self) -> SaveResult:
        """Writes a checkpoint into the server's data directory."""
        request = rim_pb2.SaveSessionRequest(robot_id=self.robot_id)
        response = self._client._unary(self._client._stub.SaveSession, request, self.robot_id)
        return SaveResult(response.checkpoint, response.map_version)

    def close(self, save: bool = True) -> None:
        """Stops the session after its queue drains.

        Args:
            save: checkpoint first. With save=False the server discards the session's data.
        """
        request = rim_pb2.CloseSessionRequest(robot_id=self.robot_id, save=save)
        self._client._unary(self._client._stub.CloseSession, request, self.robot_id)

    # -- ingest ----------------------------------------------------------------------------------

    def _scan(self, frame: Frame, index: int) -> "rim_pb2.Scan":
        scan = rim_pb2.Scan(robot_id=self.robot_id, sequence=self._next_sequence)
        scan.timestamp_s = time.time() if frame.timestamp_s is None else float(frame.timestamp_s)
        scan.pose.CopyFrom(pose_to_proto(frame.pose, f"frame {index}: pose"))
        points = as_points(frame.points, f"frame {index}: points")
        scan.points_xyz = points.tobytes()
        if frame.origins is not None:
            origins = as_points(frame.origins, f"frame {index}: origins")
            if origins.shape != points.shape:
                raise invalid_argument(f"frame {index}: origins has shape {origins.shape}, "
                                       f"points {points.shape}; they must match")
            scan.origins_xyz = origins.tobytes()
        self._next_sequence += 1
        return scan

    def stream(self, frames: Iterable[FrameLike], on_ack: Optional[Callable[[Ack], None]] = None,
               timeout: Optional[float] = None, real_time: bool = False) -> StreamSummary:
        """Streams scans and returns once every accepted one is integrated into the map.

        A scan the server refuses (NaN points, a bad pose, an empty scan) is counted in
        `rejected` with its reason, and the stream goes on. Frames are read lazily, on gRPC's
        sending thread, so `frames` may be a generator that waits for a sensor; the server's
        flow control slows it down when training lags.

        Args:
            frames: Frames, or tuples (points, pose) / (points, pose, timestamp_s).
            on_ack: called with every ack as it arrives (progress, lag), on this thread.
            timeout: deadline of the whole stream in seconds; None waits as long as it takes.
            real_time: True when `frames` yields scans as a sensor makes them (a live robot): the
                stream says so (the "x-rim-real-time: 1" header) and the session trains each
                frame for what keeps up with the sensor's rate, so that the map stays current.
                False (an upload of recorded scans): each frame trains by the session's queue.

        Raises:
            RimError: the stream failed as a whole (server gone, deadline, cancelled), or a frame
                could not be encoded (INVALID_ARGUMENT naming the frame): then the stream is
                cancelled and the frames before it may or may not be integrated.
        """
        summary = StreamSummary()
        failures: List[BaseException] = []

        def requests() -> Iterator["rim_pb2.Scan"]:
            try:
                for index, item in enumerate(frames):
                    scan = self._scan(_as_frame(item, index), index)
                    summary.sent += 1
                    yield scan
            except Exception as error:  # re-raised on the caller's thread below
                # Raising here would only make gRPC log it and cancel with a vague status.
                failures.append(error)

        start = time.monotonic()
        metadata = self._client._metadata(self.robot_id)
        if real_time:
            metadata.append(("x-rim-real-time", "1"))
        call = self._client._stub.StreamScans(requests(), timeout=timeout, metadata=metadata)
        completed = False
        try:
            for message in call:
                if failures:
                    break
                ack = Ack.from_proto(message)
                _tally(summary, ack)
                if on_ack is not None:
                    on_ack(ack)
            completed = not failures
        except grpc.RpcError as error:
            if not failures:
                raise RimError.from_rpc(error) from None
        finally:
            if not completed:
                call.cancel()
        if failures:
            raise failures[0]
        summary.seconds = time.monotonic() - start
        return summary

    # -- queries ---------------------------------------------------------------------------------

    def query(self, points: Any, gradient: bool = False,
              timeout: Optional[float] = None) -> QueryResult:
        """Signed distance (and gradient) at world-frame points.

        Batches over the server's limit (Client.info().max_query_points) are split into chunks
        of that size and sent over one StreamQuerySdf call; the answer is the same as for
        chunked unary calls, in the order of `points`.

        Args:
            points: (N, 3) world-frame points, metres.
            gradient: also return the SDF gradient (N, 3).
            timeout: deadline in seconds; default: the client's timeout.

        Raises:
            RimError: INVALID_ARGUMENT for NaN/Inf or an empty batch, NOT_FOUND for a session
                that is gone.
        """
        xyz = as_points(points, "points")
        n = len(xyz)
        limit = max(1, self._client.max_query_points)
        timeout = self._client.timeout if timeout is None else timeout
        metadata = self._client._metadata(self.robot_id)

        def request(chunk: np.ndarray) -> "rim_pb2.QuerySdfRequest":
            return rim_pb2.QuerySdfRequest(robot_id=self.robot_id, points_xyz=chunk.tobytes(),
                                           want_gradient=gradient)

        try:
            if n <= limit:
                responses = [self._client._stub.QuerySdf(request(xyz), timeout=timeout,
                                                         metadata=metadata)]
            else:
                chunks = (request(xyz[i:i + limit]) for i in range(0, n, limit))
                responses = list(self._client._stub.StreamQuerySdf(chunks, timeout=timeout,
                                                                   metadata=metadata))
        except grpc.RpcError as error:
            raise RimError.from_rpc(error) from None
        return _merge(responses, n, gradient)

    # -- mesh tiles ------------------------------------------------------------------------------

    def mesh_tiles(self, since: int = 0, region: Any = None,
                   resolution_m: float = 0.0) -> List[MeshTile]:
        """Every mesh tile whose version is newer than `since`.

        Args:
            since: a tile version seen before (0: all tiles). Passing the largest version
                received so far returns only what changed after it.
            region: ((min x, y, z), (max x, y, z)): only tiles whose bounds intersect it.
            resolution_m: the level of detail, one of the session's levels
                (SessionInfo.mesh_levels_m, finest first, e.g. 0.05, 0.1, 0.2, 0.4); 0: the
                finest. Another value is RimError INVALID_ARGUMENT naming resolution_m. A tile's
                version means the same at every level.
        """
        request = rim_pb2.GetMeshTilesRequest(robot_id=self.robot_id, since_version=int(since),
                                              resolution_m=_resolution(resolution_m))
        if region is not None:
            request.region.CopyFrom(box_to_proto(region))
        try:
            stream = self._client._stub.GetMeshTiles(
                request, timeout=self._client.timeout,
                metadata=self._client._metadata(self.robot_id))
            return [MeshTile.from_proto(tile) for tile in stream]
        except grpc.RpcError as error:
            raise RimError.from_rpc(error) from None

    def watch(self, since: int = 0, timeout: Optional[float] = None,
              resolution_m: float = 0.0) -> Iterator[MeshTile]:
        """Yields tiles as training changes them, until the session closes.

        Leaving the loop (break, or closing the generator) cancels the watch on the server.

        Args:
            since: only tiles newer than this version.
            timeout: deadline of the watch in seconds (RimError DEADLINE_EXCEEDED); None: none.
            resolution_m: the level of detail the watch pushes, as in mesh_tiles (0: the
                finest). A level that is not the session's raises RimError INVALID_ARGUMENT,
                naming resolution_m, when the loop starts.
        """
        request = rim_pb2.WatchMeshTilesRequest(robot_id=self.robot_id, since_version=int(since),
                                                resolution_m=_resolution(resolution_m))
        call = self._client._stub.WatchMeshTiles(
            request, timeout=timeout, metadata=self._client._metadata(self.robot_id))
        try:
            for tile in call:
                yield MeshTile.from_proto(tile)
        except grpc.RpcError as error:
            raise RimError.from_rpc(error) from None
        finally:
            call.cancel()  # a no-op when the server already ended the stream


def _resolution(resolution_m: Any) -> float:
    """A level of detail as the float resolution_m field takes it.

    Only what is not a number is refused here: the server checks that it is one of the session's
    levels, and its INVALID_ARGUMENT names resolution_m and the levels.
    """
    try:
        return float(resolution_m)
    except (TypeError, ValueError):
        raise invalid_argument(f"resolution_m: expected a number of metres, got "
                               f"{resolution_m!r}") from None


def _tally(summary: StreamSummary, ack: Ack) -> None:
    summary.map_version = max(summary.map_version, ack.map_version)
    summary.max_lag_frames = max(summary.max_lag_frames, ack.lag_frames)
    if ack.state == "ACCEPTED":
        summary.accepted += 1
    elif ack.state == "INTEGRATED":
        summary.integrated += 1
    elif ack.state == "REJECTED":
        # Before ACCEPTED: invalid input or a full server; after it: training failed.
        summary.rejected += 1
        summary.rejections.append(Rejection(ack.sequence, ack.code, ack.reason))


def _merge(responses: Sequence["rim_pb2.QuerySdfResponse"], n: int,
           gradient: bool) -> QueryResult:
    """Concatenates chunk answers, checking that the server answered every point."""
    sdf = np.frombuffer(b"".join(r.sdf for r in responses), dtype="<f4")
    observed = np.frombuffer(b"".join(r.observed for r in responses), dtype=np.uint8)
    grad = None
    if gradient:
        grad = np.frombuffer(b"".join(r.gradient for r in responses), dtype="<f4")
    saturated = np.frombuffer(b"".join(r.saturated for r in responses), dtype=np.uint8)
    if saturated.size == 0:
        saturated = np.zeros(n, dtype=np.uint8)
    if (sdf.size != n or observed.size != n or saturated.size != n
            or (grad is not None and grad.size != 3 * n)):
        raise RimError("DATA_LOSS", f"the server answered {sdf.size} distances and "
                       f"{observed.size} observed flags for {n} points")
    return QueryResult(
        sdf=sdf.astype(np.float32),
        gradient=None if grad is None else grad.reshape(n, 3).astype(np.float32),
        observed=observed != 0,
        saturated=saturated != 0,
        map_version=max((r.map_version for r in responses), default=0),
        server_seconds=sum(r.server_seconds for r in responses))
