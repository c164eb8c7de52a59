// octofuse bindings: OccupancyMap and the per-voxel scalar tree (information loss).
#include "common.hpp"

#include "octofuse/carried_loss.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/leaf_lookup.hpp"
#include "octofuse/map_file.hpp"
#include "octofuse/occupancy_map.hpp"

#include <cmath>
#include <string>

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

LeafClass leaf_class(const std::string& voxels) {
  if (voxels == "occupied") return LeafClass::Occupied;
  if (voxels == "free") return LeafClass::Free;
  if (voxels == "all") return LeafClass::All;
  throw py::value_error("voxels = '" + voxels + "': expected 'occupied', 'free' or 'all'");
}

template <class Real>
void insert_impl(OccupancyMap& self, py::array_t<Real, py::array::c_style> points,
                 py::array_t<double, py::array::c_style | py::array::forcecast> origin_or_pose,
                 double max_range, bool sensor_frame) {
  if (points.ndim() != 2 || points.shape(1) != 3) {
    throw py::value_error("points must be an (N, 3) array");
  }
  const std::size_t n = static_cast<std::size_t>(points.shape(0));
  const Real* p = points.data();  // points and rays are checked by the map (ScanCheck)
  const double* o = origin_or_pose.data();
  const py::ssize_t need = sensor_frame ? 16 : 3;
  if (origin_or_pose.size() != need) {
    throw py::value_error(sensor_frame ? "pose must be a 4x4 matrix" : "origin must have 3 values");
  }
  for (py::ssize_t i = 0; i < need; ++i) {
    if (!std::isfinite(o[i]))
      throw py::value_error(sensor_frame ? "pose is not finite" : "origin is not finite");
  }
  py::gil_scoped_release release;
  if (sensor_frame) {
    self.insert_scan_from_sensor(p, n, o, max_range);
  } else {
    self.insert_scan(p, n, o, max_range);
  }
}

// Leaf values and depths as numpy arrays in a dict ("values", "depths").
py::dict values_depths_dict(std::vector<float> values, std::vector<std::uint8_t> depths) {
  const auto n = static_cast<py::ssize_t>(values.size());
  py::dict d;
  d["values"] = to_numpy(std::move(values), {n});
  d["depths"] = to_numpy(std::move(depths), {n});
  return d;
}

}  // namespace

void define_maps(py::module_& m) {
  m.attr("MIN_RESOLUTION") = kMinResolution;  // the voxel sizes a map takes: one source
  m.attr("MAX_RESOLUTION") = kMaxResolution;
  const MapParams defaults;  // a map's default sensor model: one source
  m.attr("DEFAULT_MAP") =
      py::dict(py::arg("resolution") = defaults.resolution, py::arg("prob_hit") = defaults.prob_hit,
               py::arg("prob_miss") = defaults.prob_miss, py::arg("clamp_min") = defaults.clamp_min,
               py::arg("clamp_max") = defaults.clamp_max);
  py::register_exception<MapFileError>(m, "MapFileError", PyExc_OSError);

  m.def(
      "_node_pool_bytes",
      [] {
        return detail::NodePool::stats().slab_bytes + detail::ChildrenPool::stats().slab_bytes +
               detail::arena_bytes() + detail::spare_slab_bytes();
      },
      "Bytes the tree nodes' slabs take: the pools' and arenas' (in use or free), and spares.");
  m.def(
      "_trim_node_pools",
      [] {
        py::gil_scoped_release release;
        return detail::NodePool::trim() + detail::ChildrenPool::trim() + detail::trim_spare_slabs();
      },
      "Gives the pools' empty slabs and the spare ones back to the system; returns the bytes.");

  py::class_<ScalarTree>(m, "_ScalarTree")
      .def(py::init([](double res) {
             MapParams p;
             p.resolution = res;
             p.validate();  // std::invalid_argument -> ValueError
             return std::make_unique<ScalarTree>(res);
           }),
           py::arg("resolution"))
      .def_property_readonly("resolution", &ScalarTree::getResolution)
      .def_property_readonly("num_leaves", &ScalarTree::getNumLeafNodes)
      .def_property_readonly("memory_bytes",
                             [](const ScalarTree& t) {
                               py::gil_scoped_release release;
                               return t.memoryUsage();
                             })
      .def("leaves",
           [](const ScalarTree& t) {
             LeafArrays l;
             {
               py::gil_scoped_release release;
               l = scalar_leaves(t);
             }
             return leaves_to_dict(std::move(l));
           })
      .def("values_depths",
           [](const ScalarTree& t) {
             std::vector<float> values;
             std::vector<std::uint8_t> depths;
             {
               py::gil_scoped_release release;
               scalar_values_and_depths(t, values, depths);
             }
             return values_depths_dict(std::move(values), std::move(depths));
           })
      .def(
          "settled_values_depths",
          [](const ScalarTree& t, const OccupancyMap& carrier) {
            if (carrier.carried_loss() != &t)
              throw py::value_error("the map does not carry this loss tree");
            std::vector<float> values;
            std::vector<std::uint8_t> depths;
            {
              py::gil_scoped_release release;
              settled_loss_leaves(carrier.tree(), t, values, depths);
            }
            return values_depths_dict(std::move(values), std::move(depths));
          },
          py::arg("carrier"),
          "values_depths() of the tree once the losses `carrier` carries were settled into it, "
          "without settling them.")
      .def("accumulate",
           [](ScalarTree& self, const ScalarTree& other) {
             if (std::fabs(self.getResolution() - other.getResolution()) >
                 1e-9 * self.getResolution()) {
               throw py::value_error("cannot accumulate trees of different resolutions");
             }
             py::gil_scoped_release release;
             accumulate_loss(self, other);
           })
      .def("copy", [](const ScalarTree& t) { return std::make_unique<ScalarTree>(t); })
      .def("clear", &ScalarTree::clear, py::call_guard<py::gil_scoped_release>(),
           "Removes every value, freeing the nodes.");

  py::class_<OccupancyMap>(m, "_OccupancyMap")
      .def(py::init([](double res, double hit, double miss, double cmin, double cmax) {
             MapParams p{res, hit, miss, cmin, cmax};
             p.validate();  // std::invalid_argument -> ValueError
             return std::make_unique<OccupancyMap>(p);
           }),
           py::arg("resolution"), py::arg("prob_hit"), py::arg("prob_miss"), py::arg("clamp_min"),
           py::arg("clamp_max"))
      .def("insert_scan", &insert_impl<float>, py::arg("points"), py::arg("origin"),
           py::arg("max_range"), py::arg("sensor_frame"))
      .def("insert_scan", &insert_impl<double>, py::arg("points"), py::arg("origin"),
           py::arg("max_range"), py::arg("sensor_frame"))
      .def("save",
           [](const OccupancyMap& self, const std::string& path) {
             py::gil_scoped_release release;
             write_map_file(self, path);
           })
      .def_static("load",
                  [](const std::string& path) {
                    py::gil_scoped_release release;
                    return read_map_file(path);
                  })
      .def(
          "leaves",
          [](const OccupancyMap& self, const std::string& voxels) {
            const LeafClass which = leaf_class(voxels);
            LeafArrays l;
            {
              py::gil_scoped_release release;
              l = self.leaves(which);
            }
            return leaves_to_dict(std::move(l));
          },
          py::arg("voxels") = "all")
      .def(
          "leaves_with",
          [](const OccupancyMap& self, const ScalarTree& scalar, const std::string& voxels) {
            const LeafClass which = leaf_class(voxels);
            LeafArrays l;
            std::vector<float> values;
            {
              py::gil_scoped_release release;
              l = leaves_with_values(self, scalar, which, values);
            }
            const auto n = static_cast<py::ssize_t>(values.size());
            py::dict d = leaves_to_dict(std::move(l));
            d["scalar"] = to_numpy(std::move(values), {n});
            return d;
          },
          py::arg("scalar"), py::arg("voxels"))
      .def("copy",
           [](const OccupancyMap& self) {
             py::gil_scoped_release release;
             return std::make_unique<OccupancyMap>(self);
           })
      .def("clear", &OccupancyMap::clear, py::arg("keep_loss") = true,
           py::call_guard<py::gil_scoped_release>(),
           "Removes every voxel, freeing the nodes; the losses it carries are settled first "
           "(keep_loss) or go with the nodes.")
      .def("drop_loss", &OccupancyMap::drop_loss, py::call_guard<py::gil_scoped_release>(),
           "Drops the losses it carries and clears its loss tree.")
      .def(
          "carry_loss",
          [](OccupancyMap& self, ScalarTree* loss) {
            py::gil_scoped_release release;
            self.carry_loss(loss);
          },
          py::arg("loss").none(true), py::keep_alive<1, 2>(),
          "Keeps the losses its fusions add into `loss` in its nodes (None: no longer).")
      .def_property_readonly("carries_loss",
                             [](const OccupancyMap& s) { return s.carried_loss() != nullptr; })
      .def("settle_loss", &OccupancyMap::settle_loss, py::call_guard<py::gil_scoped_release>(),
           "Moves the losses it carries into its loss tree.")
      .def_property_readonly("num_leaves",
                             [](const OccupancyMap& s) {
                               py::gil_scoped_release release;  // counting walks the tree
                               return s.num_leaves();
                             })
      .def_property_readonly("known_voxels",
                             [](const OccupancyMap& s) {
                               py::gil_scoped_release release;
                               return s.known_voxels();
                             })
      .def_property_readonly("num_nodes", &OccupancyMap::num_nodes)
      .def_property_readonly("memory_bytes",
                             [](const OccupancyMap& s) {
                               py::gil_scoped_release release;
                               return s.memory_bytes();
                             })
      .def_property_readonly("resolution",
                             [](const OccupancyMap& s) { return s.params().resolution; })
      .def_property_readonly("prob_hit", [](const OccupancyMap& s) { return s.params().prob_hit; })
      .def_property_readonly("prob_miss",
                             [](const OccupancyMap& s) { return s.params().prob_miss; })
      .def_property_readonly("clamping",
                             [](const OccupancyMap& s) {
                               return py::make_tuple(s.params().clamp_min, s.params().clamp_max);
                             })
      .def_property_readonly("clamping_logodds", [](const OccupancyMap& s) {
        return py::make_tuple(s.clamp_min_logodds(), s.clamp_max_logodds());
      });
}

}  // namespace octofuse::bindings
