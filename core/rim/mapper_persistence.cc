// Mapper::Save / Mapper::Load (§5.3 layout, used by the service's SaveSession/LoadSession).
//
// A save writes a complete checkpoint into a new folder `ckpt-NNNNNN/` under the session
// directory (every file written atomically with a checksum), then switches the `CURRENT` file to
// it atomically and removes older checkpoints. A crash at any point leaves CURRENT naming a
// complete checkpoint.
#include <cmath>
#include <filesystem>
#include <mutex>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/binary_io.h"
#include "rim/base/status_macros.h"
#include "rim/map/deferred_points.h"
#include "rim/map/distance_field.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/model/decoder.h"
#include "rim/train/point_buffer.h"
#include "rim/train/trainer.h"

namespace rim {
namespace {

// Version 2 added deferred.rimf (the deferred rays); a version 1 checkpoint has none and loads
// with an empty store.
constexpr uint32_t kStateVersion = 3;
namespace fs = std::filesystem;

// Sequence number of a checkpoint folder name, or -1.
int CheckpointNumber(const std::string& name) {
  int n;
  if (name.rfind("ckpt-", 0) != 0 || !absl::SimpleAtoi(name.substr(5), &n)) return -1;
  return n;
}

// The slots of each level that hold data (the dense grids are mostly zero), in slot order.
std::vector<std::vector<int64_t>> SlotsWithData(const LocalMap& map) {
  std::vector<std::vector<int64_t>> out(size_t(map.geometry().levels()));
  for (int l = 0; l < map.geometry().levels(); ++l) {
    const LocalMap::Level& lv = map.level(l);
    size_t n = 0;
    for (int64_t s = 0; s < lv.slots(); ++s) n += lv.has_data(s) ? 1 : 0;
    out[size_t(l)].reserve(n);
    for (int64_t s = 0; s < lv.slots(); ++s)
      if (lv.has_data(s)) out[size_t(l)].push_back(s);
  }
  return out;
}

// Bytes SerializeLocalMap writes for these slots.
size_t LocalMapBytes(const LocalMap& map, const std::vector<std::vector<int64_t>>& slots) {
  const size_t row = size_t(map.geometry().feature_dim()) * sizeof(float);
  size_t bytes = 1 + 3 * sizeof(int32_t);
  for (const auto& level : slots)
    bytes += 6 * sizeof(uint64_t) +
             level.size() * (sizeof(int64_t) + 3 * row + sizeof(int32_t) + sizeof(uint8_t));
  return bytes;
}

// Per level six arrays, each a count and its elements as ByteWriter::PodVector lays them out:
// the slots, their features, Adam moments m and v, step counts and flags. Written straight from
// the grids: gathering them into vectors first, each grown by doubling, copied the local map
// (most of a checkpoint's bytes) several times over.
void SerializeLocalMap(const LocalMap& map, const std::vector<std::vector<int64_t>>& slots,
                       ByteWriter* w) {
  const int D = map.geometry().feature_dim();
  const size_t row = size_t(D) * sizeof(float);
  w->U8(map.placed() ? 1 : 0);
  for (int a = 0; a < 3; ++a) w->I32(map.coarse_origin()[a]);
  for (int l = 0; l < map.geometry().levels(); ++l) {
    const LocalMap::Level& lv = map.level(l);
    const std::vector<int64_t>& level = slots[size_t(l)];
    const uint64_t n = level.size();
    w->PodVector(level);
    w->U64(n * uint64_t(D));
    for (int64_t s : level) w->Bytes(lv.features(s), row);
    w->U64(n * uint64_t(D));
    for (int64_t s : level) w->Bytes(lv.adam_m(s), row);
    w->U64(n * uint64_t(D));
    for (int64_t s : level) w->Bytes(lv.adam_v(s), row);
    w->U64(n);
    for (int64_t s : level) w->I32(lv.adam_steps(s));
    w->U64(n);
    for (int64_t s : level) w->U8(lv.flags(s));
  }
}

absl::Status DeserializeLocalMap(ByteReader* r, LocalMap* map) {
  const int D = map->geometry().feature_dim();
  uint8_t placed;
  Int3 origin;
  RIM_RETURN_IF_ERROR(r->U8(&placed));
  for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&origin[a]));
  // A live box sits where a pose within 1e6 m of the origin put it (Mapper::ValidateScan). A
  // corrupt origin far beyond would overflow the lattice arithmetic of every later slide, query
  // and mesh (a signed overflow in LatticeBox, loops that never end).
  const MapGeometry& g = map->geometry();
  for (int a = 0; a < 3; ++a) {
    const double metres = std::abs(double(origin[a])) * g.voxel_m(g.levels() - 1);
    const int64_t finest = std::abs(int64_t(origin[a])) * g.scale_to_coarse(0) + g.cells(0)[a];
    if (placed && (metres > 1e6 + g.extent_m()[a] || finest > (int64_t{1} << 30)))
      return absl::DataLossError(absl::StrCat("local map origin (", origin.x(), ", ", origin.y(),
                                              ", ", origin.z(), ") is out of range"));
  }
  if (placed) map->PlaceWithoutLoading(origin);
  for (int l = 0; l < map->geometry().levels(); ++l) {
    LocalMap::Level& lv = map->level(l);
    std::vector<int64_t> slots;
    std::vector<float> f, m, v;
    std::vector<int32_t> steps;
    std::vector<uint8_t> flags;
    RIM_RETURN_IF_ERROR(r->PodVector(&slots));
    RIM_RETURN_IF_ERROR(r->PodVector(&f));
    RIM_RETURN_IF_ERROR(r->PodVector(&m));
    RIM_RETURN_IF_ERROR(r->PodVector(&v));
    RIM_RETURN_IF_ERROR(r->PodVector(&steps));
    RIM_RETURN_IF_ERROR(r->PodVector(&flags));
    const size_t n = slots.size();
    if (f.size() != n * D || m.size() != n * D || v.size() != n * D || steps.size() != n ||
        flags.size() != n)
      return absl::DataLossError(absl::StrCat("local map level ", l, ": inconsistent array sizes"));
    for (size_t i = 0; i < n; ++i) {
      const int64_t s = slots[i];
      if (s < 0 || s >= lv.slots())
        return absl::DataLossError(absl::StrCat("local map level ", l, ": slot out of range"));
      std::copy_n(&f[i * D], D, lv.features(s));
      std::copy_n(&m[i * D], D, lv.adam_m(s));
      std::copy_n(&v[i * D], D, lv.adam_v(s));
      lv.adam_steps(s) = steps[i];
      lv.flags(s) = flags[i];
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status Mapper::SaveState(const std::string& path) const {
  ByteWriter w;
  w.U32(kStateVersion);
  w.U64(uint64_t(frames_));
  w.U64(map_version_.load());
  decoder_->Serialize(&w);
  // Room for the whole payload at once (the point buffer: two float triples a point, and its
  // generator's state), so that the string holding it is never copied to grow.
  const std::vector<std::vector<int64_t>> slots = SlotsWithData(*local_map_);
  w.Reserve(LocalMapBytes(*local_map_, slots) + buffer_->size() * 6 * sizeof(float) + 65536);
  SerializeLocalMap(*local_map_, slots, &w);
  buffer_->Serialize(&w);
  std::ostringstream rng;
  rng << trainer_->sampler().rng();
  w.String(rng.str());
  return WriteFileAtomic(path, "STAT", w.data());
}

absl::Status Mapper::SaveDeferred(const std::string& path) const {
  ByteWriter w;
  deferred_->Serialize(&w);
  return WriteFileAtomic(path, "DEFR", w.data());
}

absl::Status Mapper::LoadDeferred(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(std::string bytes, ReadFileChecked(path, "DEFR"));
  ByteReader r(bytes, path);
  absl::Status s = deferred_->Deserialize(&r, config_.buffer.max_range_m);
  if (s.ok()) s = r.ExpectEnd();
  if (s.ok()) return s;
  // Reader errors name the file already; the store's own checks do not.
  return absl::DataLossError(absl::StartsWith(s.message(), path)
                                 ? std::string(s.message())
                                 : absl::StrCat(path, ": ", s.message()));
}

absl::Status Mapper::SaveDistance(const std::string& path) const {
  ByteWriter w;
  w.U64(uint64_t(distance_frames_ + 1));
  w.U8(distance_all_stale_ ? 1 : 0);
  w.U8(distance_box_ ? 1 : 0);
  if (distance_box_)
    for (const Int3* v : {&distance_box_->lo, &distance_box_->hi})
      for (int a = 0; a < 3; ++a) w.I32((*v)[a]);
  distance_->Serialize(&w);
  // The returns and the deferred sub-maps whose rays changed since they were built, so that a
  // restored map answers as this one does and rebuilds the same ones at its next refresh.
  distance_->SerializeReturns(&w);
  const std::vector<Int3> changed = deferred_->Changed();
  w.U64(changed.size());
  for (const Int3& key : changed)
    for (int a = 0; a < 3; ++a) w.I32(key[a]);
  return WriteFileAtomic(path, "DIST", w.data());
}

absl::Status Mapper::LoadDistance(const std::string& path) {
  RIM_ASSIGN_OR_RETURN(std::string bytes, ReadFileChecked(path, "DIST"));
  ByteReader r(bytes, path);
  uint64_t frames_plus_one;
  uint8_t stale, has_box;
  IntBox box;
  absl::Status s = r.U64(&frames_plus_one);
  if (s.ok()) s = r.U8(&stale);
  if (s.ok()) s = r.U8(&has_box);
  for (Int3* v : {&box.lo, &box.hi})
    for (int a = 0; a < 3 && s.ok() && has_box; ++a) s = r.I32(&(*v)[a]);
  if (s.ok() && (stale > 1 || has_box > 1 || frames_plus_one > uint64_t(frames_) + 1))
    s = absl::DataLossError("bad refresh state");
  if (s.ok()) s = distance_->Deserialize(&r);
  // Files from before returns were kept end here: the field builds them from the deferred store
  // (which counts every sub-map it loaded as changed).
  const bool has_returns = r.remaining() > 0;
  std::vector<Int3> changed;
  if (s.ok() && has_returns) {
    s = distance_->DeserializeReturns(&r);
    uint64_t count = 0;
    if (s.ok()) s = r.U64(&count);
    if (s.ok() && count > r.remaining() / 12)
      s = absl::DataLossError("bad count of changed sub-maps");
    for (uint64_t k = 0; k < count && s.ok(); ++k) {
      Int3 key;
      for (int a = 0; a < 3 && s.ok(); ++a) s = r.I32(&key[a]);
      changed.push_back(key);
    }
  }
  if (s.ok()) s = r.ExpectEnd();
  if (!s.ok()) {
    distance_->Clear();
    return absl::DataLossError(absl::StartsWith(s.message(), path)
                                   ? std::string(s.message())
                                   : absl::StrCat(path, ": ", s.message()));
  }
  distance_frames_ = int64_t(frames_plus_one) - 1;
  distance_all_stale_ = stale != 0;
  distance_box_ = has_box ? std::make_unique<IntBox>(box) : nullptr;
  if (has_returns)
    deferred_->SetChanged(changed);
  else
    RefreshReturns();
  return absl::OkStatus();
}

absl::Status Mapper::LoadState(const std::string& path, uint32_t* version_out) {
  RIM_ASSIGN_OR_RETURN(std::string bytes, ReadFileChecked(path, "STAT"));
  ByteReader r(bytes, path);
  uint32_t version;
  uint64_t frames, map_version;
  RIM_RETURN_IF_ERROR(r.U32(&version));
  if (version < 1 || version > kStateVersion)
    return absl::DataLossError(
        absl::StrCat(path, ": state version ", version, ", expected 1 to ", kStateVersion));
  *version_out = version;
  RIM_RETURN_IF_ERROR(r.U64(&frames));
  RIM_RETURN_IF_ERROR(r.U64(&map_version));
  auto with_path = [&](absl::Status s) {
    return s.ok() ? s : absl::DataLossError(absl::StrCat(path, ": ", s.message()));
  };
  RIM_RETURN_IF_ERROR(with_path(decoder_->Deserialize(&r)));
  RIM_RETURN_IF_ERROR(with_path(DeserializeLocalMap(&r, local_map_.get())));
  RIM_RETURN_IF_ERROR(with_path(buffer_->Deserialize(&r)));
  std::string rng_state;
  RIM_RETURN_IF_ERROR(r.String(&rng_state));
  RIM_RETURN_IF_ERROR(r.ExpectEnd());
  std::istringstream in(rng_state);
  in >> trainer_->sampler().rng();
  if (in.fail()) return absl::DataLossError(absl::StrCat(path, ": bad sampler random state"));
  frames_ = int64_t(frames);
  map_version_ = map_version;
  return absl::OkStatus();
}

absl::Status Mapper::Save(const std::string& dir, int64_t* frames_saved) const {
  // Saves overlap in the service (periodic checkpoints on the trainer thread, SaveSession and
  // shutdown on others). Unserialised, two picked the same ckpt-N folder and the store's clean-up
  // deleted the other's temporary files, or one pruned the folder the other was writing and then
  // pointed CURRENT at it.
  std::lock_guard<std::mutex> save_lock(save_mu_);
  RIM_RETURN_IF_ERROR(MakeDirs(dir));
  // Before mu_, as RefreshDistanceField takes them: the refresh state is saved as it stands.
  std::lock_guard<std::mutex> refresh_lock(refresh_mu_);
  std::lock_guard<std::mutex> frame_lock(frame_mu_);  // between frames, never within one
  std::shared_lock lock(mu_);
  // Under the lock: the trainer may have slid the local map since any earlier flush, and slabs
  // still on their way to the store would be in neither the local map nor the checkpoint. The
  // saver thread takes only its own and the store's locks, so waiting here cannot deadlock.
  saver_->Flush();
  if (frames_saved) *frames_saved = frames_;
  int next = 0;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec))
    next = std::max(next, CheckpointNumber(e.path().filename()) + 1);
  const std::string name = absl::StrFormat("ckpt-%06d", next);
  const std::string ckpt = dir + "/" + name;
  RIM_RETURN_IF_ERROR(MakeDirs(ckpt));
  RIM_RETURN_IF_ERROR(WriteFileAtomic(ckpt + "/config.rimf", "CONF", config_.ToString()));
  RIM_RETURN_IF_ERROR(SaveState(ckpt + "/state.rimf"));
  RIM_RETURN_IF_ERROR(SaveDeferred(ckpt + "/deferred.rimf"));
  RIM_RETURN_IF_ERROR(SaveDistance(ckpt + "/distance.rimf"));
  RIM_RETURN_IF_ERROR(store_->SaveTo(ckpt + "/submaps"));
  RIM_RETURN_IF_ERROR(WriteFileAtomic(dir + "/CURRENT", "CURR", name));
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const int n = CheckpointNumber(e.path().filename());
    if (n >= 0 && n != next) fs::remove_all(e.path(), ec);
  }
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<Mapper>> Mapper::Load(const std::string& dir,
                                                     uint64_t max_host_bytes) {
  RIM_ASSIGN_OR_RETURN(std::string name, ReadFileChecked(dir + "/CURRENT", "CURR"));
  if (CheckpointNumber(name) < 0)
    return absl::DataLossError(absl::StrCat(dir, "/CURRENT names '", name, "', not a checkpoint"));
  const std::string ckpt = dir + "/" + name;
  RIM_ASSIGN_OR_RETURN(std::string config_text, ReadFileChecked(ckpt + "/config.rimf", "CONF"));
  RIM_ASSIGN_OR_RETURN(MapperConfig config, ParseConfigText(config_text, ckpt + "/config.rimf"));
  // The config decides how much the mapper allocates at once; a damaged or hostile one must not
  // take the host's memory before any budget is checked.
  if (max_host_bytes > 0 && InitialHostBytes(config) > max_host_bytes)
    return absl::ResourceExhaustedError(absl::StrCat(
        ckpt, "/config.rimf: the map needs ", InitialHostBytes(config), " bytes of host memory, ",
        "over the ", max_host_bytes, " left in the budget"));
  RIM_ASSIGN_OR_RETURN(std::unique_ptr<Mapper> mapper, Create(config));
  uint32_t state_version = 0;
  RIM_RETURN_IF_ERROR(mapper->LoadState(ckpt + "/state.rimf", &state_version));
  if (state_version >= 2) RIM_RETURN_IF_ERROR(mapper->LoadDeferred(ckpt + "/deferred.rimf"));
  RIM_RETURN_IF_ERROR(mapper->store_->LoadFrom(ckpt + "/submaps"));
  // Older checkpoints have no distance field: it is extracted from the map they restore.
  if (state_version >= 3)
    RIM_RETURN_IF_ERROR(mapper->LoadDistance(ckpt + "/distance.rimf"));
  else
    mapper->RefreshDistanceField();
  return mapper;
}

}  // namespace rim
