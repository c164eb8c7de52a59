// octofuse bindings: batched scan insertion.
#include "common.hpp"

#include "octofuse/insert.hpp"

#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
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
         int threads, const std::vector<bool>& map_frame) {
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
        if (!map_frame.empty() && map_frame.size() != n) {
          throw py::value_error("insert batch: map_frame must have one flag per scan");
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
          s.map_frame = !map_frame.empty() && map_frame[i];
          for (OccupancyMap* m : s.targets) {
            if (m == nullptr) throw py::value_error("insert batch: a target map is None");
            check_same_grid(*m, *s.targets.front());  // clamping and sensor model: per map
          }
          keep.push_back(a);
        }
        py::gil_scoped_release release;
        insert_batch(scans, static_cast<unsigned>(threads));
      },
      py::arg("targets"), py::arg("points"), py::arg("poses"), py::arg("max_ranges"),
      py::arg("threads") = static_cast<int>(default_threads()),
      py::arg("map_frame") = std::vector<bool>{},
      "Insert a batch of sensor-frame scans into their target maps (ray keys computed once "
      "per scan, in parallel); the GIL is released. threads: 1 to MAX_THREADS, by default "
      "the machine's hardware threads. ValueError naming the scan and point row if a ray "
      "cannot be traced (non-finite, outside the map's extent, or too long); no map changes "
      "then. map_frame: per scan, True if its points are in the map frame (the pose's "
      "translation is then the sensor origin and its rotation is not used).");

  m.def(
      "_insert_scan_batched",
      [](OccupancyMap& map, py::array points,
         py::array_t<double, py::array::c_style | py::array::forcecast> origin, double max_range) {
        const bool dbl = py::isinstance<py::array_t<double>>(points);
        if (!(dbl || py::isinstance<py::array_t<float>>(points)) || points.ndim() != 2 ||
            points.shape(1) != 3 || !(points.flags() & py::array::c_style)) {
          throw py::value_error("points must be a C-contiguous (N, 3) float32/float64 array");
        }
        if (origin.size() != 3) throw py::value_error("origin must have 3 values");
        const double o[3] = {origin.data()[0], origin.data()[1], origin.data()[2]};
        for (double v : o)
          if (!std::isfinite(v)) throw py::value_error("origin is not finite");
        const std::size_t n = static_cast<std::size_t>(points.shape(0));
        const void* p = points.data();
        py::gil_scoped_release release;
        if (dbl) {
          insert_scan_batched(map, static_cast<const double*>(p), n, o, max_range);
        } else {
          insert_scan_batched(map, static_cast<const float*>(p), n, o, max_range);
        }
      },
      py::arg("map"), py::arg("points"), py::arg("origin"), py::arg("max_range"),
      "Insert one map-frame scan into one map by the depth-first batch path: the same map as "
      "insert_scan (OctoMap's insertPointCloud); the GIL is released.");
}

}  // namespace octofuse::bindings
