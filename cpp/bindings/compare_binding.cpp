// octofuse bindings: comparing maps (with the points near a scene's box surfaces, for the
// occupied-voxel accuracy), and the voxels that changed between two versions.
#include "common.hpp"

#include "octofuse/box_surfaces.hpp"
#include "octofuse/compare.hpp"

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <utility>

namespace octofuse::bindings {

void define_compare(py::module_& m) {
  py::class_<ReferenceMap>(m, "_ReferenceMap",
                           "A map read once for comparisons (see _compare_maps); it holds "
                           "nothing of the map it was read from.")
      .def(py::init([](const OccupancyMap& ref) {
             py::gil_scoped_release release;
             return std::make_unique<ReferenceMap>(ref);
           }),
           py::arg("ref"))
      .def_property_readonly("num_nodes", [](const ReferenceMap& r) { return r.nodes().size(); })
      .def_property_readonly("nbytes", &ReferenceMap::memory_bytes);
  m.def(
      "_compare_maps",
      [](const ReferenceMap& ref, const OccupancyMap& map, double tol, double thr) {
        check_compatible(ref.grid(), map);
        Comparison c;
        {
          py::gil_scoped_release release;
          c = compare_maps(ref, map, tol, thr);
        }
        py::list conf;
        for (auto& row : c.confusion) conf.append(py::make_tuple(row[0], row[1], row[2]));
        py::dict d;
        d["confusion"] = conf;
        d["kl_sum"] = c.kl_sum;
        d["both_known"] = c.both_known;
        d["overconfident"] = c.overconfident;
        d["abs_diff_sum"] = c.abs_diff_sum;
        return d;
      },
      py::arg("ref"), py::arg("map"), py::arg("tol"), py::arg("occ_threshold") = 0.0,
      "Counts of `map` against the reference `ref` (a _ReferenceMap): class confusion, KL, "
      "|l| differences and over-confidence over finest voxels; the GIL is released.");
  m.def(
      "_near_box_surfaces",
      [](py::array_t<double, py::array::c_style | py::array::forcecast> points,
         py::array_t<double, py::array::c_style | py::array::forcecast> boxes, double tol) {
        if (points.ndim() != 2 || points.shape(1) != 3)
          throw py::value_error("near box surfaces: points must be an n x 3 array");
        if (boxes.ndim() != 3 || boxes.shape(1) != 2 || boxes.shape(2) != 3)
          throw py::value_error("near box surfaces: boxes must be a B x 2 x 3 array of corners");
        if (static_cast<std::uint64_t>(boxes.shape(0)) > std::numeric_limits<std::uint32_t>::max())
          throw py::value_error("near box surfaces: more than 2^32 boxes");
        if (!std::isfinite(tol) || tol < 0.0)
          throw py::value_error("near box surfaces: tol must be a finite distance >= 0");
        const double* b = boxes.data();
        for (py::ssize_t i = 0; i < boxes.size(); ++i)
          if (!std::isfinite(b[i]))
            throw py::value_error("near box surfaces: a box corner is not finite");
        const auto n = static_cast<std::size_t>(points.shape(0));
        py::array_t<bool> out(static_cast<py::ssize_t>(n));
        auto* o = reinterpret_cast<std::uint8_t*>(out.mutable_data());
        {
          py::gil_scoped_release release;
          near_box_surfaces(points.data(), n, b, static_cast<std::size_t>(boxes.shape(0)), tol, o);
        }
        return out;
      },
      py::arg("points"), py::arg("boxes"), py::arg("tol"),
      "Whether each point (n x 3) lies within `tol` of the surface of one of the boxes "
      "(B x 2 x 3: min and max corners); the GIL is released.");
  m.def("_changed_voxels", [](const OccupancyMap& cur, const OccupancyMap& prev) {
    check_compatible(cur, prev);
    py::gil_scoped_release release;
    return changed_voxels(cur, prev);
  });
  m.def(
      "_most_informative_voxels",
      [](const OccupancyMap& delta, const OccupancyMap& held, std::size_t max_nodes) {
        check_compatible(delta, held);
        std::size_t taken = 0;
        std::unique_ptr<OccupancyMap> out;
        {
          py::gil_scoped_release release;
          out = most_informative_voxels(delta, held, max_nodes, taken);
        }
        return py::make_tuple(std::move(out), taken);
      },
      py::arg("delta"), py::arg("held"), py::arg("max_nodes"),
      "The leaves of `delta` that change `held` most, as many as fit in `max_nodes` nodes, "
      "and how many were taken; the GIL is released.");
  m.def("_overlaid", [](const OccupancyMap& held, const OccupancyMap& delta) {
    check_compatible(held, delta);
    py::gil_scoped_release release;
    return overlaid(held, delta);
  });
}

}  // namespace octofuse::bindings
