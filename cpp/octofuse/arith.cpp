// octofuse: log-odds arithmetic on whole maps (see arith.hpp).
#include "octofuse/arith.hpp"

#include <algorithm>
#include <stdexcept>

namespace octofuse {

void open_clamping(OccupancyMap& map) {
  // OctoMap stores logodds(p) as float: p = 0 and p = 1 give -inf and +inf.
  map.tree().setClampingThresMin(0.0);
  map.tree().setClampingThresMax(1.0);
}

void negate_values(OccupancyMap& map) {
  auto& t = map.tree();
  for (auto it = t.begin_tree(), end = t.end_tree(); it != end; ++it) {
    it->setLogOdds(-it->getLogOdds());
  }
  t.updateInnerOccupancy();
}

void clamp_values(OccupancyMap& map) {
  auto& t = map.tree();
  const float lo = t.getClampingThresMinLog();
  const float hi = t.getClampingThresMaxLog();
  for (auto it = t.begin_leafs(), end = t.end_leafs(); it != end; ++it) {
    const float v = it->getLogOdds();
    it->setLogOdds(std::min(std::max(v, lo), hi));
  }
  t.updateInnerOccupancy();
  t.prune();
}

std::size_t assign_values(OccupancyMap& map, OccupancyMap& channel, const OccupancyMap& msg) {
  check_compatible(map, msg);
  check_compatible(channel, msg);
  if (&map == &channel || &map == &msg || &channel == &msg) {
    throw std::invalid_argument("assign_values needs three different maps");
  }
  auto& tm = map.tree();
  auto& tc = channel.tree();
  const auto& src = msg.tree();
  const unsigned depth = src.getTreeDepth();
  std::size_t n = 0;
  auto one = [&](const octomap::OcTreeKey& k, float v) {
    const OccupancyNode* c = tc.search(k);
    const float old = c != nullptr ? c->getLogOdds() : 0.0f;
    tm.updateNode(k, v - old, true);
    tc.setNodeValue(k, v, true);
    ++n;
  };
  for (auto it = src.begin_leafs(), end = src.end_leafs(); it != end; ++it) {
    const float v = it->getLogOdds();
    const unsigned d = it.getDepth();
    if (d == depth) {
      one(it.getKey(), v);
      continue;
    }
    const octomap::OcTreeKey base = it.getIndexKey();
    const unsigned side = 1u << (depth - d);
    octomap::OcTreeKey k;
    for (unsigned x = 0; x < side; ++x) {
      for (unsigned y = 0; y < side; ++y) {
        for (unsigned z = 0; z < side; ++z) {
          k[0] = static_cast<octomap::key_type>(base[0] + x);
          k[1] = static_cast<octomap::key_type>(base[1] + y);
          k[2] = static_cast<octomap::key_type>(base[2] + z);
          one(k, v);
        }
      }
    }
  }
  tm.updateInnerOccupancy();
  tm.prune();
  tc.updateInnerOccupancy();
  tc.prune();
  return n;
}

}  // namespace octofuse
