#!/usr/bin/env bash
# The README's main-job command: start rim_server, stream the built-in synthetic city, pull the
# mesh, print the metrics. The server and clients are not built yet.
set -euo pipefail
echo "rim demo: not yet available. The server (rim_server) and client (rimctl) are still being" >&2
echo "built; today the mapping core and its tests are: run 'bash tests/run.sh'." >&2
exit 2
