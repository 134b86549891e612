#include "server/wal/scan_record.h"

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/binary_io.h"
#include "rim/base/status_macros.h"

namespace rim::server {
namespace {

// Points are copied as raw float triples; Vec3f must be exactly three packed floats for that.
static_assert(sizeof(Vec3f) == 3 * sizeof(float), "Vec3f must be three packed floats");

void EncodePoints(const std::vector<Vec3f>& points, ByteWriter* w) {
  w->U64(points.size());
  if (!points.empty()) w->Bytes(points.data(), points.size() * sizeof(Vec3f));
}

absl::Status DecodePoints(ByteReader* r, const std::string& context, const char* what,
                          std::vector<Vec3f>* points) {
  uint64_t count = 0;
  RIM_RETURN_IF_ERROR(r->U64(&count));
  // Checked before allocating: a corrupt count must not become a multi-gigabyte resize.
  if (count > r->remaining() / sizeof(Vec3f)) {
    return absl::DataLossError(absl::StrCat(context, ": ", what, " count ", count,
                                            " does not fit in the ", r->remaining(),
                                            " bytes left"));
  }
  points->resize(static_cast<size_t>(count));
  if (count > 0) RIM_RETURN_IF_ERROR(r->Bytes(points->data(), points->size() * sizeof(Vec3f)));
  return absl::OkStatus();
}

}  // namespace

absl::Status CheckScanRecordable(const PosedScan& scan) {
  if (!scan.origins_S.empty() && scan.origins_S.size() != scan.points_S.size()) {
    return absl::InvalidArgumentError(absl::StrCat("scan has ", scan.origins_S.size(),
                                                   " origins for ", scan.points_S.size(),
                                                   " points; expected none or one per point"));
  }
  return absl::OkStatus();
}

void EncodeScanRecord(uint64_t sequence, const PosedScan& scan, std::string* out) {
  ByteWriter w;
  w.U64(sequence);
  w.F64(scan.timestamp_s);
  const Eigen::Matrix4d& m = scan.T_world_sensor.matrix();
  for (int i = 0; i < 16; ++i) w.F64(m.data()[i]);
  EncodePoints(scan.points_S, &w);
  EncodePoints(scan.origins_S, &w);
  out->append(w.data());
}

absl::Status DecodeScanRecord(std::string_view bytes, const std::string& context,
                              uint64_t* sequence, PosedScan* scan) {
  ByteReader r(bytes, context);
  PosedScan out;
  uint64_t seq = 0;
  RIM_RETURN_IF_ERROR(r.U64(&seq));
  RIM_RETURN_IF_ERROR(r.F64(&out.timestamp_s));
  Eigen::Matrix4d m;
  for (int i = 0; i < 16; ++i) RIM_RETURN_IF_ERROR(r.F64(&m.data()[i]));
  out.T_world_sensor.matrix() = m;
  RIM_RETURN_IF_ERROR(DecodePoints(&r, context, "point", &out.points_S));
  RIM_RETURN_IF_ERROR(DecodePoints(&r, context, "origin", &out.origins_S));
  RIM_RETURN_IF_ERROR(r.ExpectEnd());
  if (!out.origins_S.empty() && out.origins_S.size() != out.points_S.size()) {
    return absl::DataLossError(absl::StrCat(context, ": ", out.origins_S.size(), " origins for ",
                                            out.points_S.size(), " points"));
  }
  *sequence = seq;
  *scan = std::move(out);
  return absl::OkStatus();
}

}  // namespace rim::server
