// octofuse: the voxels of a ray as Morton codes, the keys of OctoMap's computeRayKeys().
#pragma once

#include "octofuse/detail/key_codes.hpp"

#include <octomap/octomap_types.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>

namespace octofuse::detail {

// The bits of one axis in a Morton code (x: bits 0, 3, 6, ...); a constant, not worked out
// again at every step of a walk.
inline constexpr std::uint64_t kAxisBits = spread3(0xffff);
inline std::uint64_t axis_mask(unsigned axis) { return kAxisBits << axis; }

// The Morton code with one axis's key moved by `step` (+1, -1 or 0; the other axes' bits kept).
inline std::uint64_t morton_step(std::uint64_t m, std::uint64_t mask, int step) {
  const std::uint64_t moved = step > 0   ? ((m | ~mask) + 1) & mask
                              : step < 0 ? ((m & mask) - 1) & mask
                                         : m & mask;
  return moved | (m & ~mask);
}

// Calls emit(code) for the voxels a ray from `origin` to `end` passes through before the end's
// voxel, in ray order: the keys computeRayKeys() puts in its KeyRay, as Morton codes. It is
// OctoMap's 3D DDA (Amanatides & Woo) statement for statement, with the same float and double
// arithmetic, so the voxels are the same bit for bit (tested against computeRayKeys); what
// differs is that no KeyRay is filled and read back, and the code is stepped along one axis
// instead of interleaved anew for every key. Returns false where computeRayKeys() does (an
// endpoint outside the tree's key range). If `end_code` is given, it receives the code of the
// end's voxel (a scan's occupied voxel, found on the way), or kNoCode if that lies outside.
// A ray whose float length rounds to zero but whose end lies in another voxel makes OctoMap's
// loop run on past its buffer; ScanCheck refuses such rays before tracing, and here the walk
// stops after twice the key distance in any case.
template <class Tree, class Emit>
bool trace_ray_codes(const Tree& tree, const octomap::point3d& origin, const octomap::point3d& end,
                     Emit&& emit, std::uint64_t* end_code = nullptr) {
  octomap::OcTreeKey key_origin, key_end;
  const bool end_in_range = tree.coordToKeyChecked(end, key_end);
  const std::uint64_t code_end = end_in_range ? morton(key_end) : kNoCode;
  if (end_code != nullptr) *end_code = code_end;
  if (!tree.coordToKeyChecked(origin, key_origin) || !end_in_range) return false;
  if (key_origin == key_end) return true;
  std::uint64_t code = morton(key_origin);
  emit(code);

  octomap::point3d direction = (end - origin);
  const float length = static_cast<float>(direction.norm());
  direction /= length;
  const double resolution = tree.getResolution();
  int step[3];
  double t_max[3];
  double t_delta[3];
  long steps_left = 16;
  for (unsigned i = 0; i < 3; ++i) {
    steps_left += 2 * std::labs(static_cast<long>(key_end[i]) - static_cast<long>(key_origin[i]));
    if (direction(i) > 0.0) {
      step[i] = 1;
    } else if (direction(i) < 0.0) {
      step[i] = -1;
    } else {
      step[i] = 0;
    }
    if (step[i] != 0) {
      double voxel_border = tree.keyToCoord(key_origin[i]);
      voxel_border += static_cast<float>(step[i] * resolution * 0.5);
      t_max[i] = (voxel_border - origin(i)) / direction(i);
      t_delta[i] = resolution / std::fabs(direction(i));
    } else {
      t_max[i] = std::numeric_limits<double>::max();
      t_delta[i] = std::numeric_limits<double>::max();
    }
  }
  // the walk with each axis's t in a register of its own (an array indexed by the axis would
  // put every step's update through memory); the same comparisons and sums as OctoMap's
  double t0 = t_max[0], t1 = t_max[1], t2 = t_max[2];
  const auto advance = [&code](double& t, double delta, unsigned axis, int dir) {
    code = morton_step(code, axis_mask(axis), dir);
    t += delta;
  };
  while (--steps_left > 0) {
    if (t0 < t1) {
      if (t0 < t2) {
        advance(t0, t_delta[0], 0, step[0]);
      } else {
        advance(t2, t_delta[2], 2, step[2]);
      }
    } else if (t1 < t2) {
      advance(t1, t_delta[1], 1, step[1]);
    } else {
      advance(t2, t_delta[2], 2, step[2]);
    }
    if (code == code_end) break;
    // past the ray's length: rounding made the walk miss the end's voxel
    if (std::min(std::min(t0, t1), t2) > length) break;
    emit(code);
  }
  return true;
}

}  // namespace octofuse::detail
