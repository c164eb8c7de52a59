// octofuse bindings: OccupancyMap, the information-loss tree and tree fusion.
#include "common.hpp"

#include "octofuse/compare.hpp"
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/insert.hpp"
#include "octofuse/tree_access.hpp"

#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace octofuse::bindings {

namespace {

py::dict leaves_to_dict(LeafArrays&& l) {
  const auto n = static_cast<py::ssize_t>(l.sizes.size());
  py::dict d;
  d["centers"] = to_numpy(std::move(l.centers), {n, 3});
  d["sizes"] = to_numpy(std::move(l.sizes), {n});
  d["values"] = to_numpy(std::move(l.values), {n});
  d["depths"] = to_numpy(std::move(l.depths), {n});
  return d;
}

template <class Real>
void insert_impl(OccupancyMap& self, py::array_t<Real, py::array::c_style> points,
                 py::array_t<double, py::array::c_style | py::array::forcecast> origin_or_pose,
                 double max_range, bool sensor_frame) {
  if (points.ndim() != 2 || points.shape(1) != 3) {
    throw py::value_error("points must be an (N, 3) array");
  }
  const std::size_t n = static_cast<std::size_t>(points.shape(0));
  const Real* p = points.data();
  for (std::size_t i = 0; i < 3 * n; ++i) {
    if (!std::isfinite(static_cast<double>(p[i]))) {
      throw py::value_error("points hold a non-finite coordinate at row " + std::to_string(i / 3) +
                            "; drop NaN/inf points before inserting");
    }
  }
  const double* o = origin_or_pose.data();
  const py::ssize_t need = sensor_frame ? 16 : 3;
  if (origin_or_pose.size() != need) {
    throw py::value_error(sensor_frame ? "pose must be a 4x4 matrix" : "origin must have 3 values");
  }
  for (py::ssize_t i = 0; i < need; ++i) {
    if (!std::isfinite(o[i])) throw py::value_error(sensor_frame ? "pose is not finite" : "origin is not finite");
  }
  py::gil_scoped_release release;
  if (sensor_frame) {
    self.insert_scan_from_sensor(p, n, o, max_range);
  } else {
    self.insert_scan(p, n, o, max_range);
  }
}

}  // namespace

void define_maps(py::module_& m) {
  py::register_exception<MapFileError>(m, "MapFileError", PyExc_OSError);

  py::class_<ScalarTree>(m, "_ScalarTree")
      .def(py::init<double>(), py::arg("resolution"))
      .def_property_readonly("resolution", &ScalarTree::getResolution)
      .def_property_readonly("num_leaves", &ScalarTree::getNumLeafNodes)
      .def_property_readonly("memory_bytes", &ScalarTree::memoryUsage)
      .def("leaves", [](const ScalarTree& t) {
        LeafArrays l;
        {
          py::gil_scoped_release release;
          l = scalar_leaves(t);
        }
        return leaves_to_dict(std::move(l));
      })
      .def("accumulate", [](ScalarTree& self, const ScalarTree& other) {
        if (std::fabs(self.getResolution() - other.getResolution()) > 1e-9 * self.getResolution()) {
          throw py::value_error("cannot accumulate trees of different resolutions");
        }
        py::gil_scoped_release release;
        accumulate_loss(self, other);
      })
      .def("copy", [](const ScalarTree& t) { return std::make_unique<ScalarTree>(t); });

  py::class_<OccupancyMap>(m, "_OccupancyMap")
      .def(py::init([](double res, double hit, double miss, double cmin, double cmax) {
             MapParams p{res, hit, miss, cmin, cmax};
             p.validate();  // std::invalid_argument -> ValueError
             return std::make_unique<OccupancyMap>(p);
           }),
           py::arg("resolution"), py::arg("prob_hit"), py::arg("prob_miss"),
           py::arg("clamp_min"), py::arg("clamp_max"))
      .def("insert_scan", &insert_impl<float>, py::arg("points"), py::arg("origin"),
           py::arg("max_range"), py::arg("sensor_frame"))
      .def("insert_scan", &insert_impl<double>, py::arg("points"), py::arg("origin"),
           py::arg("max_range"), py::arg("sensor_frame"))
      .def("save", [](const OccupancyMap& self, const std::string& path) {
        py::gil_scoped_release release;
        self.save(path);
      })
      .def_static("load", [](const std::string& path) {
        py::gil_scoped_release release;
        return OccupancyMap::load(path);
      })
      .def("leaves", [](const OccupancyMap& self) {
        LeafArrays l;
        {
          py::gil_scoped_release release;
          l = self.leaves();
        }
        return leaves_to_dict(std::move(l));
      })
      .def("copy", [](const OccupancyMap& self) {
        py::gil_scoped_release release;
        return std::make_unique<OccupancyMap>(self);
      })
      .def_property_readonly("num_leaves", [](const OccupancyMap& s) {
        py::gil_scoped_release release;  // counting walks the tree
        return s.num_leaves();
      })
      .def_property_readonly("num_nodes", &OccupancyMap::num_nodes)
      .def_property_readonly("memory_bytes", &OccupancyMap::memory_bytes)
      .def_property_readonly("resolution", [](const OccupancyMap& s) { return s.params().resolution; })
      .def_property_readonly("prob_hit", [](const OccupancyMap& s) { return s.params().prob_hit; })
      .def_property_readonly("prob_miss", [](const OccupancyMap& s) { return s.params().prob_miss; })
      .def_property_readonly("clamping", [](const OccupancyMap& s) {
        return py::make_tuple(s.params().clamp_min, s.params().clamp_max);
      })
      .def_property_readonly("clamping_logodds", [](const OccupancyMap& s) {
        return py::make_tuple(s.clamp_min_logodds(), s.clamp_max_logodds());
      });

  m.def(
      "_insert_batch",
      [](const std::vector<std::vector<OccupancyMap*>>& targets, const py::list& points,
         py::array_t<double, py::array::c_style | py::array::forcecast> poses,
         py::array_t<double, py::array::c_style | py::array::forcecast> max_ranges,
         unsigned threads) {
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
        insert_batch(scans, threads);
      },
      py::arg("targets"), py::arg("points"), py::arg("poses"), py::arg("max_ranges"),
      py::arg("threads") = 2,
      "Insert a batch of sensor-frame scans into their target maps (ray keys computed once "
      "per scan, in parallel); the GIL is released.");

  m.def(
      "_compare_maps",
      [](const OccupancyMap& ref, const OccupancyMap& map, double tol, double thr) {
        check_compatible(ref, map);
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
      py::arg("ref"), py::arg("map"), py::arg("tol"), py::arg("occ_threshold") = 0.0);
  m.def("_changed_voxels", [](const OccupancyMap& cur, const OccupancyMap& prev) {
    check_compatible(cur, prev);
    py::gil_scoped_release release;
    return changed_voxels(cur, prev);
  });

  m.def(
      "_fuse_into",
      [](OccupancyMap& dst, const OccupancyMap& msg, int rule, int unknown, ScalarTree* loss) {
        if (rule < 0 || rule >= kNumRules) throw py::value_error("invalid rule index");
        if (unknown < 0 || unknown > 1) throw py::value_error("invalid unknown policy");
        if (&dst == &msg) throw py::value_error("cannot fuse a map into itself in place");
        check_compatible(dst, msg);
        if (loss != nullptr &&
            std::fabs(loss->getResolution() - dst.params().resolution) > 1e-9 * dst.params().resolution) {
          throw py::value_error("information-loss map has another resolution than the map");
        }
        FuseIntoStats st;
        {
          py::gil_scoped_release release;
          st = fuse_into(dst, msg, static_cast<Rule>(rule), static_cast<UnknownPolicy>(unknown), loss);
        }
        return py::make_tuple(st.fused, st.copied);
      },
      py::arg("dst"), py::arg("msg"), py::arg("rule"), py::arg("unknown"), py::arg("loss").none(true));

  m.def(
      "_fuse_mutual",
      [](OccupancyMap& a, OccupancyMap& b, int rule, int unknown, ScalarTree* loss_a,
         ScalarTree* loss_b) {
        if (rule < 0 || rule >= kNumRules) throw py::value_error("invalid rule index");
        if (unknown < 0 || unknown > 1) throw py::value_error("invalid unknown policy");
        if (&a == &b) throw py::value_error("cannot exchange a map with itself");
        if (loss_a != nullptr && loss_a == loss_b) throw py::value_error("the two loss maps must differ");
        check_compatible(a, b);
        std::pair<FuseIntoStats, FuseIntoStats> st;
        {
          py::gil_scoped_release release;
          st = fuse_mutual(a, b, static_cast<Rule>(rule), static_cast<UnknownPolicy>(unknown),
                           loss_a, loss_b);
        }
        return py::make_tuple(st.first.fused, st.first.copied, st.second.fused, st.second.copied);
      },
      py::arg("a"), py::arg("b"), py::arg("rule"), py::arg("unknown"), py::arg("loss_a").none(true),
      py::arg("loss_b").none(true));

  m.def("_check_compatible", [](const OccupancyMap& a, const OccupancyMap& b) {
    check_compatible(a, b);
  });
  m.def(
      "_fuse_maps",
      [](const OccupancyMap& a, const OccupancyMap& b, int rule, int unknown) {
        if (rule < 0 || rule >= kNumRules) throw py::value_error("invalid rule index");
        if (unknown < 0 || unknown > 1) throw py::value_error("invalid unknown policy");
        check_compatible(a, b);
        FusionResult r;
        {
          py::gil_scoped_release release;
          r = fuse_maps(a, b, static_cast<Rule>(rule), static_cast<UnknownPolicy>(unknown));
        }
        return py::make_tuple(std::move(r.map), std::move(r.info_loss), r.voxels_fused,
                              r.voxels_copied);
      },
      py::arg("a"), py::arg("b"), py::arg("rule"), py::arg("unknown"));
}

}  // namespace octofuse::bindings
