// octofuse: points near box surfaces, each point tested against the boxes of its cell in a
// grid of x-y cells over the grown boxes (a floor and the walls reach every cell, a shelf a
// few).
#include "octofuse/box_surfaces.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace octofuse {

namespace {

// Cells along one axis over [lo, hi]: a coordinate's cell, monotonic in the coordinate, so a
// point inside a grown box lies in one of the cells that the box's grown extent spans.
struct Axis {
  double lo, width;
  int cells;
  Axis(double lo_, double hi_, int cells_) : lo(lo_), width((hi_ - lo_) / cells_), cells(cells_) {
    if (!(width > 0.0) || !std::isfinite(width)) cells = 1;
  }
  int cell(double x) const {
    if (cells == 1) return 0;
    const double c = std::floor((x - lo) / width);
    return c < 0.0 ? 0 : (c >= cells ? cells - 1 : static_cast<int>(c));
  }
};

// Whether q lies within tol of the surface of the box [lo, hi], as Scene.signed_distance
// computes it in numpy:
// outside = |max(lo - q, q - hi, 0)| (the squares summed x, y, z), depth = min(q - lo, hi - q).
bool near_box(const double* q, const double* lo, const double* hi, double tol) {
  for (int k = 0; k < 3; ++k)
    if (!(q[k] >= lo[k] - tol && q[k] <= hi[k] + tol)) return false;
  double d[3], depth = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double below = lo[k] - q[k], above = q[k] - hi[k];
    d[k] = std::max(std::max(below, above), 0.0);
    const double in = std::min(q[k] - lo[k], hi[k] - q[k]);
    depth = k == 0 ? in : std::min(depth, in);
  }
  const double sq0 = d[0] * d[0], sq1 = d[1] * d[1], sq2 = d[2] * d[2];
  const double outside = std::sqrt((sq0 + sq1) + sq2);
  return outside > 0.0 ? outside <= tol : depth <= tol;
}

}  // namespace

void near_box_surfaces(const double* points, std::size_t n, const double* boxes, std::size_t nb,
                       double tol, std::uint8_t* out) {
  std::fill(out, out + n, std::uint8_t{0});
  if (nb == 0) return;
  double x0 = boxes[0] - tol, x1 = boxes[3] + tol, y0 = boxes[1] - tol, y1 = boxes[4] + tol;
  for (std::size_t b = 1; b < nb; ++b) {
    const double* lo = boxes + 6 * b;
    const double* hi = lo + 3;
    x0 = std::min(x0, lo[0] - tol), x1 = std::max(x1, hi[0] + tol);
    y0 = std::min(y0, lo[1] - tol), y1 = std::max(y1, hi[1] + tol);
  }
  const int per_axis = std::clamp(2 * static_cast<int>(std::ceil(std::sqrt(double(nb)))), 1, 64);
  const Axis ax(x0, x1, per_axis), ay(y0, y1, per_axis);
  // the boxes of each cell, cell by cell: counted, then placed
  const auto for_cells = [&](std::size_t b, auto&& f) {
    const double* lo = boxes + 6 * b;
    const double* hi = lo + 3;
    for (int cy = ay.cell(lo[1] - tol); cy <= ay.cell(hi[1] + tol); ++cy)
      for (int cx = ax.cell(lo[0] - tol); cx <= ax.cell(hi[0] + tol); ++cx)
        f(static_cast<std::size_t>(cy * ax.cells + cx));
  };
  std::vector<std::size_t> first(static_cast<std::size_t>(ax.cells * ay.cells) + 1, 0);
  for (std::size_t b = 0; b < nb; ++b) for_cells(b, [&](std::size_t c) { ++first[c + 1]; });
  for (std::size_t c = 1; c < first.size(); ++c) first[c] += first[c - 1];
  std::vector<std::uint32_t> in_cell(first.back());
  std::vector<std::size_t> next(first.begin(), first.end() - 1);
  for (std::size_t b = 0; b < nb; ++b)
    for_cells(b, [&](std::size_t c) { in_cell[next[c]++] = static_cast<std::uint32_t>(b); });
  for (std::size_t i = 0; i < n; ++i) {
    const double* q = points + 3 * i;
    if (!(q[0] >= x0 && q[0] <= x1 && q[1] >= y0 && q[1] <= y1)) continue;  // and NaN
    const std::size_t c = static_cast<std::size_t>(ay.cell(q[1]) * ax.cells + ax.cell(q[0]));
    for (std::size_t k = first[c]; k < first[c + 1]; ++k) {
      const double* lo = boxes + 6 * in_cell[k];
      if (near_box(q, lo, lo + 3, tol)) {
        out[i] = 1;
        break;
      }
    }
  }
}

}  // namespace octofuse
