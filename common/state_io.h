// Binary state of the online model's stages for the checkpoint (issue 20: a server restarted from
// its checkpoint continues with exactly the state an uninterrupted server had at the same frame,
// so the model after the journal replay equals the uninterrupted run's). Little-endian host
// layout of trivially copyable values, vectors with a u64 count; the reader is bounds-checked
// (a truncated or corrupt blob is an error, never a crash: the checkpoint parser is fuzzed) and
// caps every count by the bytes left. Not a wire format: a blob is read back by the same build
// (the server rejects a state of another format version and rebuilds from the stored views).
#pragma once

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "absl/strings/str_cat.h"
#include "common/status.h"

namespace exo {

class StateWriter {
 public:
  template <typename T>
  void Put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out_.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  template <typename T>
  void PutVec(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    Put<uint64_t>(v.size());
    out_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  void PutBytes(std::string_view s) {
    Put<uint64_t>(s.size());
    out_.append(s.data(), s.size());
  }
  std::string& str() { return out_; }

 private:
  std::string out_;
};

class StateReader {
 public:
  explicit StateReader(std::string_view in) : in_(in) {}
  template <typename T>
  bool Get(T* v) {
    static_assert(std::is_trivially_copyable_v<T>);
    if (in_.size() < sizeof(T)) return Fail();
    std::memcpy(v, in_.data(), sizeof(T));
    in_.remove_prefix(sizeof(T));
    return true;
  }
  // A count of elements of `elem_bytes` each that the remaining bytes can hold.
  bool Count(uint64_t* n, size_t elem_bytes) {
    if (!Get(n)) return false;
    if (elem_bytes > 0 && *n > in_.size() / elem_bytes) return Fail();
    return true;
  }
  template <typename T>
  bool GetVec(std::vector<T>* v) {
    static_assert(std::is_trivially_copyable_v<T>);
    uint64_t n = 0;
    if (!Count(&n, sizeof(T))) return false;
    v->resize(n);
    if (n) std::memcpy(v->data(), in_.data(), n * sizeof(T));
    in_.remove_prefix(n * sizeof(T));
    return true;
  }
  bool GetBytes(std::string* s) {
    uint64_t n = 0;
    if (!Count(&n, 1)) return false;
    s->assign(in_.data(), n);
    in_.remove_prefix(n);
    return true;
  }
  bool ok() const { return ok_; }
  bool done() const { return ok_ && in_.empty(); }
  absl::Status Status(std::string_view what) const {
    if (ok_) return absl::OkStatus();
    return absl::DataLossError(absl::StrCat(std::string(what), ": truncated or corrupt state"));
  }

 private:
  bool Fail() {
    ok_ = false;
    in_ = {};
    return false;
  }
  std::string_view in_;
  bool ok_ = true;
};

// A std::unordered_map with its iteration order: the bucket count and the entries in iteration
// order; GetUnordered re-creates the same bucket count and inserts in reverse order, which gives
// libstdc++'s node list the saved order back (code that iterates such a map then visits the
// entries as the saved process did: a tie broken by "the first one found" stays the same).
template <typename Map, typename PutValue>
void PutUnordered(StateWriter* w, const Map& m, PutValue put_value) {
  w->Put<uint64_t>(m.bucket_count());
  w->Put<uint64_t>(m.size());
  for (const auto& [k, v] : m) {
    w->Put(k);
    put_value(v);
  }
}
template <typename Map, typename GetValue>
bool GetUnordered(StateReader* r, Map* m, GetValue get_value) {
  uint64_t buckets = 0, n = 0;
  if (!r->Get(&buckets) || !r->Count(&n, sizeof(typename Map::key_type))) return false;
  std::vector<std::pair<typename Map::key_type, typename Map::mapped_type>> items(n);
  for (auto& [k, v] : items)
    if (!r->Get(&k) || !get_value(&v)) return false;
  m->clear();
  if (buckets <= 8 * n + (uint64_t{1} << 16)) m->rehash(buckets);
  for (auto it = items.rbegin(); it != items.rend(); ++it)
    m->emplace(std::move(it->first), std::move(it->second));
  return true;
}
template <typename Map>
void PutUnorderedPod(StateWriter* w, const Map& m) {
  PutUnordered(w, m, [w](const auto& v) { w->Put(v); });
}
template <typename Map>
bool GetUnorderedPod(StateReader* r, Map* m) {
  return GetUnordered(r, m, [r](auto* v) { return r->Get(v); });
}

}  // namespace exo
