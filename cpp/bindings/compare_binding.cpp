// octofuse bindings: comparing maps, and the voxels that changed between two versions.
#include "common.hpp"

#include "octofuse/compare.hpp"

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
  m.def("_changed_voxels", [](const OccupancyMap& cur, const OccupancyMap& prev) {
    check_compatible(cur, prev);
    py::gil_scoped_release release;
    return changed_voxels(cur, prev);
  });
}

}  // namespace octofuse::bindings
