#!/usr/bin/env bash
# Checks rim's Prometheus assets with promtool (Debian package `prometheus`):
#   - deploy/prometheus/rim-alerts.yml parses and its expressions are valid PromQL;
#   - deploy/prometheus/prometheus.yml is a valid config whose rule files load;
#   - the alert unit tests (rim-alerts.test.yml) pass: the alerts fire on synthetic failing series
#     and stay quiet on healthy ones.
# Usage: check_prometheus.sh [REPO_ROOT]   (default: two levels above this script)
set -euo pipefail
ROOT="${1:-$(cd "$(dirname "$0")/../.." && pwd)}"
DIR="$ROOT/deploy/prometheus"
PROMTOOL="${PROMTOOL:-$(command -v promtool || true)}"
if [ -z "$PROMTOOL" ]; then
  echo "check_prometheus: promtool not found; install the 'prometheus' package (deploy/install-deps.sh)" >&2
  exit 1
fi

cd "$DIR"  # rule_files in both files are relative to their own directory
"$PROMTOOL" check rules rim-alerts.yml
"$PROMTOOL" check config prometheus.yml
"$PROMTOOL" test rules rim-alerts.test.yml
echo "check_prometheus: OK"
