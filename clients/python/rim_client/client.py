"""rim_client.Client: a connection to one rim server."""

from __future__ import annotations

from typing import Any, Callable, List, Mapping, Optional

import grpc

from rim_client._connection import Metadata
from rim_client._stubs import rim_pb2, rim_pb2_grpc
from rim_client.errors import RimError, invalid_argument
from rim_client.results import ServerInfo, SessionInfo
from rim_client.session import Session

# Scans and query batches are large; the server accepts messages up to 256 MiB and enforces its
# own point limits, which give clearer errors than a transport limit would.
_MAX_MESSAGE_BYTES = 256 << 20


def _override_value(value: Any) -> str:
    # The server parses overrides as text, like its config files: booleans are true/false.
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


class Client:
    """A connection to a rim server.

    Example:
        with rim_client.Client("localhost:50051") as client:
            session = client.create_session("robot_1", preset="maicity",
                                            overrides={"train.iterations": 10})
            summary = session.stream(frames)
            result = session.query(points, gradient=True)

    Every failed call raises RimError with the gRPC status code name and the server's message.
    """

    def __init__(self, address: str, token: Optional[str] = None,
                 timeout: Optional[float] = 30.0,
                 credentials: Optional[grpc.ChannelCredentials] = None,
                 tls_ca: Optional[str] = None, tls_cert: Optional[str] = None,
                 tls_key: Optional[str] = None) -> None:
        """Opens a channel (connecting lazily, on the first call).

        Args:
            address: "host:port" of the server.
            token: sent as "authorization: Bearer <token>" on every call when given.
            timeout: deadline in seconds of unary calls and query streams; None waits forever.
                Scan streams and tile watches take their own timeout (default: none).
            credentials: TLS channel credentials; None for a plaintext channel (unless a tls_*
                file is given).
            tls_ca: PEM file of the CA that signs the server's certificate; turns TLS on (with
                tls_cert and tls_key but no tls_ca, the system roots are trusted).
            tls_cert, tls_key: PEM files of this client's certificate and key, together, for a
                server that requires client certificates (rim_server --tls-client-ca).
        """
        if credentials is None and (tls_ca or tls_cert or tls_key):
            credentials = _tls_credentials(tls_ca, tls_cert, tls_key)
        options = [("grpc.max_send_message_length", _MAX_MESSAGE_BYTES),
                   ("grpc.max_receive_message_length", _MAX_MESSAGE_BYTES)]
        if credentials is None:
            self._channel = grpc.insecure_channel(address, options=options)
        else:
            self._channel = grpc.secure_channel(address, credentials, options=options)
        self._stub = rim_pb2_grpc.RimStub(self._channel)
        self._token = token
        self.address = address
        self.timeout = timeout
        self._max_query_points: Optional[int] = None

    # -- connection ------------------------------------------------------------------------------

    def close(self) -> None:
        """Closes the channel; calls in flight are cancelled."""
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()

    def wait_ready(self, timeout: float = 10.0) -> None:
        """Blocks until the channel is connected; RimError UNAVAILABLE after `timeout` seconds."""
        try:
            grpc.channel_ready_future(self._channel).result(timeout=timeout)
        except grpc.FutureTimeoutError:
            raise RimError("UNAVAILABLE",
                           f"no connection to {self.address} within {timeout} s") from None

    # -- server and sessions ---------------------------------------------------------------------

    def info(self) -> ServerInfo:
        """Version, build, device and limits of the server."""
        info = ServerInfo.from_proto(
            self._unary(self._stub.GetServerInfo, rim_pb2.GetServerInfoRequest()))
        self._max_query_points = info.max_query_points
        return info

    @property
    def max_query_points(self) -> int:
        """The server's unary query limit (asked once, then remembered)."""
        if self._max_query_points is None:
            self.info()
        return self._max_query_points  # type: ignore[return-value]

    def create_session(self, robot_id: str, preset: Optional[str] = None,
                       overrides: Optional[Mapping[str, Any]] = None) -> Session:
        """Starts mapping for a robot.

        Args:
            robot_id: 1-64 characters of [A-Za-z0-9_.-]; names the session from now on.
            preset: maicity, maicity_online, kitti, replica, campus; None: the server default.
            overrides: config values by dotted name, e.g. {"train.iterations": 10}.

        Raises:
            RimError: ALREADY_EXISTS when the robot has a session (or a saved one: load it),
                INVALID_ARGUMENT for a bad id, preset or override (the message names it).
        """
        request = rim_pb2.CreateSessionRequest(robot_id=_check_robot_id(robot_id),
                                               preset=preset or "")
        for key, value in (overrides or {}).items():
            request.overrides.add(key=str(key), value=_override_value(value))
        info = self._unary(self._stub.CreateSession, request, robot_id)
        return Session(self, robot_id, SessionInfo.from_proto(info))

    def session(self, robot_id: str) -> Session:
        """A handle to the robot's running session; RimError NOT_FOUND when there is none."""
        request = rim_pb2.GetSessionRequest(robot_id=_check_robot_id(robot_id))
        info = self._unary(self._stub.GetSession, request, robot_id)
        return Session(self, robot_id, SessionInfo.from_proto(info))

    def load_session(self, robot_id: str) -> Session:
        """Restores a saved (or crashed) session from the server's data directory."""
        request = rim_pb2.LoadSessionRequest(robot_id=_check_robot_id(robot_id))
        info = self._unary(self._stub.LoadSession, request, robot_id)
        return Session(self, robot_id, SessionInfo.from_proto(info))

    def list_sessions(self) -> List[SessionInfo]:
        """Every running session."""
        response = self._unary(self._stub.ListSessions, rim_pb2.ListSessionsRequest())
        return [SessionInfo.from_proto(s) for s in response.sessions]

    # -- used by Session (rim_client._connection.Connection) ------------------------------------

    def _metadata(self, robot_id: Optional[str] = None) -> Metadata:
        """Per-call metadata: the robot a call is about (for routing and logs) and the token."""
        metadata = []
        if robot_id is not None:
            metadata.append(("x-robot-id", robot_id))
        if self._token is not None:
            metadata.append(("authorization", f"Bearer {self._token}"))
        return metadata

    def _unary(self, method: Callable[..., Any], request: Any,
               robot_id: Optional[str] = None) -> Any:
        try:
            return method(request, timeout=self.timeout, metadata=self._metadata(robot_id))
        except grpc.RpcError as error:
            raise RimError.from_rpc(error) from None


def _read_pem(what: str, path: Optional[str]) -> Optional[bytes]:
    if path is None:
        return None
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as error:
        raise RimError("NOT_FOUND", f"{what}: cannot read {path}: {error.strerror}") from None


def _tls_credentials(tls_ca: Optional[str], tls_cert: Optional[str],
                     tls_key: Optional[str]) -> grpc.ChannelCredentials:
    if (tls_cert is None) != (tls_key is None):
        raise invalid_argument("tls_cert and tls_key must be given together")
    return grpc.ssl_channel_credentials(root_certificates=_read_pem("tls_ca", tls_ca),
                                        private_key=_read_pem("tls_key", tls_key),
                                        certificate_chain=_read_pem("tls_cert", tls_cert))


def _check_robot_id(robot_id: Any) -> str:
    if not isinstance(robot_id, str):
        raise invalid_argument(f"robot_id: expected a string, got {type(robot_id).__name__}")
    return robot_id
