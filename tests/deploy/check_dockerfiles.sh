#!/usr/bin/env bash
# Static checks of rim's Dockerfiles (Dockerfile, deploy/Dockerfile.cuda), standing in for a
# Docker build, which rim's CI cannot run (no Docker engine; hadolint is no Debian package):
#   - every COPY source exists in the build context (the repository root) and is not excluded by
#     .dockerignore; .dockerignore keeps build trees out;
#   - every `COPY --from=STAGE` names an earlier stage, and its source is a path that stage's RUN
#     lines produce;
#   - both images run rim_server with the service's flags, as a non-root user, with /data as a
#     volume, ports 50051 and 9090, and a HEALTHCHECK through `rimctl ... health`;
#   - the CPU image's runtime packages exist in apt (skipped, saying so, without apt metadata);
#   - given a build directory holding rim_server (and rimctl), the Debian package of every library
#     they link directly is installed by the runtime stage or part of the base image.
# Usage: check_dockerfiles.sh [REPO_ROOT] [BUILD_DIR]
set -uo pipefail
ROOT="${1:-$(cd "$(dirname "$0")/../.." && pwd)}"
BUILD_DIR="${2:-}"
cd "$ROOT" || exit 1

failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
note() { echo "check_dockerfiles: $*"; }

# Libraries every debian:bookworm(-slim) image already has.
BASE_PACKAGES="libc6 libgcc-s1 libstdc++6 zlib1g"

# Dockerfile instructions one per line: continuations joined, comment lines dropped.
logical_lines() {
  awk '
    /^[[:space:]]*#/ { next }
    /^[[:space:]]*$/ { next }
    {
      line = $0
      if (sub(/\\[[:space:]]*$/, "", line)) { buf = buf line " "; next }
      print buf line; buf = ""
    }
    END { if (buf != "") print buf }' "$1"
}

# .dockerignore patterns (Go filepath.Match globs, plus "dir" covering everything below it).
ignore_patterns=()
if [ -f .dockerignore ]; then
  while IFS= read -r p; do
    p="${p%%#*}"; p="${p%"${p##*[![:space:]]}"}"
    [ -z "$p" ] && continue
    [[ "$p" == !* ]] && continue
    ignore_patterns+=("${p#/}")
  done < .dockerignore
else
  fail ".dockerignore missing"
fi
is_ignored() {
  local path="${1#./}" p
  path="${path%/}"
  for p in "${ignore_patterns[@]}"; do
    p="${p#\*\*/}"
    # shellcheck disable=SC2053  # glob match on purpose
    if [[ "$path" == $p || "$path" == $p/* || "${path##*/}" == $p ]]; then return 0; fi
  done
  return 1
}
for dir in build build-h3 build-ci; do
  is_ignored "$dir" || fail ".dockerignore does not exclude the build tree '$dir'"
done
for src in deploy/install-deps.sh CMakeLists.txt core server clients proto; do
  is_ignored "$src" && fail ".dockerignore excludes '$src', which the build needs"
done

# check_dockerfile FILE IS_DEBIAN: the checks common to both images. Sets runtime_packages to the
# packages that the last stage's `apt-get install` names.
check_dockerfile() {
  local file="$1" is_debian="$2"
  local -a stage_names=() stage_runs=()
  local stage=-1 line instr rest
  local final_stage_text="" build_text=""
  runtime_packages=""
  [ -f "$file" ] || { fail "$file missing"; return; }
  while IFS= read -r line; do
    instr="$(echo "$line" | awk '{print toupper($1)}')"
    rest="$(echo "$line" | sed -E 's/^[[:space:]]*[A-Za-z]+[[:space:]]*//')"
    case "$instr" in
      FROM)
        stage=$((stage + 1))
        local words=() image="" name="" i
        read -ra words <<< "$rest"
        for ((i = 0; i < ${#words[@]}; i++)); do
          case "${words[$i]}" in
            --*) ;;
            [Aa][Ss]) name="${words[$((i + 1))]}"; break ;;
            *) [ -z "$image" ] && image="${words[$i]}" ;;
          esac
        done
        stage_names[stage]="$name"
        stage_runs[stage]=""
        final_stage_text=""
        if [ "$is_debian" = 1 ] && [[ "$image" != debian:bookworm* ]]; then
          fail "$file: stage ${name:-$stage} is based on $image, not Debian bookworm"
        fi
        ;;
      RUN)
        stage_runs[stage]+="$rest"$'\n'
        ;;
      COPY | ADD)
        local words=() from="" srcs=() w
        read -ra words <<< "$rest"
        for w in "${words[@]}"; do
          case "$w" in
            --from=*) from="${w#--from=}" ;;
            --*) ;;
            *) srcs+=("$w") ;;
          esac
        done
        if [ "${#srcs[@]}" -lt 2 ]; then fail "$file: '$line' needs a source and a destination"; continue; fi
        unset 'srcs[${#srcs[@]}-1]'  # the destination
        if [ -z "$from" ]; then
          for w in "${srcs[@]}"; do
            [ "$w" = "." ] && continue
            compgen -G "$w" > /dev/null || fail "$file: COPY source '$w' does not exist in the repository"
            is_ignored "$w" && fail "$file: COPY source '$w' is excluded by .dockerignore"
          done
        else
          local j found=-1
          for ((j = 0; j < stage; j++)); do
            if [ "${stage_names[$j]}" = "$from" ] || [ "$j" = "$from" ]; then found=$j; fi
          done
          if [ "$found" -lt 0 ]; then
            if [[ "$from" == */* || "$from" == *:* ]]; then continue; fi  # an image, not a stage
            fail "$file: COPY --from=$from names no earlier stage"
            continue
          fi
          for w in "${srcs[@]}"; do
            w="${w%/}"
            grep -qF -- "$w" <<< "${stage_runs[$found]}" ||
              fail "$file: COPY --from=$from $w: no RUN of stage $from produces it"
          done
        fi
        ;;
    esac
    final_stage_text+="$instr $rest"$'\n'
  done < <(logical_lines "$file")

  [ "$stage" -ge 1 ] || fail "$file: expected a multi-stage build (build and runtime stages)"
  build_text="${stage_runs[0]:-}"
  grep -qE -- '--target[[:space:]]+rim_server[[:space:]]+rimctl' <<< "$build_text" ||
    fail "$file: the build stage must build the targets rim_server and rimctl"
  for bin in rim_server rimctl; do
    grep -qE -- "/out/bin/$bin" <<< "$build_text" ||
      fail "$file: the build stage does not put $bin into /out/bin"
  done

  # The runtime stage: what the service needs at run time.
  local user
  user="$(grep -E '^USER ' <<< "$final_stage_text" | tail -n 1 | awk '{print $2}')"
  if [ -z "$user" ] || [ "$user" = root ] || [ "${user%%:*}" = 0 ]; then
    fail "$file: the runtime stage must switch to a non-root USER"
  fi
  grep -qE '^VOLUME .*/data' <<< "$final_stage_text" || fail "$file: VOLUME /data missing"
  local expose
  expose="$(grep -E '^EXPOSE ' <<< "$final_stage_text")"
  for port in 50051 9090; do
    grep -qw "$port" <<< "$expose" || fail "$file: EXPOSE $port missing"
  done
  grep -qE '^HEALTHCHECK .*"rimctl", *"--server", *"127\.0\.0\.1:50051", *"health"' \
    <<< "$final_stage_text" || fail "$file: HEALTHCHECK must run rimctl --server 127.0.0.1:50051 health"
  local entry
  entry="$(grep -E '^ENTRYPOINT ' <<< "$final_stage_text")"
  for want in '"rim_server"' '"--listen", *"0\.0\.0\.0:50051"' '"--metrics", *"0\.0\.0\.0:9090"' \
              '"--data-dir", *"/data"'; do
    grep -qE "$want" <<< "$entry" || fail "$file: ENTRYPOINT lacks $want"
  done

  local last_runs="${stage_runs[$stage]:-}"
  runtime_packages="$(grep -oE 'apt-get install[^&;|]*' <<< "$last_runs" |
    sed -E 's/apt-get install//' | tr ' ' '\n' | grep -vE '^(-|$)' | sort -u | tr '\n' ' ')"
}

# ---- the CPU image -----------------------------------------------------------------------------
check_dockerfile Dockerfile 1
cpu_packages="$runtime_packages"
[ -n "$cpu_packages" ] || fail "Dockerfile: the runtime stage installs no runtime packages"
note "Dockerfile runtime packages: $cpu_packages"
if apt-cache show libc6 > /dev/null 2>&1; then
  # One call for all (apt-cache is slow to start). It skips unknown names without failing, so
  # compare the names it describes with the names asked for.
  # shellcheck disable=SC2086
  known=" $(apt-cache show --no-all-versions $cpu_packages 2> /dev/null | sed -n 's/^Package: //p' | tr '\n' ' ') "
  for p in $cpu_packages; do
    [[ "$known" == *" $p "* ]] || fail "Dockerfile: runtime package '$p' is not in apt"
  done
else
  note "apt metadata unavailable (run apt-get update): runtime package names not checked"
fi

# ---- the CUDA image (Ubuntu based; runtime packages computed during its build) -----------------
check_dockerfile deploy/Dockerfile.cuda 0
note "deploy/Dockerfile.cuda: Ubuntu packages are not checked here (no Ubuntu apt metadata)"

# ---- linked libraries against the runtime package list ----------------------------------------
check_binary() {
  local bin="$1" lib path pkg resolved
  resolved="$(ldd "$bin")"
  while read -r lib; do
    path="$(awk -v l="$lib" '$1 == l && $2 == "=>" {print $3}' <<< "$resolved")"
    if [ -z "$path" ] || [ "$path" = "not" ]; then fail "$bin: $lib not found by ldd"; continue; fi
    pkg="$( { dpkg -S "$path" || dpkg -S "$(readlink -f "$path")"; } 2> /dev/null | head -n 1 | cut -d: -f1)"
    if [ -z "$pkg" ]; then
      note "$bin: $lib ($path) belongs to no Debian package; not checked"
      continue
    fi
    case " $cpu_packages $BASE_PACKAGES " in
      *" $pkg "*) ;;
      *) fail "Dockerfile: $(basename "$bin") links $lib from package $pkg, which the runtime stage does not install" ;;
    esac
  done < <(readelf -d "$bin" | sed -nE 's/.*\(NEEDED\).*\[(.*)\]/\1/p')
}
if [ -n "$BUILD_DIR" ] && [ -x "$BUILD_DIR/server/rim_server" ] && command -v dpkg > /dev/null; then
  check_binary "$BUILD_DIR/server/rim_server"
  rimctl="$(find "$BUILD_DIR/clients" -type f -name rimctl -perm -u+x 2> /dev/null | head -n 1)"
  if [ -n "$rimctl" ]; then check_binary "$rimctl"; else note "rimctl not built in $BUILD_DIR; its libraries not checked"; fi
else
  note "no rim_server built in '${BUILD_DIR}'; linked libraries not checked"
fi

if [ "$failures" -gt 0 ]; then
  echo "check_dockerfiles: $failures problem(s)"
  exit 1
fi
echo "check_dockerfiles: OK"
