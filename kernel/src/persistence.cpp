// persistence.cpp — see persistence.hpp and docs/persistence.md.
#include "persistence.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <numeric>
#include <set>
#include <string_view>
#include <type_traits>

#include "mspace/abi.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

static_assert(std::endian::native == std::endian::little || std::endian::native == std::endian::big);
static_assert(sizeof(double) == 8 && std::numeric_limits<double>::is_iec559, "map files store IEEE-754 doubles");

/// PNG-style: a non-text byte, the name, CR LF, ^Z, LF — so that text-mode
/// transfers and `cat` of a binary are caught at once.
constexpr std::array<char, 8> kMagic = {'\x89', 'M', 'S', 'P', '\r', '\n', '\x1a', '\n'};
constexpr std::size_t kFrameSize = 4 + 8 + 4 + 8;  ///< tag, key, aux, length (before the frame CRC)

constexpr std::uint32_t tag_of(const char (&s)[5]) {
  return static_cast<std::uint32_t>(static_cast<unsigned char>(s[0])) |
         static_cast<std::uint32_t>(static_cast<unsigned char>(s[1])) << 8 |
         static_cast<std::uint32_t>(static_cast<unsigned char>(s[2])) << 16 |
         static_cast<std::uint32_t>(static_cast<unsigned char>(s[3])) << 24;
}
constexpr std::uint32_t kHead = tag_of("HEAD");
constexpr std::uint32_t kType = tag_of("TYPE");
constexpr std::uint32_t kFeat = tag_of("FEAT");
constexpr std::uint32_t kShrd = tag_of("SHRD");
constexpr std::uint32_t kEnd = tag_of("END ");
// Format version 2: the records of a checkpoint.
constexpr std::uint32_t kParm = tag_of("PARM");
constexpr std::uint32_t kRun = tag_of("RUN ");
constexpr std::uint32_t kPsta = tag_of("PSTA");
// Format version 3: the nonlinear problem of a re-linearising estimator.
constexpr std::uint32_t kProb = tag_of("PROB");
// Format version 3: the covariance of a map (docs/maps.md).
constexpr std::uint32_t kCovm = tag_of("COVM");
constexpr std::uint32_t kCovj = tag_of("COVJ");
/// Numbers of the joint covariance per COVJ record: 64 MiB.
constexpr std::size_t kCovjChunk = std::size_t{8} << 20;

std::string tag_name(std::uint32_t tag) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((tag >> (8 * i)) & 0xff);
    s += (c >= 32 && c < 127) ? c : '?';
  }
  return s;
}

// ---------------------------------------------------------------- CRC-32

/// CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320), as zlib and PNG.
class Crc32 {
 public:
  void add(const void* data, std::size_t size) {
    static const std::array<std::uint32_t, 256> table = [] {
      std::array<std::uint32_t, 256> t{};
      for (std::uint32_t i = 0; i < 256; ++i) {
        std::uint32_t c = i;
        for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        t[i] = c;
      }
      return t;
    }();
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < size; ++i) crc_ = table[(crc_ ^ p[i]) & 0xffu] ^ (crc_ >> 8);
  }
  std::uint32_t value() const { return crc_ ^ 0xffffffffu; }

 private:
  std::uint32_t crc_ = 0xffffffffu;
};

std::uint32_t crc32(const std::string& bytes) {
  Crc32 c;
  c.add(bytes.data(), bytes.size());
  return c.value();
}

// ---------------------------------------------------------------- encoding

/// Appends little-endian values to a byte string (one record's payload).
class Encoder {
 public:
  template <class T>
  void put(T value) {
    static_assert(std::is_arithmetic_v<T>);
    std::array<char, sizeof(T)> b;
    std::memcpy(b.data(), &value, sizeof(T));
    if constexpr (std::endian::native == std::endian::big) std::reverse(b.begin(), b.end());
    bytes_.append(b.data(), b.size());
  }
  void i32(std::int64_t v) { put(static_cast<std::int32_t>(v)); }
  void i64(std::int64_t v) { put(v); }
  void u64(std::size_t v) { put(static_cast<std::uint64_t>(v)); }
  void f64(double v) { put(v); }
  void str(const std::string& s) {
    u64(s.size());
    bytes_ += s;
  }
  void ints(const std::vector<int>& v) {
    u64(v.size());
    for (int x : v) i32(x);
  }
  /// rows, cols, then the values column-major.
  void matrix(const Eigen::MatrixXd& m) {
    u64(static_cast<std::size_t>(m.rows()));
    u64(static_cast<std::size_t>(m.cols()));
    for (Eigen::Index i = 0; i < m.size(); ++i) f64(m.data()[i]);
  }
  const std::string& bytes() const { return bytes_; }

 private:
  std::string bytes_;
};

/// Reads what Encoder wrote; any overrun is a malformed record.
class Decoder {
 public:
  explicit Decoder(const std::string& bytes) : bytes_(bytes) {}
  template <class T>
  T get() {
    need(sizeof(T));
    std::array<char, sizeof(T)> b;
    std::memcpy(b.data(), bytes_.data() + at_, sizeof(T));
    if constexpr (std::endian::native == std::endian::big) std::reverse(b.begin(), b.end());
    at_ += sizeof(T);
    T value;
    std::memcpy(&value, b.data(), sizeof(T));
    return value;
  }
  int i32() { return get<std::int32_t>(); }
  std::int64_t i64() { return get<std::int64_t>(); }
  double f64() { return get<double>(); }
  /// A count of items of at least `item_size` bytes each that must fit in what is left.
  std::size_t count(std::size_t item_size) {
    const std::uint64_t n = get<std::uint64_t>();
    if (item_size > 0 && n > (bytes_.size() - at_) / item_size) throw std::runtime_error("a count exceeds the record");
    return static_cast<std::size_t>(n);
  }
  std::string str() {
    const std::size_t n = count(1);
    std::string s = bytes_.substr(at_, n);
    at_ += n;
    return s;
  }
  std::vector<int> ints() {
    std::vector<int> v(count(4));
    for (int& x : v) x = i32();
    return v;
  }
  Eigen::MatrixXd matrix() {
    constexpr std::size_t kMaxSide = std::size_t{1} << 40;  // keeps rows·cols and Eigen::Index far from overflow
    const std::size_t rows = count(0), cols = count(0);
    if (rows > kMaxSide || cols > kMaxSide || (rows > 0 && cols > (bytes_.size() - at_) / 8 / rows))
      throw std::runtime_error("a matrix exceeds the record");
    Eigen::MatrixXd m(static_cast<Eigen::Index>(rows), static_cast<Eigen::Index>(cols));
    for (Eigen::Index i = 0; i < m.size(); ++i) m.data()[i] = f64();
    return m;
  }
  Eigen::VectorXd vector() {
    Eigen::MatrixXd m = matrix();
    if (m.cols() != 1 && m.size() != 0) throw std::runtime_error("a vector has more than one column");
    return m.reshaped();
  }
  void finish() const {
    if (at_ != bytes_.size()) throw std::runtime_error("trailing bytes after the record's content");
  }

 private:
  void need(std::size_t n) const {
    if (bytes_.size() - at_ < n) throw std::runtime_error("the record ends early");
  }
  const std::string& bytes_;
  std::size_t at_ = 0;
};

// ---------------------------------------------------------------- records

std::string encode_head(const StoredMap& map) {
  Encoder e;
  e.str(map.abi_tag);
  e.str(map.kind);
  e.str(map.run);
  for (int i = 0; i < 6; ++i) e.f64(map.robot_pose[i]);
  return e.bytes();
}

std::string encode_types(const StoredMap& map) {
  Encoder e;
  e.u64(map.types.size());
  for (const StoredType& t : map.types) {
    e.str(t.instance);
    e.str(t.plugin);
  }
  return e.bytes();
}

std::string encode_feature(const StoredFeature& f) {
  Encoder e;
  e.i64(f.id);
  e.i32(f.type);
  e.ints(f.state_idx);
  e.ints(f.own_idx);
  e.u64(f.shared.size());
  for (const auto& [block, id] : f.shared) {
    e.i32(block);
    e.i32(id);
  }
  e.i64(f.created_step);
  e.i64(f.last_seen_step);
  e.i32(f.last_sensor);
  e.f64(f.last_seen_t);
  e.i32(f.times_matched);
  const SavedFeature& s = f.saved;
  e.i32(s.mspace_dim);
  e.i32(s.version);
  e.matrix(s.coords);
  e.matrix(s.extra);
  e.u64(s.arrays.size());
  for (const SavedArray& a : s.arrays) {
    e.str(a.name);
    e.matrix(a.value);
  }
  return e.bytes();
}

std::string encode_shared(const StoredShared& c) {
  Encoder e;
  e.i32(c.id);
  e.i32(static_cast<int>(c.kind));
  e.ints(c.state_idx);
  e.u64(c.members.size());
  for (const auto& [feature, block] : c.members) {
    e.i32(feature);
    e.i32(block);
  }
  return e.bytes();
}

/// A named state: its arrays (name, matrix), then its byte strings (name, bytes).
void encode_state(Encoder& e, const StoredState& state) {
  e.u64(state.arrays().size());
  for (const auto& [name, value] : state.arrays()) {
    e.str(name);
    e.matrix(value);
  }
  e.u64(state.bytes().size());
  for (const auto& [name, bytes] : state.bytes()) {
    e.str(name);
    e.str(bytes);
  }
}

std::string encode_parameters(const StoredCheckpoint& c) {
  Encoder e;
  e.str(c.config_file);
  e.str(c.config_yaml);
  return e.bytes();
}

/// A record that is one named state (RUN, PROB).
std::string encode_state_payload(const StoredState& state) {
  Encoder e;
  encode_state(e, state);
  return e.bytes();
}

std::string encode_plugin_state(const StoredPluginState& p) {
  Encoder e;
  e.str(p.instance);
  e.str(p.plugin);
  e.i32(p.version);
  encode_state(e, p.state);
  return e.bytes();
}

/// COVM: the robot's rows at save time, the map's rows, then every estimated
/// feature's id and marginal covariance, in FEAT order.
std::string encode_marginals(const StoredMap& map) {
  Encoder e;
  e.i32(map.covariance->first_row);
  e.i32(map.covariance->rows);
  std::size_t n = 0;
  for (const StoredFeature& f : map.features) n += f.covariance.size() > 0 ? 1 : 0;
  e.u64(n);
  for (const StoredFeature& f : map.features) {
    if (f.covariance.size() == 0) continue;
    e.i64(f.id);
    e.matrix(f.covariance);
  }
  return e.bytes();
}

/// COVJ number `chunk`: the matrix size, where in the packed lower triangle
/// (column by column) this piece starts, and its numbers.
std::string encode_joint_chunk(const Eigen::MatrixXd& joint, std::size_t begin, std::size_t count) {
  Encoder e;
  const auto n = static_cast<std::size_t>(joint.rows());
  e.u64(n);
  e.u64(begin);
  e.u64(count);
  // Walk the packed lower triangle from `begin`: column c holds rows c..n−1.
  std::size_t c = 0, column_start = 0;
  while (c < n && column_start + (n - c) <= begin) column_start += n - c++;
  std::size_t r = c + (begin - column_start);
  for (std::size_t i = 0; i < count; ++i) {
    e.f64(joint(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c)));
    if (++r == n) r = ++c;
  }
  return e.bytes();
}

void decode_marginals(const std::string& payload, StoredMap& map, std::map<std::int64_t, Eigen::MatrixXd>& out) {
  Decoder d(payload);
  StoredCovariance& cov = map.covariance.emplace();
  cov.first_row = d.i32();
  cov.rows = d.i32();
  if (cov.first_row < 1 || cov.first_row > 6 || cov.rows < 0)
    throw std::runtime_error("bad row counts (robot " + std::to_string(cov.first_row) + ", map " +
                             std::to_string(cov.rows) + ")");
  const std::size_t n = d.count(24);
  for (std::size_t i = 0; i < n; ++i) {
    const std::int64_t id = d.i64();
    Eigen::MatrixXd m = d.matrix();
    if (m.rows() != m.cols() || !m.allFinite())
      throw std::runtime_error("the covariance of feature " + std::to_string(id) + " is not a finite square matrix");
    if (!out.emplace(id, std::move(m)).second)
      throw std::runtime_error("feature " + std::to_string(id) + " has two covariances");
  }
  d.finish();
}

/// Adds one COVJ piece to `joint` (allocated at the first piece); `filled`
/// counts the packed numbers read so far, which the piece must continue.
void decode_joint_chunk(const std::string& payload, StoredMap& map, std::size_t& filled) {
  Decoder d(payload);
  if (!map.covariance) throw std::runtime_error("COVJ before COVM");
  const std::size_t n = d.count(0), begin = d.count(0), count = d.count(8);
  if (n != static_cast<std::size_t>(map.covariance->first_row + map.covariance->rows))
    throw std::runtime_error("the joint covariance has " + std::to_string(n) + " rows, the robot and the map " +
                             std::to_string(map.covariance->first_row + map.covariance->rows));
  const std::size_t total = n * (n + 1) / 2;
  if (begin != filled || count == 0 || count > total - filled) throw std::runtime_error("the pieces are out of order");
  if (!map.covariance->joint) map.covariance->joint = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
  Eigen::MatrixXd& joint = *map.covariance->joint;
  std::size_t c = 0, column_start = 0;
  while (c < n && column_start + (n - c) <= begin) column_start += n - c++;
  std::size_t r = c + (begin - column_start);
  for (std::size_t i = 0; i < count; ++i) {
    const double v = d.f64();
    if (!std::isfinite(v)) throw std::runtime_error("a covariance entry is not finite");
    joint(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c)) = v;
    joint(static_cast<Eigen::Index>(c), static_cast<Eigen::Index>(r)) = v;
    if (++r == n) r = ++c;
  }
  filled += count;
  d.finish();
}

void decode_head(const std::string& payload, StoredMap& map) {
  Decoder d(payload);
  map.abi_tag = d.str();
  map.kind = d.str();
  map.run = d.str();
  for (int i = 0; i < 6; ++i) map.robot_pose[i] = d.f64();
  d.finish();
}

void decode_types(const std::string& payload, StoredMap& map) {
  Decoder d(payload);
  map.types.resize(d.count(16));
  for (StoredType& t : map.types) {
    t.instance = d.str();
    t.plugin = d.str();
  }
  d.finish();
}

StoredFeature decode_feature(const std::string& payload) {
  Decoder d(payload);
  StoredFeature f;
  f.id = d.i64();
  f.type = d.i32();
  f.state_idx = d.ints();
  f.own_idx = d.ints();
  const std::size_t n_shared = d.count(8);
  for (std::size_t i = 0; i < n_shared; ++i) {
    const int block = d.i32();
    f.shared[block] = d.i32();
  }
  f.created_step = d.i64();
  f.last_seen_step = d.i64();
  f.last_sensor = d.i32();
  f.last_seen_t = d.f64();
  f.times_matched = d.i32();
  SavedFeature& s = f.saved;
  s.mspace_dim = d.i32();
  s.version = d.i32();
  s.coords = d.vector();
  s.extra = d.vector();
  const std::size_t n_arrays = d.count(24);
  for (std::size_t i = 0; i < n_arrays; ++i) {
    std::string name = d.str();
    s.arrays.push_back({std::move(name), d.matrix()});
  }
  d.finish();
  return f;
}

StoredShared decode_shared(const std::string& payload) {
  Decoder d(payload);
  StoredShared c;
  c.id = d.i32();
  const int kind = d.i32();
  if (kind < 0 || kind > static_cast<int>(BlockKind::Scalar)) throw std::runtime_error("unknown block kind");
  c.kind = static_cast<BlockKind>(kind);
  c.state_idx = d.ints();
  c.members.resize(d.count(8));
  for (auto& [feature, block] : c.members) {
    feature = d.i32();
    block = d.i32();
  }
  d.finish();
  return c;
}

void decode_state(Decoder& d, StoredState& state) {
  const std::size_t arrays = d.count(24);
  for (std::size_t i = 0; i < arrays; ++i) {
    std::string name = d.str();
    try {
      state.put(name, d.matrix());
    } catch (const std::logic_error&) {
      throw std::runtime_error("the array '" + name + "' appears twice");
    }
  }
  const std::size_t blobs = d.count(16);
  for (std::size_t i = 0; i < blobs; ++i) {
    std::string name = d.str();
    try {
      state.put_bytes(name, d.str());
    } catch (const std::logic_error&) {
      throw std::runtime_error("the byte string '" + name + "' appears twice");
    }
  }
}

void decode_parameters(const std::string& payload, StoredCheckpoint& c) {
  Decoder d(payload);
  c.config_file = d.str();
  c.config_yaml = d.str();
  d.finish();
}

StoredState decode_state_payload(const std::string& payload) {
  Decoder d(payload);
  StoredState state;
  decode_state(d, state);
  d.finish();
  return state;
}

StoredPluginState decode_plugin_state(const std::string& payload) {
  Decoder d(payload);
  StoredPluginState p;
  p.instance = d.str();
  p.plugin = d.str();
  p.version = d.i32();
  decode_state(d, p.state);
  d.finish();
  return p;
}

/// The SDK major version in an ABI tag "mspace-sdkN/…"; -1 if there is none.
int sdk_major_of(const std::string& tag) {
  constexpr std::string_view prefix = "mspace-sdk";
  if (tag.compare(0, prefix.size(), prefix) != 0) return -1;
  int n = 0;
  std::size_t i = prefix.size();
  if (i >= tag.size() || tag[i] < '0' || tag[i] > '9') return -1;
  for (; i < tag.size() && tag[i] >= '0' && tag[i] <= '9' && n < 100000; ++i) n = 10 * n + (tag[i] - '0');
  return n;
}

// ---------------------------------------------------------------- file output

/// A temporary file beside the target, renamed over it by commit(); removed
/// if never committed.
class AtomicFile {
 public:
  explicit AtomicFile(const std::filesystem::path& target) : target_(target) {
    temp_ = target;
    temp_ += ".tmp-" + std::to_string(::getpid());
    file_ = std::fopen(temp_.c_str(), "wb");
    if (file_ == nullptr)
      throw PersistenceError(target_, std::string("cannot create a temporary file: ") + std::strerror(errno));
  }
  ~AtomicFile() {
    if (file_ != nullptr) std::fclose(file_);
    if (!committed_) {
      std::error_code ignored;
      std::filesystem::remove(temp_, ignored);
    }
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  void write(const void* data, std::size_t size) {
    if (size > 0 && std::fwrite(data, 1, size, file_) != size)
      throw PersistenceError(target_, std::string("write failed: ") + std::strerror(errno));
  }
  void commit() {
    const bool flushed = std::fflush(file_) == 0 && ::fsync(::fileno(file_)) == 0;
    const int close_result = std::fclose(file_);
    file_ = nullptr;
    if (!flushed || close_result != 0)
      throw PersistenceError(target_, std::string("write failed: ") + std::strerror(errno));
    std::error_code ec;
    std::filesystem::rename(temp_, target_, ec);
    if (ec) throw PersistenceError(target_, "cannot rename the temporary file into place: " + ec.message());
    committed_ = true;
  }

 private:
  std::filesystem::path target_, temp_;
  std::FILE* file_ = nullptr;
  bool committed_ = false;
};

class RecordWriter {
 public:
  explicit RecordWriter(AtomicFile& out) : out_(out) {}
  void write(std::uint32_t tag, std::int64_t key, std::int32_t aux, const std::string& payload) {
    Encoder frame;
    frame.put(tag);
    frame.put(key);
    frame.put(aux);
    frame.put(static_cast<std::uint64_t>(payload.size()));
    Encoder crcs;
    crcs.put(crc32(frame.bytes()));
    out_.write(frame.bytes().data(), frame.bytes().size());
    out_.write(crcs.bytes().data(), crcs.bytes().size());
    out_.write(payload.data(), payload.size());
    Encoder tail;
    tail.put(crc32(payload));
    out_.write(tail.bytes().data(), tail.bytes().size());
    ++records_;
  }
  std::uint64_t records() const { return records_; }

 private:
  AtomicFile& out_;
  std::uint64_t records_ = 0;
};

// ---------------------------------------------------------------- file input

struct Record {
  std::uint32_t tag = 0;
  std::int64_t key = 0;
  std::int32_t aux = 0;
  std::string payload;
  std::uint64_t offset = 0;  ///< of its frame in the file
};

class RecordReader {
 public:
  RecordReader(const std::filesystem::path& file, std::ifstream& in, std::uint64_t size)
      : file_(file), in_(in), size_(size) {}

  /// The next record; throws naming the file (and the feature, when the
  /// frame says which) on truncation or a CRC mismatch.
  Record next(const std::vector<StoredType>& types) {
    Record r;
    r.offset = static_cast<std::uint64_t>(in_.tellg());
    std::string frame(kFrameSize + 4, '\0');
    if (!in_.read(frame.data(), static_cast<std::streamsize>(frame.size())))
      throw PersistenceError(file_, "truncated: the file ends at byte " + std::to_string(size_) +
                                        " inside the frame of record " + std::to_string(index_) + " (no END record)");
    const std::string framed = frame.substr(0, kFrameSize);
    Decoder d(frame);
    r.tag = d.get<std::uint32_t>();
    r.key = d.get<std::int64_t>();
    r.aux = d.get<std::int32_t>();
    const std::uint64_t length = d.get<std::uint64_t>();
    if (d.get<std::uint32_t>() != crc32(framed))
      throw PersistenceError(file_, "corrupt: the frame of record " + std::to_string(index_) + " at byte " +
                                        std::to_string(r.offset) + " fails its CRC-32");
    const bool feature = r.tag == kFeat;
    const std::optional<std::int64_t> id = feature ? std::optional<std::int64_t>(r.key) : std::nullopt;
    const std::string plugin = feature ? plugin_of(types, r.aux) : std::string();
    const std::uint64_t at = r.offset + kFrameSize + 4;
    if (length > size_ - std::min(size_, at) || size_ - at - length < 4)
      throw PersistenceError(file_,
                             "truncated: record " + std::to_string(index_) + " (" + tag_name(r.tag) + ") needs " +
                                 std::to_string(length + 4) + " bytes after byte " + std::to_string(at) +
                                 ", the file has " + std::to_string(size_),
                             id, plugin);
    r.payload.resize(static_cast<std::size_t>(length));
    std::array<char, 4> crc{};
    if (!in_.read(r.payload.data(), static_cast<std::streamsize>(length)) || !in_.read(crc.data(), 4))
      throw PersistenceError(file_, "cannot read record " + std::to_string(index_), id, plugin);
    const std::string crc_bytes(crc.data(), 4);
    if (Decoder(crc_bytes).get<std::uint32_t>() != crc32(r.payload))
      throw PersistenceError(file_,
                             "corrupt: the content of record " + std::to_string(index_) + " (" + tag_name(r.tag) +
                                 ") at byte " + std::to_string(r.offset) + " fails its CRC-32",
                             id, plugin);
    ++index_;
    return r;
  }
  std::uint64_t index() const { return index_; }

  static std::string plugin_of(const std::vector<StoredType>& types, std::int32_t type) {
    if (type < 0 || static_cast<std::size_t>(type) >= types.size()) return "?";
    return types[static_cast<std::size_t>(type)].plugin;
  }

 private:
  const std::filesystem::path& file_;
  std::ifstream& in_;
  std::uint64_t size_;
  std::uint64_t index_ = 0;
};

/// Cross-record checks: type indices, unique ids, shared coordinates' members.
void check_consistency(const std::filesystem::path& file, const StoredMap& map) {
  std::set<std::int64_t> ids;
  for (const StoredFeature& f : map.features) {
    const std::string plugin = RecordReader::plugin_of(map.types, f.type);
    if (f.type < 0 || static_cast<std::size_t>(f.type) >= map.types.size())
      throw PersistenceError(file, "feature type index " + std::to_string(f.type) + " is not in the type table", f.id,
                             plugin);
    if (!ids.insert(f.id).second) throw PersistenceError(file, "the feature id appears twice", f.id, plugin);
    if (f.saved.mspace_dim < 0 ||
        (f.saved.mspace_dim > 0 && static_cast<int>(f.state_idx.size()) != f.saved.mspace_dim))
      throw PersistenceError(file,
                             "the M-space dimension " + std::to_string(f.saved.mspace_dim) + " does not match its " +
                                 std::to_string(f.state_idx.size()) + " state indices",
                             f.id, plugin);
  }
  std::set<int> shared_ids;
  for (const StoredShared& c : map.shared) {
    if (!shared_ids.insert(c.id).second)
      throw PersistenceError(file, "shared coordinate " + std::to_string(c.id) + " appears twice");
    for (const auto& [feature, block] : c.members)
      if (ids.count(feature) == 0)
        throw PersistenceError(file, "shared coordinate " + std::to_string(c.id) + " names feature " +
                                         std::to_string(feature) + ", which is not in the file");
  }
  for (const StoredFeature& f : map.features)
    for (const auto& [block, id] : f.shared)
      if (shared_ids.count(id) == 0)
        throw PersistenceError(file,
                               "block " + std::to_string(block) + " is shared with coordinate " + std::to_string(id) +
                                   ", which is not in the file",
                               f.id, RecordReader::plugin_of(map.types, f.type));
}

/// The covariance records against the features: every estimated feature has
/// its marginal, of its dimension, over rows of the map.
void check_covariance(const std::filesystem::path& file, StoredMap& map,
                      std::map<std::int64_t, Eigen::MatrixXd>& marginals) {
  if (!map.covariance) return;
  const int lo = map.covariance->first_row, hi = lo + map.covariance->rows;
  for (StoredFeature& f : map.features) {
    const std::string plugin = RecordReader::plugin_of(map.types, f.type);
    for (int i : f.state_idx)
      if (i < lo || i >= hi)
        throw PersistenceError(file,
                               "state index " + std::to_string(i) + " is outside the map's rows " +
                                   std::to_string(lo) + ".." + std::to_string(hi - 1),
                               f.id, plugin);
    const auto it = marginals.find(f.id);
    if (f.state_idx.empty()) {
      if (it != marginals.end()) throw PersistenceError(file, "a tentative feature has a covariance", f.id, plugin);
      continue;
    }
    if (it == marginals.end()) throw PersistenceError(file, "no covariance (COVM) for the feature", f.id, plugin);
    const auto dim = static_cast<Eigen::Index>(f.state_idx.size());
    if (it->second.rows() != dim)
      throw PersistenceError(file,
                             "its covariance is " + std::to_string(it->second.rows()) + "x" +
                                 std::to_string(it->second.cols()) + " for M-space dimension " + std::to_string(dim),
                             f.id, plugin);
    f.covariance = std::move(it->second);
    marginals.erase(it);
  }
  if (!marginals.empty())
    throw PersistenceError(file, "a covariance (COVM) for feature " + std::to_string(marginals.begin()->first) +
                                     ", which is not in the file");
  for (const StoredShared& c : map.shared)
    for (int i : c.state_idx)
      if (i < lo || i >= hi)
        throw PersistenceError(file, "shared coordinate " + std::to_string(c.id) + ": state index " +
                                         std::to_string(i) + " is outside the map's rows");
}

std::string what_with_context(const std::filesystem::path& file, const std::string& what,
                              std::optional<std::int64_t> feature_id, const std::string& plugin) {
  std::string s = "map file '" + file.string() + "'";
  if (feature_id) s += ", feature " + std::to_string(*feature_id);
  if (!plugin.empty()) s += " (plugin '" + plugin + "')";
  return s + ": " + what;
}

}  // namespace

PersistenceError::PersistenceError(const std::filesystem::path& file, const std::string& what,
                                   std::optional<std::int64_t> feature_id, const std::string& plugin)
    : std::runtime_error(what_with_context(file, what, feature_id, plugin)),
      file_(file),
      feature_id_(feature_id),
      plugin_(plugin) {}

std::string pack_strings(const std::vector<std::string>& strings) {
  Encoder e;
  e.u64(strings.size());
  for (const std::string& s : strings) e.str(s);
  return e.bytes();
}

std::vector<std::string> unpack_strings(const std::string& bytes) {
  try {
    Decoder d(bytes);
    std::vector<std::string> strings(d.count(8));
    for (std::string& s : strings) s = d.str();
    d.finish();
    return strings;
  } catch (const std::runtime_error& e) {
    throw std::invalid_argument(std::string("not a list of strings: ") + e.what());
  }
}

void StoredState::put(const std::string& name, const Eigen::MatrixXd& value) {
  if (!arrays_.emplace(name, value).second) throw std::logic_error("saved array '" + name + "' written twice");
}

void StoredState::put_bytes(const std::string& name, const std::string& bytes) {
  if (!bytes_.emplace(name, bytes).second) throw std::logic_error("saved byte string '" + name + "' written twice");
}

bool StoredState::has(const std::string& name) const { return arrays_.count(name) != 0 || bytes_.count(name) != 0; }

const Eigen::MatrixXd& StoredState::get(const std::string& name) const {
  const auto it = arrays_.find(name);
  if (it == arrays_.end()) throw std::invalid_argument("no saved array '" + name + "'");
  return it->second;
}

const std::string& StoredState::get_bytes(const std::string& name) const {
  const auto it = bytes_.find(name);
  if (it == bytes_.end()) throw std::invalid_argument("no saved byte string '" + name + "'");
  return it->second;
}

StoredMap snapshot_map(const Slam& slam, const std::filesystem::path& file, SnapshotCovariance covariance) {
  StoredMap map;
  map.abi_tag = sdk_abi_tag();
  map.run = slam.config().name;
  map.robot_pose = slam.pose();
  for (const FeatureTypeSlot& t : slam.feature_types()) map.types.push_back({t.instance, t.plugin});
  for (const MapFeature& mf : slam.features()) {
    StoredFeature f;
    f.id = mf.id;
    f.type = mf.type;
    static_cast<FeatureBookkeeping&>(f) = mf;
    const FeatureTypeSlot& type = slam.feature_types()[static_cast<std::size_t>(mf.type)];
    try {
      f.saved = mf.feature->save();
    } catch (const std::exception& e) {
      throw PersistenceError(file, std::string("save() failed: ") + e.what(), mf.id, type.plugin);
    }
    map.features.push_back(std::move(f));
  }
  for (const SharedCoordinate& c : slam.shared_coordinates())
    map.shared.push_back({c.id, c.kind, c.state_idx, c.members});
  if (covariance == SnapshotCovariance::None) return map;
  // The map's covariance: every estimated feature's marginal, and (for
  // `extend`) the joint covariance of all the map's estimator rows.
  StoredCovariance& cov = map.covariance.emplace();
  cov.first_row = static_cast<int>(slam.robot_dofs().size());
  cov.rows = slam.estimator_dim() - cov.first_row;
  for (std::size_t i = 0; i < map.features.size(); ++i)
    if (!map.features[i].state_idx.empty()) map.features[i].covariance = slam.feature_covariance(slam.features()[i]);
  if (covariance == SnapshotCovariance::Joint) {
    std::vector<int> rows(static_cast<std::size_t>(cov.first_row + cov.rows));
    std::iota(rows.begin(), rows.end(), 0);
    cov.joint = slam.state_covariance(rows);
  }
  return map;
}

void write_map_file(const std::filesystem::path& file, const StoredMap& map) {
  if ((map.kind == "checkpoint") != map.checkpoint.has_value())
    throw PersistenceError(file, "a checkpoint needs its checkpoint records, a map has none");
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path());
  AtomicFile out(file);
  out.write(kMagic.data(), kMagic.size());
  Encoder version;
  version.put(kMapFormatVersion);
  out.write(version.bytes().data(), version.bytes().size());
  RecordWriter w(out);
  w.write(kHead, 0, -1, encode_head(map));
  w.write(kType, 0, -1, encode_types(map));
  for (const StoredFeature& f : map.features) w.write(kFeat, f.id, f.type, encode_feature(f));
  for (const StoredShared& c : map.shared) w.write(kShrd, c.id, -1, encode_shared(c));
  if (map.checkpoint) {
    w.write(kParm, 0, -1, encode_parameters(*map.checkpoint));
    w.write(kRun, 0, -1, encode_state_payload(map.checkpoint->run));
    for (std::size_t i = 0; i < map.checkpoint->plugins.size(); ++i)
      w.write(kPsta, static_cast<std::int64_t>(i), -1, encode_plugin_state(map.checkpoint->plugins[i]));
    if (map.checkpoint->problem) w.write(kProb, 0, -1, encode_state_payload(*map.checkpoint->problem));
  }
  if (map.covariance) {
    w.write(kCovm, 0, -1, encode_marginals(map));
    if (map.covariance->joint) {
      const auto n = static_cast<std::size_t>(map.covariance->joint->rows());
      const std::size_t total = n * (n + 1) / 2;
      for (std::size_t begin = 0, chunk = 0; begin < total; begin += kCovjChunk, ++chunk)
        w.write(kCovj, static_cast<std::int64_t>(chunk), -1,
                encode_joint_chunk(*map.covariance->joint, begin, std::min(kCovjChunk, total - begin)));
    }
  }
  Encoder end;
  end.put(w.records());
  w.write(kEnd, 0, -1, end.bytes());
  out.commit();
}

StoredMap read_map_file(const std::filesystem::path& file, const std::string& kind) {
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(file, ec);
  if (ec) throw PersistenceError(file, "cannot read: " + ec.message());
  std::ifstream in(file, std::ios::binary);
  if (!in) throw PersistenceError(file, "cannot open for reading");
  std::array<char, 8> magic{};
  std::array<char, 4> version_bytes{};
  if (!in.read(magic.data(), magic.size()) || magic != kMagic)
    throw PersistenceError(file, "not an mspace map file (wrong magic number)");
  if (!in.read(version_bytes.data(), version_bytes.size()))
    throw PersistenceError(file, "truncated: the file ends before its format version");
  StoredMap map;
  map.format_version = Decoder(std::string(version_bytes.data(), 4)).get<std::uint32_t>();
  if (map.format_version < kOldestMapFormatVersion || map.format_version > kMapFormatVersion)
    throw PersistenceError(file, "format version " + std::to_string(map.format_version) +
                                     "; this build of mspace reads versions " +
                                     std::to_string(kOldestMapFormatVersion) + " to " +
                                     std::to_string(kMapFormatVersion));
  RecordReader reader(file, in, static_cast<std::uint64_t>(size));
  bool head = false, types = false, parameters = false, run = false;
  std::map<std::int64_t, Eigen::MatrixXd> marginals;  // COVM, by feature id
  std::size_t joint_filled = 0;                        // COVJ numbers read
  for (;;) {
    const std::uint64_t index = reader.index();
    Record r = reader.next(map.types);
    const bool feature = r.tag == kFeat;
    const std::optional<std::int64_t> id = feature ? std::optional<std::int64_t>(r.key) : std::nullopt;
    const std::string plugin = feature ? RecordReader::plugin_of(map.types, r.aux) : std::string();
    try {
      if (index == 0 && r.tag != kHead) throw std::runtime_error("the first record is not HEAD");
      if (index == 1 && r.tag != kType) throw std::runtime_error("the second record is not TYPE");
      if (r.tag == kHead) {
        if (head) throw std::runtime_error("a second HEAD record");
        decode_head(r.payload, map);
        head = true;
        if (map.kind != "map" && map.kind != "checkpoint")
          throw std::runtime_error("unknown kind of file '" + map.kind + "'");
        if (map.kind != kind)
          throw PersistenceError(file, "this is a " + map.kind + ", not a " + kind +
                                           (kind == "checkpoint" ? " (mspace run --resume needs a checkpoint)" : ""));
        const int major = sdk_major_of(map.abi_tag);
        // SDK 4 changed no saved feature layout (it added plugin run-time
        // state), so maps of SDK 3 still read; a checkpoint's plugin states
        // follow the plugin interfaces of its own SDK version.
        const int oldest = kind == "checkpoint" ? MSPACE_SDK_VERSION_MAJOR : 3;
        if (major < oldest || major > MSPACE_SDK_VERSION_MAJOR)
          throw PersistenceError(file, "written with SDK ABI '" + map.abi_tag + "' (SDK version " +
                                           std::to_string(major) + "); this build has '" + sdk_abi_tag() +
                                           "': the plugins' saved state may differ; re-create the " + kind);
        if (map.kind == "checkpoint") map.checkpoint.emplace();
      } else if (r.tag == kType) {
        if (types) throw std::runtime_error("a second TYPE record");
        decode_types(r.payload, map);
        types = true;
      } else if (r.tag == kFeat) {
        StoredFeature f = decode_feature(r.payload);
        if (f.id != r.key || f.type != r.aux) throw std::runtime_error("the frame and the content disagree");
        map.features.push_back(std::move(f));
      } else if (r.tag == kShrd) {
        map.shared.push_back(decode_shared(r.payload));
      } else if ((r.tag == kParm || r.tag == kRun || r.tag == kPsta) && map.format_version >= 2) {
        if (!map.checkpoint) throw std::runtime_error("a checkpoint record in a map");
        if (r.tag == kParm) {
          if (parameters) throw std::runtime_error("a second PARM record");
          decode_parameters(r.payload, *map.checkpoint);
          parameters = true;
        } else if (r.tag == kRun) {
          if (run) throw std::runtime_error("a second RUN record");
          map.checkpoint->run = decode_state_payload(r.payload);
          run = true;
        } else {
          if (r.key != static_cast<std::int64_t>(map.checkpoint->plugins.size()))
            throw std::runtime_error("plugin state records out of order");
          map.checkpoint->plugins.push_back(decode_plugin_state(r.payload));
        }
      } else if (r.tag == kProb && map.format_version >= 3) {
        if (!map.checkpoint) throw std::runtime_error("a nonlinear problem in a map");
        if (map.checkpoint->problem) throw std::runtime_error("a second PROB record");
        map.checkpoint->problem = decode_state_payload(r.payload);
      } else if (r.tag == kCovm && map.format_version >= 3) {
        if (map.kind != "map") throw std::runtime_error("a map covariance record in a " + map.kind);
        if (map.covariance) throw std::runtime_error("a second COVM record");
        decode_marginals(r.payload, map, marginals);
      } else if (r.tag == kCovj && map.format_version >= 3) {
        decode_joint_chunk(r.payload, map, joint_filled);
      } else if (r.tag == kEnd) {
        std::uint64_t count = 0;
        {
          Decoder d(r.payload);
          count = d.get<std::uint64_t>();
          d.finish();
        }
        if (count != index)
          throw std::runtime_error("END counts " + std::to_string(count) + " records, the file has " +
                                   std::to_string(index));
        if (static_cast<std::uint64_t>(in.tellg()) != size) throw std::runtime_error("bytes after the END record");
        break;
      } else {
        throw std::runtime_error("unknown record tag '" + tag_name(r.tag) + "'");
      }
    } catch (const PersistenceError&) {
      throw;
    } catch (const std::exception& e) {
      throw PersistenceError(file,
                             "malformed record " + std::to_string(index) + " (" + tag_name(r.tag) + ") at byte " +
                                 std::to_string(r.offset) + ": " + e.what(),
                             id, plugin);
    }
  }
  if (map.checkpoint && (!parameters || !run))
    throw PersistenceError(file, std::string("a checkpoint without its ") + (parameters ? "RUN" : "PARM") + " record");
  if (map.covariance && map.covariance->joint) {
    const auto n = static_cast<std::size_t>(map.covariance->first_row + map.covariance->rows);
    if (joint_filled != n * (n + 1) / 2)
      throw PersistenceError(file, "truncated joint covariance: " + std::to_string(joint_filled) + " of " +
                                       std::to_string(n * (n + 1) / 2) + " numbers (COVJ records missing)");
  }
  check_consistency(file, map);
  check_covariance(file, map, marginals);
  return map;
}

std::vector<RestoredFeature> restore_features(const StoredMap& map, const std::filesystem::path& file,
                                              const std::vector<FeatureTypeSlot>& types) {
  // Which of the run's feature types each type of the file is.
  std::vector<int> slot_of(map.types.size(), -1);
  for (std::size_t i = 0; i < map.types.size(); ++i)
    for (std::size_t j = 0; j < types.size(); ++j)
      if (types[j].instance == map.types[i].instance && types[j].plugin == map.types[i].plugin && types[j].type)
        slot_of[i] = static_cast<int>(j);
  std::vector<RestoredFeature> out;
  out.reserve(map.features.size());
  for (const StoredFeature& f : map.features) {
    const StoredType& stored = map.types.at(static_cast<std::size_t>(f.type));
    const int slot = slot_of[static_cast<std::size_t>(f.type)];
    if (slot < 0)
      throw PersistenceError(file,
                             "feature type '" + stored.instance + "' of plugin '" + stored.plugin +
                                 "' is not loaded in this run (is the plugin installed and the type configured?)",
                             f.id, stored.plugin);
    const FeatureTypeSlot& type = types[static_cast<std::size_t>(slot)];
    std::unique_ptr<Feature> feature;
    try {
      feature = type.type->restore(f.saved);
    } catch (const std::exception& e) {
      throw PersistenceError(file, std::string("restore() refused the saved state: ") + e.what(), f.id, stored.plugin);
    }
    if (!feature) throw PersistenceError(file, "restore() returned nothing", f.id, stored.plugin);
    if (feature->mspace_dim() != f.saved.mspace_dim || feature->coords().size() != f.saved.coords.size())
      throw PersistenceError(file,
                             "restore() gave M-space dimension " + std::to_string(feature->mspace_dim()) +
                                 ", the file says " + std::to_string(f.saved.mspace_dim),
                             f.id, stored.plugin);
    out.push_back({f.id, slot, type.adopt(std::move(feature), f.id)});
  }
  return out;
}

void write_map_bin(const std::filesystem::path& file, const Slam& slam) {
  write_map_file(file, snapshot_map(slam, file,
                                    slam.config().output.map_joint_covariance ? SnapshotCovariance::Joint
                                                                             : SnapshotCovariance::Marginal));
}

std::filesystem::path find_map_file(const std::filesystem::path& given) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_regular_file(given, ec)) return given;
  if (fs::is_directory(given, ec)) {
    if (fs::is_regular_file(given / "map.bin", ec)) return given / "map.bin";
    throw PersistenceError(given, "no map here: the folder holds no map.bin (written by a mapping run with output.map: true)");
  }
  throw PersistenceError(given, "no such file or folder");
}

}  // namespace mspace::kernel
