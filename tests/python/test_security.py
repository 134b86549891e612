#!/usr/bin/env python3
"""The Python client's TLS and token options against the real rim_server (docs/security.md).

Makes a throwaway CA, server and client certificate with openssl, starts rim_server (path in
$RIM_SERVER_BIN) with --tokens, --tls-cert/--tls-key and --tls-client-ca, and checks that
Client(tls_ca=, tls_cert=, tls_key=, token=) gets in, that a missing token is UNAUTHENTICATED and
a viewer may not create sessions, and that a client without a certificate does not get in.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import unittest
from typing import List

import rim_client

MAKE_CERTS = r"""set -e
key='-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes'
openssl req -x509 $key -keyout ca.key -out ca.crt -days 2 -subj /CN=ca \
  -addext basicConstraints=critical,CA:TRUE -addext keyUsage=critical,keyCertSign,cRLSign
printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n' > server.ext
printf 'extendedKeyUsage=clientAuth\n' > client.ext
for leaf in server client; do
  openssl req -new $key -keyout $leaf.key -out $leaf.csr -subj /CN=$leaf
  openssl x509 -req -in $leaf.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 2 \
    -out $leaf.crt -extfile $leaf.ext
done
"""
VIEWER_TOKEN = "py-viewer-2c91e0"


class SecurityTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        binary = os.environ.get("RIM_SERVER_BIN", "")
        if not os.access(binary, os.X_OK):
            raise RuntimeError(f"RIM_SERVER_BIN must name the rim_server binary, got '{binary}'")
        cls.dir = tempfile.mkdtemp(prefix="rim_python_security_")
        subprocess.run(["/bin/sh", "-c", MAKE_CERTS], cwd=cls.dir, check=True,
                       capture_output=True)
        digest = subprocess.run([binary, "--hash-token", "-"], input=VIEWER_TOKEN + "\n",
                                capture_output=True, text=True, check=True).stdout.strip()
        with open(cls.path("tokens.txt"), "w") as f:
            f.write(f"viewer wall {digest}\n")
        cls.log = open(cls.path("server.log"), "w")
        cls.server = subprocess.Popen(
            [binary, "--listen", "127.0.0.1:0", "--data-dir", cls.path("data"),
             "--warmup-frames", "0", "--tokens", cls.path("tokens.txt"),
             "--tls-cert", cls.path("server.crt"), "--tls-key", cls.path("server.key"),
             "--tls-client-ca", cls.path("ca.crt")],
            stdout=subprocess.PIPE, stderr=cls.log, text=True)
        found: List[str] = []

        def read() -> None:
            for line in cls.server.stdout:
                match = re.search(r"rim_server listening on (\S+:\d+)", line)
                if match:
                    found.append(match.group(1))
                    return

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        reader.join(30.0)
        if not found:
            cls.server.kill()
            raise RuntimeError(f"rim_server did not start; see {cls.path('server.log')}")
        cls.address = found[0]

    @classmethod
    def tearDownClass(cls) -> None:
        cls.server.send_signal(signal.SIGTERM)
        status = cls.server.wait(20)
        cls.log.close()
        if status != 0:
            with open(cls.path("server.log")) as log:
                raise AssertionError(f"rim_server exited with {status} after SIGTERM, not 0:\n"
                                     + log.read())
        shutil.rmtree(cls.dir, ignore_errors=True)

    @classmethod
    def path(cls, name: str) -> str:
        return os.path.join(cls.dir, name)

    def client(self, **kwargs) -> rim_client.Client:
        return rim_client.Client(self.address, timeout=10.0, **kwargs)

    def test_tls_client_certificate_and_token(self) -> None:
        tls = dict(tls_ca=self.path("ca.crt"), tls_cert=self.path("client.crt"),
                   tls_key=self.path("client.key"))
        with self.client(token=VIEWER_TOKEN, **tls) as client:
            self.assertTrue(client.info().version)
            self.assertEqual(client.list_sessions(), [])
            with self.assertRaises(rim_client.RimError) as denied:
                client.create_session("robot_1")
            self.assertEqual(denied.exception.code, "PERMISSION_DENIED")
        with self.client(**tls) as client:
            with self.assertRaises(rim_client.RimError) as missing:
                client.info()
            self.assertEqual(missing.exception.code, "UNAUTHENTICATED")

    def test_no_client_certificate_does_not_get_in(self) -> None:
        with self.client(token=VIEWER_TOKEN, tls_ca=self.path("ca.crt")) as client:
            with self.assertRaises(rim_client.RimError) as refused:
                client.info()
            self.assertEqual(refused.exception.code, "UNAVAILABLE")

    def test_certificate_and_key_go_together(self) -> None:
        with self.assertRaises(rim_client.RimError) as error:
            self.client(tls_ca=self.path("ca.crt"), tls_cert=self.path("client.crt"))
        self.assertEqual(error.exception.code, "INVALID_ARGUMENT")
        with self.assertRaises(rim_client.RimError) as error:
            self.client(tls_ca=self.path("missing.crt"))
        self.assertEqual(error.exception.code, "NOT_FOUND")


if __name__ == "__main__":
    unittest.main()
