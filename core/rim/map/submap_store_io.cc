// SubmapStore's serialisation: one sub-map to bytes and back, and a whole store to a directory of
// checksummed files.
#include <dirent.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "rim/base/binary_io.h"
#include "rim/base/row8.h"
#include "rim/base/status_macros.h"
#include "rim/map/submap_store.h"

namespace rim {

void SubmapStore::SerializeLocked(const Int3& key, const Submap& s, std::string* out) const {
  ByteWriter w;
  w.I32(key.x());
  w.I32(key.y());
  w.I32(key.z());
  w.U64(s.version);
  w.I32(geometry_.levels());
  w.I32(geometry_.feature_dim());
  w.I32(config_.block_size);
  for (int l = 0; l < geometry_.levels(); ++l) {
    // Sorted by block key so that the same content always gives the same bytes.
    std::vector<const std::pair<const Int3, std::shared_ptr<Block>>*> blocks;
    for (const auto& kv : s.blocks[l]) blocks.push_back(&kv);
    std::sort(blocks.begin(), blocks.end(), [](const auto* a, const auto* b) {
      return std::lexicographical_compare(a->first.data(), a->first.data() + 3, b->first.data(),
                                          b->first.data() + 3);
    });
    w.U64(blocks.size());
    for (const auto* kv : blocks) {
      w.I32(kv->first.x());
      w.I32(kv->first.y());
      w.I32(kv->first.z());
      // The 8-bit rows as the store keeps them: a quarter of the float32 bytes that older files
      // hold, and nothing to convert.
      w.PodVector(kv->second->features);
      w.PodVector(kv->second->observed);
    }
  }
  *out = w.Release();
}

absl::StatusOr<std::string> SubmapStore::SerializeSubmap(const Int3& key) const {
  std::string out;
  SavedFile stamp;
  RIM_RETURN_IF_ERROR(SerializeStamped(key, &out, &stamp));
  return out;
}

absl::Status SubmapStore::SerializeStamped(const Int3& key, std::string* out,
                                           SavedFile* stamp) const {
  std::lock_guard<std::mutex> lock(mu_);
  const Submap* s = FindLocked(key);
  if (!s) return absl::NotFoundError(absl::StrCat("no sub-map ", SubmapKeyName(key)));
  // Its data is on disk and could not be reloaded: serialising it as empty would lose it.
  if (s->state == SubmapState::kOnDisk)
    return absl::DataLossError(absl::StrCat("sub-map ", SubmapKeyName(key),
                                            " could not be reloaded from ", SpillPath(key), ": ",
                                            last_error_.message()));
  SerializeLocked(key, *s, out);
  stamp->generation = s->generation;
  stamp->version = s->version;
  return absl::OkStatus();
}

absl::Status SubmapStore::ParseSubmap(const std::string& bytes, const std::string& context,
                                      SubmapFormat format, Int3* key_out, Submap* out) const {
  ByteReader r(bytes, context);
  Int3 key;
  uint64_t version;
  int32_t levels, dim, block;
  std::vector<float> wide;
  RIM_RETURN_IF_ERROR(r.I32(&key.x()));
  RIM_RETURN_IF_ERROR(r.I32(&key.y()));
  RIM_RETURN_IF_ERROR(r.I32(&key.z()));
  RIM_RETURN_IF_ERROR(r.U64(&version));
  RIM_RETURN_IF_ERROR(r.I32(&levels));
  RIM_RETURN_IF_ERROR(r.I32(&dim));
  RIM_RETURN_IF_ERROR(r.I32(&block));
  if (levels != geometry_.levels() || dim != geometry_.feature_dim() || block != config_.block_size)
    return absl::DataLossError(absl::StrCat(context, ": sub-map layout (levels ", levels, ", dim ",
                                            dim, ", block ", block, ") does not match the config"));
  // Sub-maps of a live map lie within reach of poses within 1e6 m (Mapper::ValidateScan); a corrupt
  // key far beyond would overflow the lattice arithmetic (key * cells) of every read and mesh.
  for (int a = 0; a < 3; ++a) {
    const double metres = std::abs(double(key[a])) * geometry_.extent_m()[a];
    const int64_t lattice = (std::abs(int64_t(key[a])) + 1) * geometry_.cells(0)[a];
    if (metres > 1e6 + 2 * geometry_.extent_m()[a] || lattice > (int64_t{1} << 30))
      return absl::DataLossError(
          absl::StrCat(context, ": sub-map key ", SubmapKeyName(key), " is out of range"));
  }
  const size_t b3 = size_t(block) * block * block;
  Submap s;
  s.version = version;
  s.state = SubmapState::kFrozen;
  for (int l = 0; l < levels; ++l) {
    uint64_t n;
    RIM_RETURN_IF_ERROR(r.U64(&n));
    if (n > r.remaining() / 12)
      return absl::DataLossError(absl::StrCat(context, ": bad block count"));
    for (uint64_t i = 0; i < n; ++i) {
      Int3 bk;
      RIM_RETURN_IF_ERROR(r.I32(&bk.x()));
      RIM_RETURN_IF_ERROR(r.I32(&bk.y()));
      RIM_RETURN_IF_ERROR(r.I32(&bk.z()));
      // A sub-map owns lattice points [0, cells) from its corner, so blocks [0, (cells - 1) / B].
      const Int3 last_block = FloorDiv(geometry_.cells(l) - Int3::Ones(), Int3::Constant(block));
      if ((bk.array() < 0).any() || (bk.array() > last_block.array()).any())
        return absl::DataLossError(absl::StrCat(context, ": block ", SubmapKeyName(bk),
                                                " at level ", l, " lies outside its sub-map"));
      auto b = std::make_shared<Block>();
      if (format == SubmapFormat::kFloat32) {
        RIM_RETURN_IF_ERROR(r.FloatArray(&wide));
      } else {
        RIM_RETURN_IF_ERROR(r.PodVector(&b->features));
        if (b->features.size() != b3 * Row8Bytes(int(dim)))
          return absl::DataLossError(absl::StrCat(context, ": block of wrong size at level ", l));
        SanitizeRows8(b->features.data(), b3, int(dim));
      }
      RIM_RETURN_IF_ERROR(r.PodVector(&b->observed));
      if (b->observed.size() != (l == 0 ? b3 : 0) ||
          (format == SubmapFormat::kFloat32 && wide.size() != b3 * dim))
        return absl::DataLossError(absl::StrCat(context, ": block of wrong size at level ", l));
      if (format == SubmapFormat::kFloat32) {
        b->features.resize(b3 * Row8Bytes(int(dim)));
        EncodeRows8(wide.data(), b3, int(dim), b->features.data());
      }
      s.blocks[l].emplace(bk, std::move(b));
      s.bytes += BlockBytes(l);
    }
  }
  RIM_RETURN_IF_ERROR(r.ExpectEnd());
  *key_out = key;
  *out = std::move(s);
  return absl::OkStatus();
}

absl::Status SubmapStore::DeserializeSubmap(const std::string& bytes, const std::string& context,
                                            SubmapFormat format) {
  Int3 key;
  SavedFile stamp;
  return Install(bytes, context, format, &key, &stamp);
}

absl::Status SubmapStore::Install(const std::string& bytes, const std::string& context,
                                  SubmapFormat format, Int3* key, SavedFile* stamp) {
  Submap s;
  RIM_RETURN_IF_ERROR(ParseSubmap(bytes, context, format, key, &s));
  std::lock_guard<std::mutex> lock(mu_);
  auto it = submaps_.find(*key);
  if (it != submaps_.end()) {
    host_bytes_ -= it->second.bytes;
    s.state =
        it->second.state == SubmapState::kActive ? SubmapState::kActive : SubmapState::kFrozen;
  }
  s.last_access = ++access_clock_;
  s.generation = ++generation_clock_;
  host_bytes_ += s.bytes;
  stamp->generation = s.generation;
  stamp->version = s.version;
  submaps_[*key] = std::move(s);
  saved_.erase(*key);
  return absl::OkStatus();
}

absl::StatusOr<std::string> ReadSubmapFile(const std::string& path, SubmapFormat* format) {
  std::string kind;
  RIM_ASSIGN_OR_RETURN(std::string bytes,
                       ReadFileCheckedOneOf(path, {kSubmapFileKind, kSubmapFloatFileKind}, &kind));
  *format = kind == kSubmapFileKind ? SubmapFormat::kRow8 : SubmapFormat::kFloat32;
  return bytes;
}

absl::Status SubmapStore::SaveOne(const Int3& key, const std::string& path) const {
  SavedFile prior;
  bool unchanged = false;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = submaps_.find(key);
    auto saved = saved_.find(key);
    if (it != submaps_.end() && saved != saved_.end() &&
        saved->second.generation == it->second.generation &&
        saved->second.version == it->second.version) {
      prior = saved->second;
      unchanged = true;
    }
  }
  if (unchanged && prior.path != path) {
    // The file must still be the one written: a file replaced or rewritten since is not trusted.
    absl::StatusOr<FileIdentity> now = IdentifyFile(prior.path);
    if (now.ok() && *now == prior.identity && LinkFileAtomic(prior.path, path).ok()) {
      prior.path = path;
      std::lock_guard<std::mutex> lock(mu_);
      saved_[key] = std::move(prior);
      return absl::OkStatus();
    }
  }
  SavedFile written;
  std::string bytes;
  RIM_RETURN_IF_ERROR(SerializeStamped(key, &bytes, &written));
  RIM_RETURN_IF_ERROR(WriteFileAtomic(path, kSubmapFileKind, bytes));
  RIM_ASSIGN_OR_RETURN(written.identity, IdentifyFile(path));
  written.path = path;
  std::lock_guard<std::mutex> lock(mu_);
  saved_[key] = std::move(written);
  return absl::OkStatus();
}

absl::Status SubmapStore::SaveTo(const std::string& dir) const {
  RIM_RETURN_IF_ERROR(MakeDirs(dir));
  for (const Int3& key : Keys())
    RIM_RETURN_IF_ERROR(SaveOne(key, absl::StrCat(dir, "/submap_", SubmapKeyName(key), ".subm")));
  // Files of sub-maps that no longer exist would come back on load: remove them.
  std::vector<Int3> keys = Keys();
  if (DIR* d = opendir(dir.c_str())) {
    while (dirent* e = readdir(d)) {
      std::string name = e->d_name;
      if (name.rfind("submap_", 0) != 0 || name.size() < 12) continue;
      bool keep = false;
      for (const Int3& k : keys) keep |= name == absl::StrCat("submap_", SubmapKeyName(k), ".subm");
      if (!keep) unlink((dir + "/" + name).c_str());
    }
    closedir(d);
  }
  return absl::OkStatus();
}

absl::Status SubmapStore::LoadFrom(const std::string& dir) {
  DIR* d = opendir(dir.c_str());
  if (!d) return absl::NotFoundError(absl::StrCat("cannot open sub-map directory ", dir));
  std::vector<std::string> files;
  while (dirent* e = readdir(d)) {
    std::string name = e->d_name;
    if (name.rfind("submap_", 0) == 0 && name.size() > 5 && name.substr(name.size() - 5) == ".subm")
      files.push_back(dir + "/" + name);
  }
  closedir(d);
  std::sort(files.begin(), files.end());
  for (const std::string& f : files) {
    // The identity before the read: a file changed while it is read is not the one loaded.
    absl::StatusOr<FileIdentity> identity = IdentifyFile(f);
    SubmapFormat format;
    RIM_ASSIGN_OR_RETURN(std::string bytes, ReadSubmapFile(f, &format));
    Int3 key;
    SavedFile stamp;
    RIM_RETURN_IF_ERROR(Install(bytes, f, format, &key, &stamp));
    if (!identity.ok()) continue;
    // Loading this file again gives the sub-map as it now is, so the next save may link the file
    // rather than write it again.
    stamp.path = f;
    stamp.identity = *identity;
    std::lock_guard<std::mutex> lock(mu_);
    saved_[key] = std::move(stamp);
  }
  return absl::OkStatus();
}

}  // namespace rim
