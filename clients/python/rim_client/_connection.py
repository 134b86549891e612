"""What a Session asks of the Client that made it: the channel's stub and the per-call plumbing.

session.py names this Protocol rather than the Client class, so that client.py imports session.py
and nothing imports back: the package's imports go one way.
"""

from __future__ import annotations

from typing import Any, Callable, Optional, Protocol, Sequence, Tuple


# gRPC call metadata: (key, value) pairs.
Metadata = Sequence[Tuple[str, str]]


class Connection(Protocol):
    """The connection a Session calls through (rim_client.Client is one)."""

    address: str
    timeout: Optional[float]
    _stub: Any  # rim_pb2_grpc.RimStub

    @property
    def max_query_points(self) -> int:
        """The server's unary query limit."""
        ...

    def _metadata(self, robot_id: Optional[str] = None) -> Metadata:
        """Per-call metadata: the robot a call is about and the token."""
        ...

    def _unary(self, method: Callable[..., Any], request: Any,
               robot_id: Optional[str] = None) -> Any:
        """Calls a unary method with the timeout and metadata; RimError on failure."""
        ...
