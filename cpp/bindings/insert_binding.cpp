// octofuse bindings: batched scan insertion.
#include "common.hpp"

#include "octofuse/insert.hpp"
#include "octofuse/insert_fast.hpp"

#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace octofuse::bindings {

namespace {

using Poses = py::array_t<double, py::array::c_style | py::array::forcecast>;

void check_thread_count(int threads) {
  if (threads < 1 || threads > static_cast<int>(kMaxThreads)) {
    throw py::value_error("threads = " + std::to_string(threads) + ": expected 1 to " +
                          std::to_string(kMaxThreads));
  }
}

/// The scans of a batch, checked (targets left empty); `keep` holds their point arrays.
std::vector<ScanInput> scan_inputs(const py::list& points, const Poses& poses,
                                   const Poses& max_ranges, const std::vector<bool>& map_frame,
                                   std::vector<py::array>& keep) {
  const std::size_t n = points.size();
  if (poses.ndim() != 3 || static_cast<std::size_t>(poses.shape(0)) != n || poses.shape(1) != 4 ||
      poses.shape(2) != 4 || static_cast<std::size_t>(max_ranges.size()) != n) {
    throw py::value_error("insert batch: points, poses (S,4,4) and max_ranges (S,) must agree");
  }
  if (!map_frame.empty() && map_frame.size() != n) {
    throw py::value_error("insert batch: map_frame must have one flag per scan");
  }
  std::vector<ScanInput> scans(n);
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
    s.map_frame = !map_frame.empty() && map_frame[i];
    keep.push_back(a);
  }
  return scans;
}

/// Checks that every map of a scan's targets is on the grid of the first (clamping and
/// sensor model: per map).
void check_targets(const std::vector<OccupancyMap*>& maps) {
  for (OccupancyMap* m : maps) {
    if (m == nullptr) throw py::value_error("insert batch: a target map is None");
    check_same_grid(*m, *maps.front());
  }
}

/// The fast mode's parameters for `mode` ("exact": none), or ValueError.
const FastInsert* fast_mode(const std::string& mode, FastInsert& opt) {
  try {
    if (parse_insert_mode(mode) == InsertMode::Exact) return nullptr;
    opt.validate();
  } catch (const std::invalid_argument& e) {
    throw py::value_error(e.what());
  }
  return &opt;
}

}  // namespace

void define_insert(py::module_& m) {
  m.attr("MAX_THREADS") = kMaxThreads;
  m.def("default_threads", &default_threads,
        "The machine's hardware threads (1 to MAX_THREADS): the default thread count.");
  m.def(
      "_insert_batch",
      [](const std::vector<std::vector<OccupancyMap*>>& targets, const py::list& points,
         const Poses& poses, const Poses& max_ranges, int threads,
         const std::vector<bool>& map_frame, const std::string& mode) {
        check_thread_count(threads);
        FastInsert opt;
        const FastInsert* fast = fast_mode(mode, opt);
        if (points.size() != targets.size()) {
          throw py::value_error("insert batch: targets and points must agree");
        }
        std::vector<py::array> keep;
        std::vector<ScanInput> scans = scan_inputs(points, poses, max_ranges, map_frame, keep);
        for (std::size_t i = 0; i < scans.size(); ++i) {
          scans[i].targets = targets[i];
          check_targets(targets[i]);
        }
        py::gil_scoped_release release;
        insert_batch(scans, static_cast<unsigned>(threads), fast);
      },
      py::arg("targets"), py::arg("points"), py::arg("poses"), py::arg("max_ranges"),
      py::arg("threads") = static_cast<int>(default_threads()),
      py::arg("map_frame") = std::vector<bool>{}, py::arg("mode") = "exact",
      "Insert a batch of sensor-frame scans into their target maps (ray keys computed once "
      "per scan, in parallel); the GIL is released. threads: 1 to MAX_THREADS, by default "
      "the machine's hardware threads. ValueError naming the scan and point row if a ray "
      "cannot be traced (non-finite, outside the map's extent, or too long); no map changes "
      "then. map_frame: per scan, True if its points are in the map frame (the pose's "
      "translation is then the sensor origin and its rotation is not used). mode: 'exact' "
      "(insertPointCloud's map) or 'fast' (the real-time mode of insert_fast.hpp).");

  py::class_<RayItems>(m, "_RayItems",
                       "A batch's ray updates, traced once (see _trace_rays, _apply_rays).")
      .def_property_readonly("scans", [](const RayItems& r) { return r.per_scan.size(); })
      .def_property_readonly("resolution", [](const RayItems& r) { return r.resolution; })
      .def_property_readonly("nbytes", [](const RayItems& r) {
        std::size_t n = 0;
        for (const auto& v : r.per_scan) n += v.capacity() * sizeof(std::uint64_t);
        for (const auto& f : r.fast) {
          if (f) n += (f->items.capacity() + f->cells.capacity()) * 8 + f->ends.capacity() * 4;
        }
        return n;
      });
  m.def(
      "_trace_rays",
      [](const OccupancyMap& grid, const py::list& points, const Poses& poses,
         const Poses& max_ranges, int threads, const std::vector<bool>& map_frame,
         const std::string& mode) {
        check_thread_count(threads);
        FastInsert opt;
        const FastInsert* fast = fast_mode(mode, opt);
        std::vector<py::array> keep;
        const std::vector<ScanInput> scans =
            scan_inputs(points, poses, max_ranges, map_frame, keep);
        py::gil_scoped_release release;
        return trace_rays(scans, grid, static_cast<unsigned>(threads), false, fast);
      },
      py::arg("grid"), py::arg("points"), py::arg("poses"), py::arg("max_ranges"),
      py::arg("threads"), py::arg("map_frame") = std::vector<bool>{}, py::arg("mode") = "exact",
      "Trace a batch of scans' rays on the grid of map `grid` once (arguments and errors as "
      "_insert_batch; no map changes); the GIL is released.");
  m.def(
      "_apply_rays",
      [](const RayItems& items, const std::vector<std::vector<OccupancyMap*>>& targets,
         int threads) {
        check_thread_count(threads);  // apply_rays checks the count of target lists
        for (const auto& per_scan : targets) {
          for (OccupancyMap* t : per_scan) {
            if (t == nullptr) throw py::value_error("apply rays: a target map is None");
            if (std::fabs(t->params().resolution - items.resolution) > 1e-9 * items.resolution) {
              throw py::value_error(
                  "apply rays: a map of " + std::to_string(t->params().resolution) +
                  " m for rays traced at " + std::to_string(items.resolution) + " m");
            }
          }
        }
        py::gil_scoped_release release;
        apply_rays(items, targets, static_cast<unsigned>(threads));
      },
      py::arg("items"), py::arg("targets"), py::arg("threads"),
      "Apply traced rays to maps (targets[i]: the maps of scan i; each map gets its scans in "
      "order, maps in parallel); the GIL is released.");

  m.def(
      "_insert_scan_batched",
      [](OccupancyMap& map, py::array points,
         py::array_t<double, py::array::c_style | py::array::forcecast> origin, double max_range,
         const std::string& mode, int threads, unsigned cell_levels, unsigned min_rays) {
        FastInsert opt{cell_levels, min_rays, static_cast<unsigned>(std::max(threads, 0))};
        const FastInsert* fast = fast_mode(mode, opt);
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
        if (fast != nullptr && dbl) {
          insert_scan_fast(map, static_cast<const double*>(p), n, o, max_range, *fast);
        } else if (fast != nullptr) {
          insert_scan_fast(map, static_cast<const float*>(p), n, o, max_range, *fast);
        } else if (dbl) {
          insert_scan_batched(map, static_cast<const double*>(p), n, o, max_range);
        } else {
          insert_scan_batched(map, static_cast<const float*>(p), n, o, max_range);
        }
      },
      py::arg("map"), py::arg("points"), py::arg("origin"), py::arg("max_range"),
      py::arg("mode") = "exact", py::arg("threads") = 1,
      py::arg("cell_levels") = FastInsert{}.coarse_levels,
      py::arg("min_rays") = FastInsert{}.min_rays,
      "Insert one map-frame scan into one map by the depth-first batch path: the same map as "
      "insert_scan (OctoMap's insertPointCloud), or with mode='fast' the real-time mode "
      "(threads tracing the scan, its cells of 2^cell_levels voxels cleared whole where "
      "min_rays rays cross them); the GIL is released.");
  m.def(
      "_insert_ray_loop",
      [](OccupancyMap& map, py::array_t<float, py::array::c_style | py::array::forcecast> points,
         py::array_t<double, py::array::c_style | py::array::forcecast> origin, double max_range) {
        if (points.ndim() != 2 || points.shape(1) != 3 || origin.size() != 3) {
          throw py::value_error("expected (N, 3) points and an origin of 3 values");
        }
        const double o[3] = {origin.data()[0], origin.data()[1], origin.data()[2]};
        py::gil_scoped_release release;
        insert_ray_loop(map, points.data(), static_cast<std::size_t>(points.shape(0)), o,
                        max_range);
      },
      py::arg("map"), py::arg("points"), py::arg("origin"), py::arg("max_range"),
      "A benchmark baseline: OctoMap's insertRay() for every point of a map-frame scan.");
}

}  // namespace octofuse::bindings
