// Dataset::Open: detects the folder's layout and hands over to its reader.
#include "rim/io/dataset.h"

#include <string>

#include "absl/strings/str_cat.h"
#include "rim/io/dataset_internal.h"
#include "rim/io/file_util.h"

namespace rim::io {

const char* LayoutName(DatasetLayout layout) {
  switch (layout) {
    case DatasetLayout::kKitti:
      return "KITTI";
    case DatasetLayout::kPlyFrames:
      return "PLY frames";
    case DatasetLayout::kPcdFrames:
      return "PCD frames";
    case DatasetLayout::kSevenScenes:
      return "7-Scenes";
    case DatasetLayout::kReplica:
      return "Replica";
  }
  return "unknown";
}

absl::StatusOr<std::unique_ptr<Dataset>> Dataset::Open(const std::string& path) {
  if (!IsDirectory(path)) {
    return absl::NotFoundError(absl::StrCat(path, ": not a directory (a dataset is a folder)"));
  }
  auto has = [](const std::string& dir, const char* prefix, const char* suffix) {
    return !ListFiles(dir, prefix, suffix).empty();
  };
  // Checked in this order; the first match decides.
  if (has(JoinPath(path, "velodyne"), "", ".bin")) return internal::OpenKitti(path);
  if (has(JoinPath(path, "scans"), "", ".pcd")) return internal::OpenPcdFrames(path);
  for (const char* sub : {"velodyne", "frames"}) {
    const std::string dir = JoinPath(path, sub);
    if (has(dir, "", ".ply")) return internal::OpenPlyFrames(path, dir);
  }
  if (has(path, "frame-", ".depth.png")) return internal::OpenSevenScenes(path);
  if (has(JoinPath(path, "results"), "depth", ".png")) return internal::OpenReplica(path);
  if (has(path, "", ".ply")) return internal::OpenPlyFrames(path, path);
  return absl::NotFoundError(absl::StrCat(
      path,
      ": no known dataset layout; looked for velodyne/*.bin + poses.txt (KITTI), scans/*.pcd + "
      "poses.txt (PCD frames), *.ply in velodyne/, frames/ or the folder itself + poses.txt (PLY "
      "frames), frame-*.depth.png + frame-*.pose.txt (7-Scenes), results/depth*.png + traj.txt "
      "(Replica)"));
}

}  // namespace rim::io
