// octofuse: leaves_with_values and scalar_values_and_depths.
#include "octofuse/leaf_lookup.hpp"

#include "walk.hpp"

#include <cmath>

namespace octofuse {

namespace {

/// The value of the leaf of `t` at `depth` whose cell is floor(centre / size) on every axis
/// (size: the edge of a node at `depth` over finest voxels of `resolution`), or false if `t`
/// has no leaf there.
bool leaf_at(const ScalarTree& t, double resolution, const double centre[3], unsigned depth,
             float& value) {
  const double size = resolution * std::ldexp(1.0, 16 - static_cast<int>(depth));
  if (depth == 0) {  // a root leaf: its centre lies in cell -1 on every axis
    const ScalarNode* root = t.getRoot();
    if (root == nullptr || t.nodeHasChildren(root)) return false;
    for (int a = 0; a < 3; ++a)
      if (std::floor(centre[a] / size) != -1.0) return false;
    value = root->getValue();
    return true;
  }
  const std::int64_t half = std::int64_t{1} << (depth - 1);  // the key of cell 0 at `depth`
  std::int64_t key[3];
  for (int a = 0; a < 3; ++a) {
    key[a] = static_cast<std::int64_t>(std::floor(centre[a] / size)) + half;
    if (key[a] < 0 || key[a] >= (std::int64_t{1} << depth)) return false;
  }
  const ScalarNode* n = t.getRoot();
  for (unsigned level = 0; level < depth; ++level) {
    if (n == nullptr || !t.nodeHasChildren(n)) return false;  // a coarser leaf, or unknown
    const unsigned bit = depth - 1 - level;
    const unsigned i =
        ((key[0] >> bit) & 1) | (((key[1] >> bit) & 1) << 1) | (((key[2] >> bit) & 1) << 2);
    if (!t.nodeChildExists(n, i)) return false;
    n = t.getNodeChild(n, i);
  }
  if (n == nullptr || t.nodeHasChildren(n)) return false;
  value = n->getValue();
  return true;
}

}  // namespace

LeafArrays leaves_with_values(const OccupancyMap& map, const ScalarTree& scalar, LeafClass which,
                              std::vector<float>& scalar_values) {
  std::uint32_t depths = 0;  // bit d: the scalar tree has leaves at depth d
  detail::for_each_leaf(scalar, [&](const ScalarNode&, const octomap::OcTreeKey&, unsigned d) {
    depths |= std::uint32_t{1} << d;
  });
  LeafArrays out;
  scalar_values.clear();
  const OccupancyTree& t = map.tree();
  detail::for_each_leaf(t, [&](const OccupancyNode& node, const octomap::OcTreeKey& k, unsigned d) {
    const float lo = node.getLogOdds();
    if (!of_class(lo, which)) return;
    const double centre[3] = {t.keyToCoord(k[0], d), t.keyToCoord(k[1], d), t.keyToCoord(k[2], d)};
    float v = 0.0f;
    bool found = false;
    for (unsigned sd = 0; sd <= 16; ++sd) {  // deeper hits win, as in the Python lookup
      float x;
      if ((depths >> sd & 1) && leaf_at(scalar, map.params().resolution, centre, sd, x)) {
        v = x;
        found = true;
      }
    }
    if (!found || !std::isfinite(v)) return;
    detail::append_leaf(out, t, k, d, lo);
    scalar_values.push_back(v);
  });
  return out;
}

void scalar_values_and_depths(const ScalarTree& tree, std::vector<float>& values,
                              std::vector<std::uint8_t>& depths) {
  const std::size_t n = tree.size();  // the node count the tree keeps: leaves and more
  values.clear();
  depths.clear();
  values.reserve(n);
  depths.reserve(n);
  detail::for_each_leaf(tree, [&](const ScalarNode& node, const octomap::OcTreeKey&, unsigned d) {
    values.push_back(node.getValue());
    depths.push_back(static_cast<std::uint8_t>(d));
  });
}

}  // namespace octofuse
