// GetMeshTiles: a server-streaming reactor that meshes and Draco-encodes one tile per write, so
// only one tile's payload is in memory at a time.
#include <array>
#include <memory>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/service/service.h"
#include "server/service/status_mapping.h"

namespace rim::server {
namespace {

bool Intersects(const TileInfo& tile, const rim::v1::Box3& box) {
  return tile.min_m.x() <= box.max().x() && tile.max_m.x() >= box.min().x() &&
         tile.min_m.y() <= box.max().y() && tile.max_m.y() >= box.min().y() &&
         tile.min_m.z() <= box.max().z() && tile.max_m.z() >= box.min().z();
}

class MeshTilesReactor : public grpc::ServerWriteReactor<rim::v1::MeshTile> {
 public:
  MeshTilesReactor(SessionManager* sessions, const rim::v1::GetMeshTilesRequest& request) {
    auto session = sessions->Get(request.robot_id());
    if (!session.ok()) {
      Finish(ToGrpcStatus(session.status()));
      return;
    }
    session_ = *session;
    auto level = session_->mapper().MeshLevel(request.resolution_m());
    if (!level.ok()) {
      Finish(ToGrpcStatus(level.status()));
      return;
    }
    resolution_m_ = *level;
    for (const TileInfo& tile : session_->mapper().ListTiles(request.since_version())) {
      if (!request.has_region() || Intersects(tile, request.region())) tiles_.push_back(tile);
    }
    NextWrite();
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      Finish(grpc::Status(grpc::StatusCode::CANCELLED, "client stopped reading mesh tiles"));
      return;
    }
    NextWrite();
  }

  void OnDone() override { delete this; }

 private:
  void NextWrite() {
    if (next_ >= tiles_.size()) {
      Finish(grpc::Status::OK);
      return;
    }
    const TileInfo& tile = tiles_[next_++];
    auto encoded = session_->tiles().Get(session_->mapper(), tile, resolution_m_);
    if (!encoded.ok()) {
      Finish(ToGrpcStatus(encoded.status()));
      return;
    }
    const std::array<double, 3> lo{tile.min_m.x(), tile.min_m.y(), tile.min_m.z()};
    const std::array<double, 3> hi{tile.max_m.x(), tile.max_m.y(), tile.max_m.z()};
    out_.Clear();
    out_.set_key_x(tile.key.x());
    out_.set_key_y(tile.key.y());
    out_.set_key_z(tile.key.z());
    out_.set_version((*encoded)->version);
    auto* bounds = out_.mutable_bounds();
    bounds->mutable_min()->set_x(lo[0]);
    bounds->mutable_min()->set_y(lo[1]);
    bounds->mutable_min()->set_z(lo[2]);
    bounds->mutable_max()->set_x(hi[0]);
    bounds->mutable_max()->set_y(hi[1]);
    bounds->mutable_max()->set_z(hi[2]);
    out_.set_draco((*encoded)->draco);
    out_.set_vertex_count((*encoded)->vertex_count);
    out_.set_face_count((*encoded)->face_count);
    out_.set_resolution_m((*encoded)->resolution_m);
    StartWrite(&out_);
  }

  std::shared_ptr<Session> session_;
  float resolution_m_ = 0;
  std::vector<TileInfo> tiles_;
  size_t next_ = 0;
  rim::v1::MeshTile out_;
};

}  // namespace

grpc::ServerWriteReactor<rim::v1::MeshTile>* NewMeshTilesReactor(
    SessionManager* sessions, const rim::v1::GetMeshTilesRequest& request) {
  return new MeshTilesReactor(sessions, request);
}

}  // namespace rim::server
