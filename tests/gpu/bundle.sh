#!/usr/bin/env bash
# Builds the GPU path on this machine (the CUDA toolkit's nvcc, no GPU needed) and packs what a GPU
# machine needs to run it into BUILD/gpu-bundle: the test and benchmark binaries, rim_map, rim_sim
# and rim_eval (the GPU against the CPU on a simulated city), and the shared
# libraries they load beyond glibc (abseil, libstdc++). The GPU machine then needs only its driver:
# the CUDA runtime is linked in statically. docs/gpu.md.
#
# Usage: tests/gpu/bundle.sh [BUILD_DIR]   (default build-cuda)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build-cuda}
command -v nvcc >/dev/null || export PATH=/usr/local/cuda/bin:$PATH
cmake -S "$root" -B "$build" -G Ninja -DRIM_CUDA=ON -DRIM_TORCH=OFF -DCMAKE_BUILD_TYPE=Release >/dev/null
ninja -C "$build" gpu_kernels_test rim_gpu_bench rim_map rim_sim rim_eval
bundle=$build/gpu-bundle
rm -rf "$bundle"
mkdir -p "$bundle/bin" "$bundle/lib"
cp "$build/tests/gpu_kernels_test" "$build/tests/rim_gpu_bench" "$build/clients/rim_map" \
  "$build/clients/rim_sim" "$build/clients/rim_eval" "$bundle/bin/"
# Every library the binaries load, except glibc's own (the GPU machine's is as new or newer).
for bin in "$bundle"/bin/*; do
  ldd "$bin" | awk '$3 ~ /^\// {print $3}'
done | sort -u | while read -r lib; do
  case $(basename "$lib") in
    libc.so.*|libm.so.*|libdl.so.*|libpthread.so.*|librt.so.*|ld-linux*) ;;
    *) cp -L "$lib" "$bundle/lib/" ;;
  esac
done
echo "gpu bundle: $bundle ($(du -sh "$bundle" | cut -f1))"
