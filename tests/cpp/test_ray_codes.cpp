// trace_ray_codes() against OctoMap's computeRayKeys(): the same voxels, in the same order.
#include "octofuse/detail/ray_codes.hpp"

#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

namespace {

using octofuse::detail::morton;
using octofuse::detail::trace_ray_codes;
using octomap::point3d;

// Compares one ray both ways; returns the number of voxels it passes through.
std::size_t expect_same_ray(const octomap::OcTree& tree, const point3d& o, const point3d& e) {
  octomap::KeyRay ray;
  const bool octomap_ok = tree.computeRayKeys(o, e, ray);
  std::vector<std::uint64_t> expected;
  for (const auto& k : ray) expected.push_back(morton(k));
  std::vector<std::uint64_t> got;
  std::uint64_t end_code = 0;  // the tracer always sets it
  const bool ok = trace_ray_codes(
      tree, o, e, [&got](std::uint64_t c) { got.push_back(c); }, &end_code);
  EXPECT_EQ(ok, octomap_ok) << o << " -> " << e;
  octomap::OcTreeKey end_key;
  EXPECT_EQ(end_code,
            tree.coordToKeyChecked(e, end_key) ? morton(end_key) : octofuse::detail::kNoCode)
      << "the end's voxel of " << o << " -> " << e;
  EXPECT_EQ(got, expected) << o << " -> " << e << " at resolution " << tree.getResolution();
  return got.size();
}

TEST(RayCodes, RandomRaysAtSeveralResolutions) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> pos(-20.0f, 20.0f);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  std::uniform_real_distribution<float> log_len(-4.0f, 1.5f);
  std::size_t voxels = 0;
  for (double res : {0.05, 0.1, 0.137, 1.0}) {
    octomap::OcTree tree(res);
    for (int i = 0; i < 4000; ++i) {
      const point3d o(pos(rng), pos(rng), pos(rng));
      const point3d dir = point3d(unit(rng), unit(rng), unit(rng)).normalized();
      const point3d e = o + dir * std::pow(10.0f, log_len(rng));
      voxels += expect_same_ray(tree, o, e);
    }
  }
  EXPECT_GT(voxels, 100000u);  // the rays cross many voxels, not only their own
}

TEST(RayCodes, RaysOnVoxelFacesAlongAxesAndDiagonals) {
  std::mt19937_64 rng(11);
  std::uniform_int_distribution<int> cell(-200, 200);
  std::uniform_int_distribution<int> pick(0, 5);
  const double res = 0.05;
  octomap::OcTree tree(res);
  const auto on_grid = [&](int k, int how) {
    // a voxel face, a voxel centre, or a hair beside a face
    const float face = static_cast<float>(k * res);
    if (how == 0) return face;
    if (how == 1) return static_cast<float>((k + 0.5) * res);
    return std::nextafter(face, how == 2 ? 1e9f : -1e9f);
  };
  for (int i = 0; i < 20000; ++i) {
    const point3d o(on_grid(cell(rng), pick(rng) % 4), on_grid(cell(rng), pick(rng) % 4),
                    on_grid(cell(rng), pick(rng) % 4));
    point3d e(on_grid(cell(rng), pick(rng) % 4), on_grid(cell(rng), pick(rng) % 4),
              on_grid(cell(rng), pick(rng) % 4));
    switch (pick(rng)) {  // axis-parallel, planar and exactly diagonal rays
      case 0:
        e.y() = o.y();
        e.z() = o.z();
        break;
      case 1:
        e.z() = o.z();
        break;
      case 2: {
        const float d = e.x() - o.x();
        e.y() = o.y() + d;
        e.z() = o.z() - d;
        break;
      }
      default:
        break;
    }
    expect_same_ray(tree, o, e);
  }
}

TEST(RayCodes, EndsWhereTheWalkReachesTheRaysLengthExactly) {
  // At resolutions a binary float holds exactly, a ray from a voxel centre to a voxel face
  // along an axis (or a diagonal) reaches a voxel border at exactly its length: OctoMap keeps
  // the voxel before the end's (its test is "past the length", not "at it")
  std::size_t voxels = 0;
  for (double res : {1.0, 0.5, 0.25, 0.125}) {
    octomap::OcTree tree(res);
    const auto centre = [res](int k) { return static_cast<float>((k + 0.5) * res); };
    const auto face = [res](int k) { return static_cast<float>(k * res); };
    for (int k0 : {-7, -1, 0, 3}) {
      for (int n : {1, 2, 5, 40}) {
        for (int dir : {1, -1}) {
          const float o = centre(k0), e = face(dir > 0 ? k0 + n + 1 : k0 - n);
          voxels += expect_same_ray(tree, point3d(o, 0.3f, -0.2f), point3d(e, 0.3f, -0.2f));
          voxels += expect_same_ray(tree, point3d(0.1f, o, 0.7f), point3d(0.1f, e, 0.7f));
          voxels += expect_same_ray(tree, point3d(-0.4f, 1.1f, o), point3d(-0.4f, 1.1f, e));
          voxels += expect_same_ray(tree, point3d(o, o, 0.0f), point3d(e, e, 0.0f));
        }
      }
    }
  }
  EXPECT_GT(voxels, 1000u);
}

TEST(RayCodes, EndpointsOutsideTheTreeAndInOneVoxel) {
  octomap::OcTree tree(0.05);
  expect_same_ray(tree, point3d(0, 0, 0), point3d(5000.0f, 0, 0));  // outside: false
  expect_same_ray(tree, point3d(-5000.0f, 0, 0), point3d(1.0f, 0, 0));
  expect_same_ray(tree, point3d(0.01f, 0.01f, 0.01f), point3d(0.02f, 0.02f, 0.02f));  // one voxel
  expect_same_ray(tree, point3d(1.0f, 2.0f, 3.0f), point3d(1.0f, 2.0f, 3.0f));
  // long rays (within KeyRay's 100,000 keys, past which OctoMap's own tracing overflows)
  expect_same_ray(tree, point3d(-1000.0f, 0.3f, -0.2f), point3d(1000.0f, 0.1f, 0.4f));
  expect_same_ray(tree, point3d(-600.0f, -600.0f, -600.0f), point3d(600.0f, 600.0f, 599.0f));
}

TEST(RayCodes, MortonStepMovesOneAxisOnly) {
  for (unsigned axis = 0; axis < 3; ++axis) {
    const std::uint64_t mask = octofuse::detail::axis_mask(axis);
    for (unsigned a : {0u, 1u, 255u, 256u, 32767u, 32768u, 65534u}) {
      octomap::OcTreeKey k(1234, 40000, 7);
      k[axis] = static_cast<octomap::key_type>(a);
      octomap::OcTreeKey up = k, down = k;
      up[axis] = static_cast<octomap::key_type>(a + 1);
      EXPECT_EQ(octofuse::detail::morton_step(morton(k), mask, 1), morton(up));
      EXPECT_EQ(octofuse::detail::morton_step(morton(k), mask, 0), morton(k));
      if (a > 0) {
        down[axis] = static_cast<octomap::key_type>(a - 1);
        EXPECT_EQ(octofuse::detail::morton_step(morton(k), mask, -1), morton(down));
      }
    }
  }
}

TEST(RayCodes, SortCodesSortsLikeStdSort) {
  std::mt19937_64 rng(3);
  for (std::size_t n : {0u, 1u, 255u, 256u, 1000u, 70000u}) {
    for (std::uint64_t spread :
         {std::uint64_t{1} << 48, std::uint64_t{1} << 20, std::uint64_t{300}}) {
      // codes of a narrow region (most bytes shared, the passes skipped) and of the whole range
      const std::uint64_t room = (std::uint64_t{1} << 48) - spread;
      const std::uint64_t base = room == 0 ? 0 : rng() % room;
      std::vector<std::uint64_t> v(n);
      for (auto& c : v) c = base + rng() % spread;
      std::vector<std::uint64_t> expected = v;
      std::sort(expected.begin(), expected.end());
      octofuse::detail::sort_codes(v);
      EXPECT_EQ(v, expected) << n << " codes within " << spread;
    }
  }
}

}  // namespace
