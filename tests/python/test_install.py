#!/usr/bin/env python3
"""rim_client as pip installed it: the package and its generated stubs come from the environment's
site-packages, not from the source tree, and the stubs match this checkout's proto.

Usage: test_install.py SOURCE_DIR_OF_THE_PACKAGE (clients/python), run with the venv's Python.
"""

from __future__ import annotations

import ast
import os
import re
import sys
import sysconfig
import unittest

SOURCE_DIR = os.path.realpath(sys.argv.pop(1)) if len(sys.argv) > 1 else ""
PROTO = os.path.join(os.path.dirname(os.path.dirname(SOURCE_DIR)), "proto", "rim", "v1", "rim.proto")


class InstalledPackageTest(unittest.TestCase):
    def test_imports_come_from_site_packages(self):
        import rim_client
        from rim.v1 import rim_pb2, rim_pb2_grpc

        site = os.path.realpath(sysconfig.get_paths()["purelib"])
        for module in (rim_client, rim_pb2, rim_pb2_grpc):
            path = os.path.realpath(module.__file__)
            self.assertTrue(path.startswith(site + os.sep), f"{module.__name__} from {path}")
            self.assertFalse(path.startswith(SOURCE_DIR + os.sep), path)

    def test_stubs_match_the_proto(self):
        from rim.v1 import rim_pb2, rim_pb2_grpc

        with open(PROTO, encoding="utf-8") as f:
            text = f.read()
        declared = set(re.findall(r"^\s*rpc\s+(\w+)\s*\(", text, re.MULTILINE))
        messages = set(re.findall(r"^message\s+(\w+)\s*\{", text, re.MULTILINE))
        self.assertGreater(len(declared), 5)
        service = rim_pb2.DESCRIPTOR.services_by_name["Rim"]
        self.assertEqual({m.name for m in service.methods}, declared)
        self.assertEqual(set(rim_pb2.DESCRIPTOR.message_types_by_name), messages)
        self.assertTrue(hasattr(rim_pb2_grpc, "RimStub"))

    def test_client_api_is_there(self):
        import rim_client

        for name in ("Client", "Session", "RimError", "QueryResult", "MeshTile"):
            self.assertTrue(hasattr(rim_client, name), name)

    def test_imports_go_one_way(self):
        # Every import between rim_client's modules, TYPE_CHECKING ones too: no cycle.
        import rim_client

        folder = os.path.dirname(os.path.realpath(rim_client.__file__))
        graph = {}
        for name in sorted(os.listdir(folder)):
            if not name.endswith(".py") or name == "__init__.py":
                continue
            with open(os.path.join(folder, name), encoding="utf-8") as f:
                tree = ast.parse(f.read(), name)
            imported = set()
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module:
                    imported.add(node.module)
                elif isinstance(node, ast.Import):
                    imported.update(alias.name for alias in node.names)
            graph[name[:-3]] = {m.split(".")[1] for m in imported
                                if m.startswith("rim_client.") and m != "rim_client"}
        self.assertIn("session", graph["client"])
        self.assertNotIn("client", graph["session"])

        def visit(module, path):
            self.assertNotIn(module, path, " -> ".join(path + [module]))
            for target in sorted(graph.get(module, ())):
                visit(target, path + [module])

        for module in graph:
            visit(module, [])


if __name__ == "__main__":
    unittest.main()
