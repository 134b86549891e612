"""Build step of rim_client: generates the gRPC stubs into the package being built.

Metadata lives in pyproject.toml. The stubs are generated, never committed, so that they always
match the proto of this checkout. The proto is found at $RIM_PROTO_DIR, else at ./proto (a copy
that the CMake build makes beside this file), else at ../../proto (the source tree). protoc and
grpc_python_plugin come from $PROTOC and $GRPC_PYTHON_PLUGIN, else from PATH.
"""

import os
import shutil
import subprocess

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
PROTO = os.path.join("rim", "v1", "rim.proto")


def proto_root():
    candidates = [os.environ.get("RIM_PROTO_DIR", ""), os.path.join(HERE, "proto"),
                  os.path.join(HERE, "..", "..", "proto")]
    for root in candidates:
        if root and os.path.isfile(os.path.join(root, PROTO)):
            return os.path.abspath(root)
    raise RuntimeError(f"rim_client: {PROTO} not found (looked in {candidates}); set RIM_PROTO_DIR")


def tool(name, package, env):
    path = os.environ.get(env) or shutil.which(name)
    if path is None:
        raise RuntimeError(f"rim_client: '{name}' not found; install Debian's {package}")
    return path


class BuildWithStubs(build_py):
    """build_py, then protoc writes rim/v1/rim_pb2.py and rim_pb2_grpc.py into the build tree."""

    def run(self):
        super().run()
        root = proto_root()
        out = self.build_lib
        os.makedirs(os.path.join(out, "rim", "v1"), exist_ok=True)
        subprocess.run(
            [tool("protoc", "protobuf-compiler", "PROTOC"), f"--proto_path={root}", f"--python_out={out}",
             f"--grpc_python_out={out}",
             f"--plugin=protoc-gen-grpc_python={tool('grpc_python_plugin', 'protobuf-compiler-grpc', 'GRPC_PYTHON_PLUGIN')}",
             os.path.join(root, PROTO)],
            check=True)
        # rim_pb2_grpc imports "rim.v1.rim_pb2": both folders must be packages.
        for package in ("rim", os.path.join("rim", "v1")):
            open(os.path.join(out, package, "__init__.py"), "a").close()


setup(cmdclass={"build_py": BuildWithStubs})
