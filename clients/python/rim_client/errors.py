"""The one exception type of the rim client."""

from __future__ import annotations

import grpc

# ScanAck.code carries a gRPC status code as an integer; callers want its name.
_CODE_NAMES = {code.value[0]: code.name for code in grpc.StatusCode}


def code_name(code: int) -> str:
    """The gRPC status code name ("NOT_FOUND") for its number; "UNKNOWN" if unknown."""
    return _CODE_NAMES.get(int(code), "UNKNOWN")


class RimError(Exception):
    """A rim call that failed.

    Attributes:
        code: the gRPC status code name, e.g. "NOT_FOUND", "INVALID_ARGUMENT",
            "RESOURCE_EXHAUSTED". Input that the client cannot even encode (an array of the wrong
            shape, a pose that is not a rotation) is refused before it is sent, with the code the
            server would have used, "INVALID_ARGUMENT", so that callers handle one kind of error.
        message: what went wrong; for bad input it names the field.
    """

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message

    @classmethod
    def from_rpc(cls, error: grpc.RpcError) -> "RimError":
        """Wraps a failed gRPC call (status code and details)."""
        # grpc raises RpcError objects that are also grpc.Call; be lenient about the rest.
        code = error.code() if hasattr(error, "code") else None
        details = error.details() if hasattr(error, "details") else None
        name = code.name if isinstance(code, grpc.StatusCode) else "UNKNOWN"
        return cls(name, details or str(error))


def invalid_argument(message: str) -> RimError:
    """A RimError for input refused on the client side."""
    return RimError("INVALID_ARGUMENT", message)
