// octofuse: OccupancyMap, the adapter around octomap::OcTree.
#include "octofuse/occupancy_map.hpp"

#include "octofuse/tree_access.hpp"


#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

namespace octofuse {

namespace {

const char* const kOtHeader = "# Octomap OcTree file";
const char* const kBtHeader = "# Octomap OcTree binary file";
constexpr unsigned kMaxDepth = 16;

std::string shortest(double v) {
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, res.ptr);
}

bool ends_with(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

/// Cursor over the binary data section of a map file with bounds checks.
struct Reader {
  const std::string& path;
  const char* p;
  const char* end;

  [[noreturn]] void truncated() const {
    throw MapFileError("map file '" + path + "' is truncated: the tree data ends early");
  }
  template <class T>
  T get() {
    if (static_cast<std::size_t>(end - p) < sizeof(T)) truncated();
    T v;
    std::memcpy(&v, p, sizeof(T));
    p += sizeof(T);
    return v;
  }
};

using OcTreeAccess = detail::TreeAccess<octomap::OcTree>;

// Full format: value (float) + children mask (1 byte) per node, depth first.
void read_ot_node(Reader& r, octomap::OcTree& tree, octomap::OcTreeNode* node, unsigned depth,
                  std::size_t& count) {
  const float value = r.get<float>();
  if (!std::isfinite(value)) {
    throw MapFileError("map file '" + r.path + "' holds a non-finite log-odds value (" +
                       std::to_string(value) + "): the file is corrupt");
  }
  node->setLogOdds(value);
  ++count;
  const auto mask = r.get<std::uint8_t>();
  if (mask != 0 && depth >= kMaxDepth) {
    throw MapFileError("map file '" + r.path + "' is corrupt: a node at depth " +
                       std::to_string(depth) + " has children (OcTree depth is 16)");
  }
  for (unsigned i = 0; i < 8; ++i) {
    if (mask & (1u << i)) {
      read_ot_node(r, tree, tree.createNodeChild(node, i), depth + 1, count);
    }
  }
}

// Binary format: 2 bits per child: 01 free leaf, 10 occupied leaf, 11 inner, 00 unknown
// (bit 2i set = "free" flag, bit 2i+1 = "occupied" flag, as OctoMap writes them).
void read_bt_node(Reader& r, octomap::OcTree& tree, octomap::OcTreeNode* node, unsigned depth) {
  const auto lo = r.get<std::uint8_t>();
  const auto hi = r.get<std::uint8_t>();
  const float fmin = tree.getClampingThresMinLog(), fmax = tree.getClampingThresMaxLog();
  bool inner[8] = {false};
  for (unsigned i = 0; i < 8; ++i) {
    const std::uint8_t bits = i < 4 ? lo : hi;
    const unsigned j = i % 4;
    const bool b0 = bits & (1u << (2 * j)), b1 = bits & (1u << (2 * j + 1));
    if (!b0 && !b1) continue;
    if (depth >= kMaxDepth) {
      throw MapFileError("map file '" + r.path + "' is corrupt: a node at depth " +
                         std::to_string(depth) + " has children (OcTree depth is 16)");
    }
    octomap::OcTreeNode* child = tree.createNodeChild(node, i);
    if (b0 && b1) {
      inner[i] = true;
    } else {
      child->setLogOdds(b0 ? fmin : fmax);
    }
  }
  for (unsigned i = 0; i < 8; ++i) {
    if (!inner[i]) continue;
    octomap::OcTreeNode* child = tree.getNodeChild(node, i);
    read_bt_node(r, tree, child, depth + 1);
    child->setLogOdds(child->getMaxChildLogOdds());
  }
}

struct Header {
  std::string id;
  std::size_t size = 0;
  double res = 0.0;
  bool has_size = false;
  MapParams params;
};

double parse_double(const std::string& path, const std::string& key, const std::string& tok) {
  double v = 0.0;
  auto res = std::from_chars(tok.data(), tok.data() + tok.size(), v);
  if (res.ec != std::errc() || res.ptr != tok.data() + tok.size()) {
    throw MapFileError("map file '" + path + "' has a bad header value for '" + key +
                       "': '" + tok + "'");
  }
  return v;
}

// Parses the text header; returns the offset of the binary data.
std::size_t parse_header(const std::string& path, const std::string& buf, std::size_t pos,
                         Header& h) {
  bool saw_data = false;
  while (pos < buf.size()) {
    const std::size_t eol = buf.find('\n', pos);
    if (eol == std::string::npos) break;
    std::string line = buf.substr(pos, eol - pos);
    pos = eol + 1;
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
          if (k == "prob_hit") h.params.prob_hit = parse_double(path, k, v);
          else if (k == "prob_miss") h.params.prob_miss = parse_double(path, k, v);
          else if (k == "clamping_thres_min") h.params.clamp_min = parse_double(path, k, v);
          else if (k == "clamping_thres_max") h.params.clamp_max = parse_double(path, k, v);
        }
      }
      continue;
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
      h.size = static_cast<std::size_t>(parse_double(path, key, val));
      h.has_size = true;
    }
  }
  if (!saw_data) {
    throw MapFileError("map file '" + path + "' is truncated or corrupt: its header has no 'data' line");
  }
  if (h.id == "1") h.id = "OcTree";  // deprecated id OctoMap still accepts
  if (h.id != "OcTree") {
    throw MapFileError("map file '" + path + "' holds an octree of type '" + h.id +
                       "'; octofuse reads occupancy trees of type 'OcTree'");
  }
  if (!(h.res > 0.0) || !std::isfinite(h.res)) {
    throw MapFileError("map file '" + path + "' has an invalid resolution: " + shortest(h.res));
  }
  h.params.resolution = h.res;
  return pos;
}

std::string header_text(const char* first_line, const octomap::OcTree& tree, const MapParams& p) {
  std::ostringstream s;
  s << first_line << "\n# (feel free to add / change comments, but leave the first line as it is!)\n"
    << "# octofuse prob_hit " << shortest(p.prob_hit) << " prob_miss " << shortest(p.prob_miss)
    << " clamping_thres_min " << shortest(p.clamp_min) << " clamping_thres_max "
    << shortest(p.clamp_max) << "\n#\n"
    << "id " << tree.getTreeType() << "\nsize " << tree.size() << "\nres "
    << shortest(tree.getResolution()) << "\ndata\n";
  return s.str();
}

template <class Tree>
LeafArrays collect_leaves(const Tree& tree) {
  LeafArrays out;
  const std::size_t n = tree.getNumLeafNodes();
  out.centers.reserve(3 * n);
  out.sizes.reserve(n);
  out.values.reserve(n);
  out.depths.reserve(n);
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const octomap::OcTreeKey& k = it.getKey();
    const unsigned d = it.getDepth();
    for (int a = 0; a < 3; ++a) out.centers.push_back(tree.keyToCoord(k[a], d));
    out.sizes.push_back(it.getSize());
    out.values.push_back(it->getValue());
    out.depths.push_back(static_cast<std::uint8_t>(d));
  }
  return out;
}

}  // namespace

void MapParams::validate() const {
  auto bad = [](const std::string& what, double v, const std::string& expected) {
    throw std::invalid_argument(what + " = " + shortest(v) + ": expected " + expected);
  };
  if (!(resolution > 0.0) || !std::isfinite(resolution)) bad("resolution", resolution, "a positive number of metres");
  if (!(prob_hit > 0.5 && prob_hit < 1.0)) bad("prob_hit", prob_hit, "a probability in (0.5, 1)");
  if (!(prob_miss > 0.0 && prob_miss < 0.5)) bad("prob_miss", prob_miss, "a probability in (0, 0.5)");
  if (!(clamp_min > 0.0 && clamp_min < 0.5)) bad("clamping min", clamp_min, "a probability in (0, 0.5)");
  if (!(clamp_max > 0.5 && clamp_max < 1.0)) bad("clamping max", clamp_max, "a probability in (0.5, 1)");
}

OccupancyMap::OccupancyMap(const MapParams& params) : params_(params) {
  params_.validate();
  tree_ = std::make_unique<octomap::OcTree>(params_.resolution);
  tree_->setProbHit(params_.prob_hit);
  tree_->setProbMiss(params_.prob_miss);
  tree_->setClampingThresMin(params_.clamp_min);
  tree_->setClampingThresMax(params_.clamp_max);
}

OccupancyMap::OccupancyMap(const OccupancyMap& other)
    : params_(other.params_), tree_(std::make_unique<octomap::OcTree>(*other.tree_)) {
  tree_->setProbHit(params_.prob_hit);
  tree_->setProbMiss(params_.prob_miss);
  tree_->setClampingThresMin(params_.clamp_min);
  tree_->setClampingThresMax(params_.clamp_max);
}

void OccupancyMap::save(const std::string& path) const {
  const bool binary = ends_with(path, ".bt");
  const std::string tmp = path + ".octofuse-tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) {
      throw MapFileError("cannot write map file '" + path + "': " + std::strerror(errno));
    }
    f << header_text(binary ? kBtHeader : kOtHeader, *tree_, params_);
    if (binary) {
      tree_->writeBinaryData(f);
    } else {
      tree_->writeData(f);
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

std::unique_ptr<OccupancyMap> OccupancyMap::load(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) {
    throw MapFileError("cannot open map file '" + path + "': " + std::strerror(errno));
  }
  std::string buf((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const std::size_t eol = buf.find('\n');
  const std::string first = buf.substr(0, eol == std::string::npos ? std::min<std::size_t>(buf.size(), 60) : eol);
  bool binary;
  if (first.rfind(kBtHeader, 0) == 0) {
    binary = true;
  } else if (first.rfind(kOtHeader, 0) == 0) {
    binary = false;
  } else {
    std::string shown;
    for (char c : first.substr(0, 40)) shown += (c >= 32 && c < 127) ? c : '?';
    throw MapFileError("'" + path + "' is not an OctoMap file: it starts with '" + shown +
                       "', expected '" + kOtHeader + "' (.ot) or '" + kBtHeader + "' (.bt)");
  }
  Header h;
  const std::size_t data = parse_header(path, buf, eol == std::string::npos ? buf.size() : eol + 1, h);
  try {
    h.params.validate();
  } catch (const std::invalid_argument& e) {
    throw MapFileError("map file '" + path + "' has invalid parameters: " + e.what());
  }
  auto map = std::make_unique<OccupancyMap>(h.params);
  Reader r{path, buf.data() + data, buf.data() + buf.size()};
  if (binary) {
    if (r.p < r.end) {
      octomap::OcTreeNode* root = OcTreeAccess::ensure_root(*map->tree_);
      read_bt_node(r, *map->tree_, root, 0);
      root->setLogOdds(root->getMaxChildLogOdds());
    }
  } else if (!h.has_size || h.size > 0) {
    octomap::OcTreeNode* root = OcTreeAccess::ensure_root(*map->tree_);
    std::size_t count = 0;
    read_ot_node(r, *map->tree_, root, 0, count);
    if (h.has_size && count != h.size) {
      throw MapFileError("map file '" + path + "' is corrupt: its header says " +
                         std::to_string(h.size) + " nodes but the data holds " +
                         std::to_string(count));
    }
  }
  OcTreeAccess::mark_changed(*map->tree_);
  return map;
}

LeafArrays OccupancyMap::leaves() const { return collect_leaves(*tree_); }
LeafArrays scalar_leaves(const ScalarTree& tree) { return collect_leaves(tree); }

}  // namespace octofuse
