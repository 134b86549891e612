#!/usr/bin/env bash
# Real LiDAR: rim_map over the hku_campus walk (80 scans) with the campus preset. It must finish,
# produce a mesh, and keep memory flat: RSS minus the global map (which grows with the area
# walked) may not grow by more than 96 MB from frame 10 to the end. And no crack along the faces of
# the last local box: the walk comes back, so that box's faces cut through mapped ground.
# Usage: campus.sh BUILD_DIR [WORK_DIR]. Skips (exit 0 with a message) when the data is absent.
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
if [ -n "${2:-}" ]; then
  WORK="$2"
else
  WORK="$(mktemp -d)"
  # A scratch folder of our own: removed on exit unless RIM_KEEP_TEST_DIRS is set.
  [ -n "${RIM_KEEP_TEST_DIRS:-}" ] || trap 'rm -rf "$WORK"' EXIT
fi
DATA="${RIM_HKU_CAMPUS:-}"
if [ -z "$DATA" ] || [ ! -d "$DATA/scans" ]; then
  echo "SKIP: hku_campus data not found (set RIM_HKU_CAMPUS to the folder with scans/ and poses.txt)"
  exit 0
fi
"$BUILD/clients/rim_map" "$DATA" --preset campus --out "$WORK/map"
python3 - "$WORK/map/timing.json" "$WORK/map/mesh.ply" <<'PY'
import json, os, sys
t = json.load(open(sys.argv[1]))
rss, sub = t["rss_mb_per_frame"], t["submap_mb_per_frame"]
base = [r - s for r, s in zip(rss, sub)]
growth = max(base[10:]) - base[10]
size = os.path.getsize(sys.argv[2])
print(f"campus: {t['frames']:.0f} frames, {t['ms_per_frame']:.0f} ms/frame, peak RSS "
      f"{t['peak_rss_mb']:.0f} MB, global map {sub[-1]:.0f} MB, RSS minus map grew {growth:.0f} MB, "
      f"mesh {size / 1e6:.1f} MB")
ok = t["frames"] == 80 and size > 1e6 and growth < 96
print("PASS" if ok else "FAIL")
sys.exit(0 if ok else 1)
PY

# The last box of the campus preset: ±12 m about the last pose, placed in whole coarse voxels
# (0.4 m), as MapGeometry::BoxOriginFor does. Only the faces with mapped ground on both sides are
# checked: those an earlier box reached beyond. A face no box ever passed is the map's frontier,
# where the mesh ends because nothing beyond it was trained (the walk's westmost pose is the last
# one, so its box's west face is such a frontier).
FACES="$(python3 - "$DATA/poses.txt" <<'PY'
import math, sys
poses = [[float(v) for v in line.split()] for line in open(sys.argv[1]) if line.strip()]
last = poses[-1]
faces = []
for axis, col in (("x", 3), ("y", 7)):
    lo = math.floor((last[col] - 12.0) / 0.4 + 0.5) * 0.4
    hi = lo + 24.0
    if min(p[col] for p in poses) - 12.0 <= lo - 0.4:
        faces.append("%s=%.1f" % (axis, lo))
    else:
        print("%s=%.1f: the map's frontier (no box reached beyond it), not checked" % (axis, lo),
              file=sys.stderr)
    if max(p[col] for p in poses) + 12.0 >= hi + 0.4:
        faces.append("%s=%.1f" % (axis, hi))
    else:
        print("%s=%.1f: the map's frontier (no box reached beyond it), not checked" % (axis, hi),
              file=sys.stderr)
print(" ".join(faces))
PY
)"
# shellcheck disable=SC2086
python3 "$(dirname "$0")/plane_cracks.py" "$WORK/map/mesh.ply" $FACES
