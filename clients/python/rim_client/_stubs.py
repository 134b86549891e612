"""The generated messages and stub, imported with a message that says how to get them."""

try:
    from rim.v1 import rim_pb2, rim_pb2_grpc  # noqa: F401 (re-exported)
except ImportError as error:  # pragma: no cover - depends on the environment
    raise ImportError(
        "rim_client needs its generated gRPC stubs (rim.v1.rim_pb2), which pip generates when it "
        "installs the package: 'pip install --no-build-isolation --no-index ./clients/python' "
        "(see clients/python/README.md)"
    ) from error

__all__ = ["rim_pb2", "rim_pb2_grpc"]
