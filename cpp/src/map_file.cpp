// octofuse: reading and writing OctoMap's .ot and .bt files, with every declared size checked
// against what the file holds before anything is allocated.
#include "octofuse/map_file.hpp"

#include "octofuse/detail/text.hpp"
#include "octofuse/detail/tree_access.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

namespace octofuse {

namespace {

using detail::printable;
using detail::shortest;
using OcTreeAccess = detail::TreeAccess<OccupancyTree>;

const char* const kOtHeader = "# Octomap OcTree file";
const char* const kBtHeader = "# Octomap OcTree binary file";
constexpr unsigned kMaxDepth = 16;
constexpr std::size_t kOtNodeBytes = sizeof(float) + 1;  // value + child mask
constexpr std::size_t kBtRecordBytes = 2;                // 2 bits per child

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw MapFileError("map file '" + path + "' " + what);
}

/// Cursor over the binary data section of a map file with bounds checks.
struct Reader {
  const std::string& path;
  const char* p;
  const char* end;

  std::size_t left() const { return static_cast<std::size_t>(end - p); }
  template <class T>
  T get() {
    if (left() < sizeof(T)) fail(path, "is truncated: the tree data ends early");
    T v;
    std::memcpy(&v, p, sizeof(T));
    p += sizeof(T);
    return v;
  }
};

/// Nodes of a tree and how many of them have children.
struct Counts {
  std::size_t nodes = 0, inner = 0;
};

[[noreturn]] void too_deep(const std::string& path, unsigned depth) {
  fail(path, "is corrupt: a node at depth " + std::to_string(depth) +
                 " has children (OcTree depth is 16)");
}

// Full format: value (float) + children mask (1 byte) per node, depth first. With kBuild false
// the data is only checked and counted (tree and node are null).
template <bool kBuild>
void read_ot_node(Reader& r, OccupancyTree* tree, OccupancyNode* node, unsigned depth, Counts& c) {
  const float value = r.get<float>();
  if (!std::isfinite(value)) {
    fail(r.path,
         "holds a non-finite log-odds value (" + std::to_string(value) + "): the file is corrupt");
  }
  if constexpr (kBuild) node->setLogOdds(value);
  ++c.nodes;
  const auto mask = r.get<std::uint8_t>();
  if (mask == 0) return;
  if (depth >= kMaxDepth) too_deep(r.path, depth);
  ++c.inner;
  for (unsigned i = 0; i < 8; ++i) {
    if (!(mask & (1u << i))) continue;
    OccupancyNode* child = nullptr;
    if constexpr (kBuild) child = tree->createNodeChild(node, i);
    read_ot_node<kBuild>(r, tree, child, depth + 1, c);
  }
}

// Binary format: 2 bits per child: 01 free leaf, 10 occupied leaf, 11 inner, 00 unknown
// (bit 2i set = "free" flag, bit 2i+1 = "occupied" flag, as OctoMap writes them).
template <bool kBuild>
void read_bt_node(Reader& r, OccupancyTree* tree, OccupancyNode* node, unsigned depth, Counts& c) {
  const auto lo = r.get<std::uint8_t>();
  const auto hi = r.get<std::uint8_t>();
  ++c.inner;
  bool inner[8] = {false};
  unsigned n_inner = 0;
  for (unsigned i = 0; i < 8; ++i) {
    const std::uint8_t bits = i < 4 ? lo : hi;
    const unsigned j = i % 4;
    const bool b0 = bits & (1u << (2 * j)), b1 = bits & (1u << (2 * j + 1));
    if (!b0 && !b1) continue;
    if (depth >= kMaxDepth) too_deep(r.path, depth);
    ++c.nodes;
    inner[i] = b0 && b1;
    n_inner += inner[i];
    if constexpr (kBuild) {
      OccupancyNode* child = tree->createNodeChild(node, i);
      if (!inner[i]) {
        child->setLogOdds(b0 ? tree->getClampingThresMinLog() : tree->getClampingThresMaxLog());
      }
    }
  }
  // every inner child needs a record of its own further on
  if (n_inner * kBtRecordBytes > r.left()) fail(r.path, "is truncated: the tree data ends early");
  for (unsigned i = 0; i < 8; ++i) {
    if (!inner[i]) continue;
    OccupancyNode* child = nullptr;
    if constexpr (kBuild) child = tree->getNodeChild(node, i);
    read_bt_node<kBuild>(r, tree, child, depth + 1, c);
    if constexpr (kBuild) child->setLogOdds(child->getMaxChildLogOdds());
  }
}

struct Header {
  std::string id;
  std::uint64_t size = 0;
  bool has_size = false;
  double res = 0.0;
  MapParams params;
};

double parse_double(const std::string& path, const std::string& key, const std::string& tok) {
  double v = 0.0;
  auto res = std::from_chars(tok.data(), tok.data() + tok.size(), v);
  if (res.ec != std::errc() || res.ptr != tok.data() + tok.size()) {
    fail(path, "has a bad header value for '" + key + "': '" + printable(tok) + "'");
  }
  return v;
}

std::uint64_t parse_count(const std::string& path, const std::string& key, const std::string& tok) {
  std::uint64_t v = 0;
  auto res = std::from_chars(tok.data(), tok.data() + tok.size(), v);
  if (res.ec != std::errc() || res.ptr != tok.data() + tok.size()) {
    fail(path, "has a bad header value for '" + key + "': '" + printable(tok) +
                   "' (expected a whole number of nodes)");
  }
  return v;
}

// Parses the text header; returns the offset of the binary data. Comment lines may hold any
// bytes; the other lines must be printable ASCII.
std::size_t parse_header(const std::string& path, const std::string& buf, std::size_t pos,
                         Header& h) {
  bool saw_data = false;
  unsigned line_no = 1;
  while (pos < buf.size()) {
    const std::size_t eol = buf.find('\n', pos);
    if (eol == std::string::npos) break;
    std::string line = buf.substr(pos, eol - pos);
    pos = eol + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (key.empty()) continue;
    if (key[0] == '#') {
      std::string word;
      ls >> word;
      if (word == "octofuse") {
        std::string k, v;
        while (ls >> k >> v) {
          if (k == "prob_hit")
            h.params.prob_hit = parse_double(path, k, v);
          else if (k == "prob_miss")
            h.params.prob_miss = parse_double(path, k, v);
          else if (k == "clamping_thres_min")
            h.params.clamp_min = parse_double(path, k, v);
          else if (k == "clamping_thres_max")
            h.params.clamp_max = parse_double(path, k, v);
        }
      }
      continue;
    }
    for (char ch : line) {
      const auto u = static_cast<unsigned char>(ch);
      if (u >= 127 || (u < 32 && ch != '\t')) {
        fail(path, "has a corrupt header: line " + std::to_string(line_no) + " ('" +
                       printable(line) + "') holds a byte that is not text");
      }
    }
    std::string val;
    ls >> val;
    if (key == "data") {
      saw_data = true;
      break;
    } else if (key == "id") {
      h.id = val;
    } else if (key == "res") {
      h.res = parse_double(path, key, val);
    } else if (key == "size") {
      h.size = parse_count(path, key, val);
      h.has_size = true;
    }
  }
  if (!saw_data) fail(path, "is truncated or corrupt: its header has no 'data' line");
  if (h.id == "1") h.id = "OcTree";  // deprecated id OctoMap still accepts
  if (h.id != "OcTree") {
    fail(path, "holds an octree of type '" + printable(h.id) +
                   "'; octofuse reads occupancy trees of type 'OcTree'");
  }
  if (!(h.res > 0.0) || !std::isfinite(h.res)) {
    fail(path, "has an invalid resolution: " + shortest(h.res));
  }
  h.params.resolution = h.res;
  try {
    h.params.validate();
  } catch (const std::invalid_argument& e) {
    fail(path, std::string("has invalid parameters: ") + e.what());
  }
  return pos;
}

std::size_t physical_memory() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return static_cast<std::size_t>(-1);
  return static_cast<std::size_t>(pages) * static_cast<std::size_t>(page);
}

// Refuses a tree that would need more than half of the machine's memory (nodes and child
// arrays as octofuse's pools store them).
void check_memory(const std::string& path, const Counts& c) {
  const double node = detail::NodePool::kBlock, children = detail::ChildrenPool::kBlock;
  const double need = node * static_cast<double>(c.nodes) + children * static_cast<double>(c.inner);
  const double have = static_cast<double>(physical_memory());
  if (need > 0.5 * have) {
    fail(path, "holds " + std::to_string(c.nodes) + " nodes, which need about " +
                   shortest(std::round(need / 1e8) / 10) +
                   " GB, more than half of this machine's " +
                   shortest(std::round(have / 1e8) / 10) + " GB");
  }
}

// The file's bytes, for regular files only (a FIFO or a device would block or never end), the
// first line checked before the rest is read.
std::string read_file(const std::string& path, bool& binary) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw MapFileError("cannot open map file '" + path + "': " + std::strerror(errno));
  }
  if (!S_ISREG(st.st_mode)) {
    const char* kind = S_ISDIR(st.st_mode)    ? "a directory"
                       : S_ISFIFO(st.st_mode) ? "a FIFO"
                       : S_ISCHR(st.st_mode)  ? "a character device"
                       : S_ISBLK(st.st_mode)  ? "a block device"
                       : S_ISSOCK(st.st_mode) ? "a socket"
                                              : "not a regular file";
    fail(path, std::string("is ") + kind + ", not a regular file");
  }
  const auto size = static_cast<std::size_t>(st.st_size);
  std::ifstream f(path, std::ios::binary);
  if (!f) throw MapFileError("cannot open map file '" + path + "': " + std::strerror(errno));
  std::string buf(std::min<std::size_t>(size, 64), '\0');
  f.read(&buf[0], static_cast<std::streamsize>(buf.size()));
  buf.resize(static_cast<std::size_t>(f.gcount()));
  const std::size_t eol = buf.find('\n');
  const std::string first = buf.substr(0, eol == std::string::npos ? buf.size() : eol);
  if (first.rfind(kBtHeader, 0) == 0) {
    binary = true;
  } else if (first.rfind(kOtHeader, 0) == 0) {
    binary = false;
  } else {
    throw MapFileError("'" + path + "' is not an OctoMap file: it starts with '" +
                       printable(first, 40) + "', expected '" + kOtHeader + "' (.ot) or '" +
                       kBtHeader + "' (.bt)");
  }
  if (size > physical_memory() / 2) {
    fail(path, "is " + std::to_string(size) + " bytes, more than half of this machine's memory");
  }
  const std::size_t head = buf.size();
  buf.resize(size);
  f.read(&buf[head], static_cast<std::streamsize>(size - head));
  buf.resize(head + static_cast<std::size_t>(f.gcount()));
  return buf;
}

std::string header_text(const char* first_line, const OccupancyTree& tree, const MapParams& p) {
  std::ostringstream s;
  s << first_line
    << "\n# (feel free to add / change comments, but leave the first line as it is!)\n"
    << "# octofuse prob_hit " << shortest(p.prob_hit) << " prob_miss " << shortest(p.prob_miss)
    << " clamping_thres_min " << shortest(p.clamp_min) << " clamping_thres_max "
    << shortest(p.clamp_max) << "\n#\n"
    << "id " << tree.getTreeType() << "\nsize " << tree.size() << "\nres "
    << shortest(tree.getResolution()) << "\ndata\n";
  return s.str();
}

bool ends_with(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

// Builds the map from a whole file or stream `buf` (first line already checked); `path` names
// it in messages.
std::unique_ptr<OccupancyMap> parse_map(const std::string& path, const std::string& buf,
                                        bool binary) {
  Header h;
  const std::size_t eol = buf.find('\n');
  const std::size_t data =
      parse_header(path, buf, eol == std::string::npos ? buf.size() : eol + 1, h);
  const Reader start{path, buf.data() + data, buf.data() + buf.size()};
  if (h.has_size && h.size == 0 && start.left() > 0) {
    fail(path, "is corrupt: its header says 0 nodes but " + std::to_string(start.left()) +
                   " bytes of tree data follow");
  }
  const bool has_tree = binary ? start.left() > 0 : (!h.has_size || h.size > 0);
  auto map = std::make_unique<OccupancyMap>(h.params);
  if (!has_tree) return map;
  if (!binary && h.has_size && h.size > start.left() / kOtNodeBytes) {
    fail(path, "is truncated or corrupt: its header says " + std::to_string(h.size) +
                   " nodes but its " + std::to_string(start.left()) +
                   " bytes of tree data hold at most " +
                   std::to_string(start.left() / kOtNodeBytes));
  }
  // check and count without allocating, then build
  Counts counts;
  Reader r = start;
  if (binary) {
    counts.nodes = 1;  // the root
    read_bt_node<false>(r, nullptr, nullptr, 0, counts);
  } else {
    read_ot_node<false>(r, nullptr, nullptr, 0, counts);
    if (h.has_size && counts.nodes != h.size) {
      fail(path, "is corrupt: its header says " + std::to_string(h.size) +
                     " nodes but the data holds " + std::to_string(counts.nodes));
    }
  }
  check_memory(path, counts);
  OccupancyTree& tree = map->settled_tree();
  OccupancyNode* root = OcTreeAccess::ensure_root(tree);
  Counts built;
  Reader b = start;
  if (binary) {
    read_bt_node<true>(b, &tree, root, 0, built);
    root->setLogOdds(root->getMaxChildLogOdds());
  } else {
    read_ot_node<true>(b, &tree, root, 0, built);
  }
  OcTreeAccess::mark_changed(tree);
  return map;
}

}  // namespace

std::unique_ptr<OccupancyMap> read_map_file(const std::string& path) {
  bool binary = false;
  const std::string buf = read_file(path, binary);
  return parse_map(path, buf, binary);
}

std::unique_ptr<OccupancyMap> read_map_stream(const std::string& bytes, const std::string& name) {
  const std::size_t eol = bytes.find('\n');
  const std::string first = bytes.substr(0, eol == std::string::npos ? bytes.size() : eol);
  bool binary = false;
  if (first.rfind(kBtHeader, 0) == 0) {
    binary = true;
  } else if (first.rfind(kOtHeader, 0) != 0) {
    throw MapFileError("'" + name + "' is not an OctoMap stream: it starts with '" +
                       printable(first, 40) + "', expected '" + kOtHeader + "' (.ot) or '" +
                       kBtHeader + "' (.bt)");
  }
  if (bytes.size() > physical_memory() / 2) {
    fail(name,
         "is " + std::to_string(bytes.size()) + " bytes, more than half of this machine's memory");
  }
  return parse_map(name, bytes, binary);
}

std::string write_map_stream(const OccupancyMap& map, bool binary) {
  std::ostringstream f(std::ios::binary);
  f << header_text(binary ? kBtHeader : kOtHeader, map.tree(), map.params());
  if (binary) {
    map.tree().writeBinaryData(f);
  } else {
    map.tree().writeData(f);
  }
  return f.str();
}

std::string write_tree_data(const OccupancyMap& map) {
  std::ostringstream f(std::ios::binary);
  if (map.tree().getRoot() != nullptr) map.tree().writeData(f);
  return f.str();
}

std::unique_ptr<OccupancyMap> read_tree_data(const std::string& data, const MapParams& params,
                                             const std::string& name) {
  params.validate();
  std::ostringstream s(std::ios::binary);
  s << kOtHeader << "\n# octofuse prob_hit " << shortest(params.prob_hit) << " prob_miss "
    << shortest(params.prob_miss) << " clamping_thres_min " << shortest(params.clamp_min)
    << " clamping_thres_max " << shortest(params.clamp_max) << "\nid OcTree\n";
  if (data.empty()) s << "size 0\n";
  s << "res " << shortest(params.resolution) << "\ndata\n" << data;
  return parse_map(name, s.str(), false);
}

void write_map_file(const OccupancyMap& map, const std::string& path) {
  const bool binary = ends_with(path, ".bt");
  const std::string tmp = path + ".octofuse-tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) {
      throw MapFileError("cannot write map file '" + path + "': " + std::strerror(errno));
    }
    f << header_text(binary ? kBtHeader : kOtHeader, map.tree(), map.params());
    if (binary) {
      map.tree().writeBinaryData(f);
    } else {
      map.tree().writeData(f);
    }
    f.flush();
    if (!f) {
      std::remove(tmp.c_str());
      throw MapFileError("writing map file '" + path + "' failed (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string err = std::strerror(errno);
    std::remove(tmp.c_str());
    throw MapFileError("cannot write map file '" + path + "': " + err);
  }
}

}  // namespace octofuse
