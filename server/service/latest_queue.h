// A FIFO queue that holds at most one value per key: putting a key that is already queued
// replaces its value in place. A watcher's pending tiles live in one, so that a dashboard that
// reads slowly holds at most one version of each tile (the newest), never a backlog.
#pragma once

#include <deque>
#include <optional>
#include <utility>

#include "absl/container/flat_hash_map.h"

namespace rim::server {

template <typename Key, typename Value, typename Hash, typename Eq>
class LatestPerKeyQueue {
 public:
  // Queues `value` under `key`; returns true when it replaced a queued value of the same key
  // (which keeps its place in the queue).
  bool Put(const Key& key, Value value) {
    auto [it, inserted] = values_.try_emplace(key, std::move(value));
    if (!inserted) {
      it->second = std::move(value);
      return true;
    }
    order_.push_back(key);
    return false;
  }
  // The oldest queued key's value, removed; nullopt when empty.
  std::optional<Value> Pop() {
    if (order_.empty()) return std::nullopt;
    auto it = values_.find(order_.front());
    order_.pop_front();
    Value v = std::move(it->second);
    values_.erase(it);
    return v;
  }
  size_t size() const { return order_.size(); }
  bool empty() const { return order_.empty(); }

 private:
  std::deque<Key> order_;
  absl::flat_hash_map<Key, Value, Hash, Eq> values_;
};

}  // namespace rim::server
