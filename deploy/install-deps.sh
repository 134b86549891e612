#!/usr/bin/env bash
# Installs the Debian bookworm packages that rim needs to build, test and run.
# Idempotent: packages already present are left alone; apt-get update runs once per call,
# and only when something is missing.
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build ccache pkg-config git ca-certificates
  # core
  libtorch-dev libeigen3-dev libabsl-dev zlib1g-dev libpng-dev
  nlohmann-json3-dev liblzf-dev libnanoflann-dev
  # every binary's command line (core/rim/base/flags.h): CLI11, header-only
  libcli11-dev
  # service
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  prometheus-cpp-dev libdraco-dev
  # the dashboard's HTTP server (rim_server --http)
  libcivetweb-dev
  # token digests (SHA-256) for rim_server --tokens
  libssl-dev
  # tests and benchmarks; clang and its libFuzzer runtime for tests/fuzz (RIM_FUZZ=ON)
  libgtest-dev libgmock-dev libbenchmark-dev prometheus python3-yaml clang libclang-rt-14-dev
  # the TSDF reference mapper that benchmarks compare with (tests/bench/tsdf): OpenVDB, and the
  # Boost headers its headers and CMake module need but its package does not pull in
  libopenvdb-dev libboost-iostreams-dev
  # python client: installed with pip into a venv, offline (setuptools, wheel from Debian)
  python3 python3-numpy python3-grpcio python3-protobuf python3-venv python3-pip
  python3-setuptools python3-wheel
  # the dashboard's browser test: headless Chromium driven over the DevTools protocol
  chromium python3-websocket
  # the proxy in front of replicas (deploy/haproxy), run by the scale test
  haproxy
)
# The dashboard's three.js comes from npm (clients/web/package-lock.json, `npm ci` at build time):
# Debian's nodejs and npm, unless the machine already has an npm.
if ! command -v npm > /dev/null 2>&1; then
  PACKAGES+=(nodejs npm)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ "${#missing[@]}" -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages already installed"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "install-deps: installing ${missing[*]}"
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
echo "install-deps: done"
