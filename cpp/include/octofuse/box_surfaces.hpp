// octofuse: the points that lie near the surface of a scene of axis-aligned boxes (the
// ground truth of the occupied-voxel accuracy).
#pragma once

#include <cstddef>
#include <cstdint>

namespace octofuse {

/// Sets out[i] to 1 if point i (row i of the n x 3 array `points`) lies within `tol` of the
/// surface of one of the `nb` boxes (`boxes`: nb x 2 x 3, each box's min and max corner),
/// else to 0: in a box grown by tol, and either outside the box within tol of it (Euclidean
/// distance) or inside it within tol of a face. The arithmetic is that of
/// Scene.signed_distance (Python, numpy) in the same order, so the answers agree with
/// |signed_distance| <= tol bit for bit. Boxes and tol must be finite (the caller checks); a
/// point with a NaN is near nothing.
void near_box_surfaces(const double* points, std::size_t n, const double* boxes, std::size_t nb,
                       double tol, std::uint8_t* out);

}  // namespace octofuse
