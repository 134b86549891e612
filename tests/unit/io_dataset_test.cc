// Dataset::Open: layout detection, pose conversion and frame reading for every layout of
// DESIGN.md §4.1, on small synthetic folders written with our own writers, and on the real
// hku_campus data when RIM_HKU_CAMPUS points at it.
#include <stdlib.h>
#include <sys/stat.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "rim/io/dataset.h"
#include "rim/io/kitti.h"
#include "rim/io/pcd.h"
#include "rim/io/ply_points.h"
#include "rim/io/png_io.h"
#include "rim/io/pose_file.h"
#include "support/temp_dir.h"

namespace rim::io {
namespace {

using ::testing::HasSubstr;

std::string TempDir() { return rim::testing_support::MakeTempDir("rim_io_dataset"); }

std::string SubDir(const std::string& dir, const std::string& name) {
  const std::string path = dir + "/" + name;
  mkdir(path.c_str(), 0755);
  return path;
}

void WriteRaw(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string Name(int i, const char* suffix) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%06d%s", i, suffix);
  return buf;
}

PointCloud FrameCloud(int frame) {
  PointCloud cloud;
  for (int i = 0; i < 50; ++i) {
    cloud.points.emplace_back(0.5f * i + frame, -0.25f * i, 0.125f * frame);
    cloud.intensity.push_back(static_cast<float>(i));
  }
  return cloud;
}

std::vector<Eigen::Isometry3d> TestPoses(int n) {
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < n; ++i) {
    Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
    p.linear() = Eigen::AngleAxisd(0.2 * i, Eigen::Vector3d(0.1, 0.3, 1).normalized()).matrix();
    p.translation() = Eigen::Vector3d(1.5 * i, 0.5 * i, -0.1 * i);
    poses.push_back(p);
  }
  return poses;
}

Eigen::Isometry3d TestTr() {
  Eigen::Isometry3d tr = Eigen::Isometry3d::Identity();
  tr.linear() << 0, -1, 0, 0, 0, -1, 1, 0, 0;
  tr.translation() = Eigen::Vector3d(-0.004, -0.076, -0.27);
  return tr;
}

void ExpectPoseNear(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  EXPECT_TRUE(a.matrix().isApprox(b.matrix(), 1e-12)) << a.matrix() << "\nvs\n" << b.matrix();
}

TEST(IoDatasetTest, KittiLayoutWithCalibAndTimes) {
  const std::string dir = TempDir();
  const std::string velo = SubDir(dir, "velodyne");
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(WriteKittiBin(velo + "/" + Name(i, ".bin"), FrameCloud(i)).ok());
  const auto poses = TestPoses(3);
  ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", poses).ok());
  ASSERT_TRUE(WriteCalibFile(dir + "/calib.txt", TestTr()).ok());
  WriteRaw(dir + "/times.txt", "0.0\n0.104\n0.207\n");

  auto ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  EXPECT_EQ((*ds)->layout(), DatasetLayout::kKitti);
  EXPECT_STREQ(LayoutName((*ds)->layout()), "KITTI");
  ASSERT_EQ((*ds)->size(), 3u);
  auto scan = (*ds)->Read(2);
  ASSERT_TRUE(scan.ok()) << scan.status();
  EXPECT_EQ(scan->points_S, FrameCloud(2).points);
  EXPECT_TRUE(scan->origins_S.empty());
  EXPECT_DOUBLE_EQ(scan->timestamp_s, 0.207);
  ExpectPoseNear(scan->T_world_sensor, TestTr().inverse() * poses[2] * TestTr());
  // The poses without reading a frame: the same as Read gives.
  ASSERT_EQ((*ds)->poses().size(), 3u);
  EXPECT_TRUE((*ds)->poses()[2].matrix() == scan->T_world_sensor.matrix());

  auto out_of_range = (*ds)->Read(3);
  ASSERT_FALSE(out_of_range.ok());
  EXPECT_EQ(out_of_range.status().code(), absl::StatusCode::kOutOfRange);

  // Without calib.txt, Tr is the identity: poses are used as they are.
  std::remove((dir + "/calib.txt").c_str());
  ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  scan = (*ds)->Read(1);
  ASSERT_TRUE(scan.ok()) << scan.status();
  ExpectPoseNear(scan->T_world_sensor, poses[1]);

  // A truncated frame fails on Read, naming the file.
  WriteRaw(velo + "/000001.bin", std::string(17, '\0'));
  scan = (*ds)->Read(1);
  ASSERT_FALSE(scan.ok());
  EXPECT_THAT(scan.status().message(), HasSubstr("000001.bin"));
}

TEST(IoDatasetTest, PoseAndFrameCountMismatchNamesBoth) {
  const std::string dir = TempDir();
  const std::string velo = SubDir(dir, "velodyne");
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(WriteKittiBin(velo + "/" + Name(i, ".bin"), FrameCloud(i)).ok());
  ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", TestPoses(2)).ok());
  auto ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("poses.txt has 2 poses"));
  EXPECT_THAT(ds.status().message(), HasSubstr("velodyne has 3"));

  std::remove((dir + "/poses.txt").c_str());
  ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("poses.txt"));

  // A NaN pose names the line.
  WriteRaw(dir + "/poses.txt",
           "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 nan 0 0 1 0\n");
  ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("poses.txt:3"));
}

TEST(IoDatasetTest, PlyFramesInEachPlace) {
  for (const char* sub : {"frames", "velodyne", ""}) {
    SCOPED_TRACE(sub);
    const std::string dir = TempDir();
    const std::string frames = *sub ? SubDir(dir, sub) : dir;
    for (int i = 0; i < 4; ++i) {
      ASSERT_TRUE(WritePlyPoints(frames + "/" + Name(i, ".ply"), FrameCloud(i),
                                 i % 2 ? PlyFormat::kAscii : PlyFormat::kBinary)
                      .ok());
    }
    const auto poses = TestPoses(4);
    ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", poses).ok());
    ASSERT_TRUE(WriteCalibFile(dir + "/calib.txt", TestTr()).ok());
    auto ds = Dataset::Open(dir);
    ASSERT_TRUE(ds.ok()) << ds.status();
    EXPECT_EQ((*ds)->layout(), DatasetLayout::kPlyFrames);
    ASSERT_EQ((*ds)->size(), 4u);
    for (int i : {0, 3}) {
      auto scan = (*ds)->Read(i);
      ASSERT_TRUE(scan.ok()) << scan.status();
      EXPECT_EQ(scan->points_S, FrameCloud(i).points);
      EXPECT_DOUBLE_EQ(scan->timestamp_s, 0.1 * i);
      ExpectPoseNear(scan->T_world_sensor, TestTr().inverse() * poses[i] * TestTr());
    }
  }
}

TEST(IoDatasetTest, PcdFramesDropNonFinitePoints) {
  const std::string dir = TempDir();
  const std::string scans = SubDir(dir, "scans");
  const PcdDataMode modes[3] = {PcdDataMode::kAscii, PcdDataMode::kBinary,
                                PcdDataMode::kBinaryCompressed};
  for (int i = 0; i < 3; ++i) {
    PointCloud cloud = FrameCloud(i);
    cloud.points[7].y() = std::numeric_limits<float>::quiet_NaN();
    ASSERT_TRUE(WritePcd(scans + "/" + Name(i, ".pcd"), cloud, modes[i]).ok());
  }
  // A calib.txt is ignored by the PCD layout: its poses are already sensor-to-world.
  ASSERT_TRUE(WriteCalibFile(dir + "/calib.txt", TestTr()).ok());
  const auto poses = TestPoses(3);
  ASSERT_TRUE(WritePosesFile(dir + "/poses.txt", poses).ok());
  auto ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  EXPECT_EQ((*ds)->layout(), DatasetLayout::kPcdFrames);
  ASSERT_EQ((*ds)->size(), 3u);
  for (int i = 0; i < 3; ++i) {
    auto scan = (*ds)->Read(i);
    ASSERT_TRUE(scan.ok()) << scan.status();
    std::vector<Vec3f> expected = FrameCloud(i).points;
    expected.erase(expected.begin() + 7);
    EXPECT_EQ(scan->points_S, expected);
    ExpectPoseNear(scan->T_world_sensor, poses[i]);
  }
}

// A synthetic depth image: every pixel 2 m (in `units`), except a few invalid ones.
std::vector<uint16_t> DepthPixels(int w, int h, uint16_t value) {
  std::vector<uint16_t> px(w * h, value);
  px[0] = 0;
  px[1] = 0xFFFF;
  return px;
}

TEST(IoDatasetTest, SevenScenesLayout) {
  const std::string scene = TempDir();
  const std::string dir = SubDir(scene, "seq-01");
  const auto poses = TestPoses(2);
  for (int i = 0; i < 2; ++i) {
    const std::string stem = dir + "/frame-" + Name(i, "");
    ASSERT_TRUE(WritePng16(stem + ".depth.png", 64, 48, DepthPixels(64, 48, 2000).data()).ok());
    std::string pose;
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) pose += std::to_string(poses[i].matrix()(r, c)) + "\t";
      pose += "\n";
    }
    WriteRaw(stem + ".pose.txt", pose);
  }
  // No camera-intrinsics.txt: the 7-Scenes defaults (585, 585, 320, 240).
  auto ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  EXPECT_EQ((*ds)->layout(), DatasetLayout::kSevenScenes);
  ASSERT_EQ((*ds)->size(), 2u);
  auto scan = (*ds)->Read(1);
  ASSERT_TRUE(scan.ok()) << scan.status();
  ASSERT_EQ(scan->points_S.size(), 64u * 48 - 2);  // 0 and 65535 skipped
  EXPECT_TRUE(scan->origins_S.empty());
  // Pixel (2, 0) at 2 m.
  EXPECT_NEAR(scan->points_S[0].x(), (2 - 320.0) * 2 / 585, 1e-6);
  EXPECT_NEAR(scan->points_S[0].y(), (0 - 240.0) * 2 / 585, 1e-6);
  EXPECT_FLOAT_EQ(scan->points_S[0].z(), 2.0f);
  EXPECT_TRUE(scan->T_world_sensor.matrix().isApprox(poses[1].matrix(), 1e-5));
  ASSERT_EQ((*ds)->poses().size(), 2u);
  EXPECT_TRUE((*ds)->poses()[1].matrix() == scan->T_world_sensor.matrix());

  // 3DMatch keeps camera-intrinsics.txt in the scene folder, one level up.
  WriteRaw(scene + "/camera-intrinsics.txt", "50 0 31.5\n0 50 23.5\n0 0 1\n");
  ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  scan = (*ds)->Read(0);
  ASSERT_TRUE(scan.ok()) << scan.status();
  EXPECT_NEAR(scan->points_S[0].x(), (2 - 31.5) * 2 / 50, 1e-6);

  std::remove((dir + "/frame-000001.pose.txt").c_str());
  ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("frame-000001.pose.txt"));
}

TEST(IoDatasetTest, ReplicaLayoutAppliesScaleAndChecksSize) {
  const std::string root = TempDir();
  const std::string dir = SubDir(root, "room0");
  const std::string results = SubDir(dir, "results");
  const auto poses = TestPoses(3);
  std::string traj;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(
        WritePng16(results + "/depth" + Name(i, ".png"), 40, 30, DepthPixels(40, 30, 13107).data())
            .ok());
    for (int k = 0; k < 16; ++k) {
      char buf[40];
      std::snprintf(buf, sizeof(buf), "%.17g ", poses[i].matrix()(k / 4, k % 4));
      traj += buf;
    }
    traj += "\n";
  }
  WriteRaw(dir + "/traj.txt", traj);
  auto ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());  // no cam_params.json
  EXPECT_THAT(ds.status().message(), HasSubstr("cam_params.json"));

  // NICE-SLAM keeps cam_params.json next to the scene folders.
  WriteRaw(root + "/cam_params.json",
           "{\"camera\": {\"w\": 40, \"h\": 30, \"fx\": 20.0, \"fy\": 20.0, \"cx\": 19.5, "
           "\"cy\": 14.5, \"scale\": 6553.5}}");
  ds = Dataset::Open(dir);
  ASSERT_TRUE(ds.ok()) << ds.status();
  EXPECT_EQ((*ds)->layout(), DatasetLayout::kReplica);
  ASSERT_EQ((*ds)->size(), 3u);
  auto scan = (*ds)->Read(2);
  ASSERT_TRUE(scan.ok()) << scan.status();
  ASSERT_EQ(scan->points_S.size(), 40u * 30 - 1);  // only 0 is invalid
  EXPECT_NEAR(scan->points_S[0].z(), 65535 / 6553.5, 1e-5);
  EXPECT_NEAR(scan->points_S[1].z(), 13107 / 6553.5, 1e-6);  // 2 m
  EXPECT_NEAR(scan->points_S[1].x(), (2 - 19.5) * 2 / 20.0, 1e-5);
  ExpectPoseNear(scan->T_world_sensor, poses[2]);

  // An image whose size disagrees with w, h.
  ASSERT_TRUE(
      WritePng16(results + "/depth000001.png", 41, 30, DepthPixels(41, 30, 100).data()).ok());
  scan = (*ds)->Read(1);
  ASSERT_FALSE(scan.ok());
  EXPECT_THAT(scan.status().message(), HasSubstr("depth000001.png"));
  EXPECT_THAT(scan.status().message(), HasSubstr("41x30"));

  // traj.txt with a line too few.
  WriteRaw(dir + "/traj.txt", traj.substr(0, traj.rfind('\n', traj.size() - 2) + 1));
  ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("traj.txt has 2 poses"));
}

TEST(IoDatasetTest, EmptyOrMissingFolderFails) {
  const std::string dir = TempDir();
  auto ds = Dataset::Open(dir);
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr(dir));
  EXPECT_THAT(ds.status().message(), HasSubstr("velodyne/*.bin"));
  EXPECT_THAT(ds.status().message(), HasSubstr("scans/*.pcd"));
  EXPECT_THAT(ds.status().message(), HasSubstr("frame-*.depth.png"));
  EXPECT_THAT(ds.status().message(), HasSubstr("results/depth*.png"));
  ds = Dataset::Open(dir + "/does_not_exist");
  ASSERT_FALSE(ds.ok());
  EXPECT_THAT(ds.status().message(), HasSubstr("does_not_exist"));
}

TEST(IoDatasetTest, HkuCampusRealData) {
  const char* env = std::getenv("RIM_HKU_CAMPUS");
  if (env == nullptr || *env == '\0') {
    GTEST_SKIP() << "RIM_HKU_CAMPUS is not set; point it at shared/data/hku_campus to run this";
  }
  struct stat st;
  if (stat(env, &st) != 0) GTEST_SKIP() << "RIM_HKU_CAMPUS=" << env << " does not exist";
  auto ds = Dataset::Open(env);
  ASSERT_TRUE(ds.ok()) << ds.status();
  EXPECT_EQ((*ds)->layout(), DatasetLayout::kPcdFrames);
  ASSERT_EQ((*ds)->size(), 80u);
  auto scan = (*ds)->Read(0);
  ASSERT_TRUE(scan.ok()) << scan.status();
  EXPECT_GE(scan->points_S.size(), 60000u);
  EXPECT_LE(scan->points_S.size(), 90000u);
  for (const Vec3f& p : scan->points_S) ASSERT_TRUE(p.allFinite());
  for (size_t i : {size_t{0}, size_t{40}, size_t{79}}) {
    auto s = (*ds)->Read(i);
    ASSERT_TRUE(s.ok()) << s.status();
    const Eigen::Matrix3d R = s->T_world_sensor.linear();
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_NEAR(R.determinant(), 1.0, 1e-9);
    EXPECT_GT(s->timestamp_s, 1e9);  // UNIX time from times.txt
  }
}

}  // namespace
}  // namespace rim::io
