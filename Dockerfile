# rim_server and rimctl, CPU build on Debian bookworm with Debian's libtorch.
#
#   docker build -t rim-server:cpu .
#   docker run -d --name rim -p 50051:50051 -p 9090:9090 -p 8080:8080 -v rim-data:/data rim-server:cpu
#   docker stop -t 180 rim        # SIGTERM: drain queues and save every session, then exit
#
# Extra server flags follow the image name (e.g. `rim-server:cpu --max-sessions 4`). The CUDA
# variant is deploy/Dockerfile.cuda. Checked by tests/deploy/check_dockerfiles.sh (no Docker engine
# in rim's CI: this file is not built there).

# ---- build: the project's dependency script, then only the two binaries --------------------------
FROM debian:bookworm AS build
WORKDIR /src
COPY deploy/install-deps.sh deploy/install-deps.sh
RUN bash deploy/install-deps.sh && rm -rf /var/lib/apt/lists/*
COPY . .
# CMake writes rim_server to build/server/rim_server and rimctl under build/clients/ (the exact
# sub-folder is found, not assumed). Both are installed into /out/bin, the one path the runtime
# stage copies from. The dashboard's files (`web` target) go to /out/share/rim/web, where
# rim_server finds them from /usr/local/bin.
RUN cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DRIM_BUILD_TESTS=OFF \
 && cmake --build build --target rim_server rimctl web \
 && install -D -m 0755 build/server/rim_server /out/bin/rim_server \
 && mkdir -p /out/share/rim && cp -r build/web /out/share/rim/web \
 && install -D -m 0755 "$(find build/clients -type f -name rimctl -perm -u+x | head -n 1)" /out/bin/rimctl \
 && strip /out/bin/rim_server /out/bin/rimctl

# ---- runtime: the binaries and the shared libraries they load, nothing else ---------------------
FROM debian:bookworm-slim AS runtime
# The Debian packages that own the binaries' direct shared-library dependencies (readelf NEEDED +
# dpkg -S on a bookworm build); apt brings in what those need. libc6, libgcc-s1, libstdc++6 and
# zlib1g are part of the base image. libprometheus-cpp-* serve --metrics, libcivetweb1 --http.
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libtorch1.13 libssl3 \
      libgrpc++1.51 libgrpc29 libprotobuf32 libabsl20220623 \
      libprometheus-cpp-core1.0 libprometheus-cpp-pull1.0 \
      libdraco7 libpng16-16 liblzf1 libcivetweb1 \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /out/bin/ /usr/local/bin/
COPY --from=build /out/share/ /usr/local/share/
# Fail the image build, not the first container start, when a library is missing.
RUN ! ldd /usr/local/bin/rim_server /usr/local/bin/rimctl | grep 'not found'
RUN useradd --system --user-group --uid 10001 --home-dir /data --no-create-home rim \
 && mkdir -p /data && chown rim:rim /data
USER rim
VOLUME /data
# 50051: gRPC (rim.v1, grpc.health.v1, reflection); 9090: Prometheus /metrics; 8080: the browser
# dashboard and its read-only JSON API.
EXPOSE 50051 9090 8080
# SERVING only after warm-up and until SIGTERM; the start period covers loading sessions.
HEALTHCHECK --interval=30s --timeout=5s --start-period=2m --retries=3 \
  CMD ["rimctl", "--server", "127.0.0.1:50051", "health"]
STOPSIGNAL SIGTERM
# Listening on all interfaces without tokens needs --insecure (docs/security.md): the image is meant
# to sit behind a proxy or on a private network. Anything reachable from outside should add
# `--tokens /run/secrets/rim-tokens` (and --tls-cert/--tls-key) to the container's arguments.
ENTRYPOINT ["rim_server", "--listen", "0.0.0.0:50051", "--metrics", "0.0.0.0:9090", "--http", "0.0.0.0:8080", "--data-dir", "/data", "--insecure"]
