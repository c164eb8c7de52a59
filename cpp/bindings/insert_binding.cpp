// octofuse bindings: batched scan insertion.
#include "common.hpp"

#include "octofuse/insert.hpp"

#include <pybind11/stl.h>

#include <algorithm>
#include <string>
#include <vector>

namespace octofuse::bindings {

void define_insert(py::module_& m) {
  m.attr("MAX_THREADS") = kMaxThreads;
  m.def("default_threads", &default_threads,
        "The machine's hardware threads (1 to MAX_THREADS): the default thread count.");
  m.def(
      "_insert_batch",
      [](const std::vector<std::vector<OccupancyMap*>>& targets, const py::list& points,
         py::array_t<double, py::array::c_style | py::array::forcecast> poses,
         py::array_t<double, py::array::c_style | py::array::forcecast> max_ranges,
         int threads) {
        if (threads < 1 || threads > static_cast<int>(kMaxThreads)) {
          throw py::value_error("threads = " + std::to_string(threads) + ": expected 1 to " +
                                std::to_string(kMaxThreads));
        }
        const std::size_t n = targets.size();
        if (points.size() != n || poses.ndim() != 3 || static_cast<std::size_t>(poses.shape(0)) != n ||
            poses.shape(1) != 4 || poses.shape(2) != 4 ||
            static_cast<std::size_t>(max_ranges.size()) != n) {
          throw py::value_error("insert batch: targets, points, poses (S,4,4) and max_ranges (S,) must agree");
        }
        std::vector<ScanInput> scans(n);
        std::vector<py::array> keep;
        keep.reserve(n);
        for (std::size_t i = 0; i < n; ++i) {
          py::array a = py::reinterpret_borrow<py::array>(points[i]);
          const bool dbl = py::isinstance<py::array_t<double>>(a);
          if (!(dbl || py::isinstance<py::array_t<float>>(a)) || a.ndim() != 2 || a.shape(1) != 3 ||
              !(a.flags() & py::array::c_style)) {
            throw py::value_error("insert batch: scan " + std::to_string(i) +
                                  " points must be a C-contiguous (N, 3) float32/float64 array");
          }
          ScanInput& s = scans[i];
          s.xyz = a.data();
          s.is_double = dbl;
          s.n = static_cast<std::size_t>(a.shape(0));
          std::copy(poses.data() + 16 * i, poses.data() + 16 * (i + 1), s.pose);
          s.max_range = max_ranges.data()[i];
          s.targets = targets[i];
          for (OccupancyMap* m : s.targets) {
            if (m == nullptr) throw py::value_error("insert batch: a target map is None");
            check_compatible(*m, *s.targets.front());
          }
          keep.push_back(a);
        }
        py::gil_scoped_release release;
        insert_batch(scans, static_cast<unsigned>(threads));
      },
      py::arg("targets"), py::arg("points"), py::arg("poses"), py::arg("max_ranges"),
      py::arg("threads") = static_cast<int>(default_threads()),
      "Insert a batch of sensor-frame scans into their target maps (ray keys computed once "
      "per scan, in parallel); the GIL is released. threads: 1 to MAX_THREADS, by default "
      "the machine's hardware threads. ValueError naming the scan and point row if a ray "
      "cannot be traced (non-finite, outside the map's extent, or too long); no map changes "
      "then.");
}

}  // namespace octofuse::bindings
