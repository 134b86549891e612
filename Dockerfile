# CPU build of rim on Debian bookworm. The runtime image and its health check are refined with the
# service; today it builds the core and runs its unit tests.
FROM debian:bookworm AS build
WORKDIR /src
COPY deploy/install-deps.sh deploy/install-deps.sh
RUN bash deploy/install-deps.sh
COPY . .
RUN cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release && cmake --build build \
    && ctest --test-dir build -L unit --output-on-failure
