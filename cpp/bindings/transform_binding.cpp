// octofuse bindings: rigid transforms and resampling of maps, and OctoMap streams in memory.
#include "common.hpp"

#include "octofuse/map_file.hpp"
#include "octofuse/occupancy_map.hpp"
#include "octofuse/transform.hpp"

#include <cmath>
#include <string>

namespace octofuse::bindings {

void define_transform(py::module_& m) {
  m.def(
      "_transform_map",
      [](const OccupancyMap& src, py::array_t<double, py::array::c_style | py::array::forcecast> T,
         double resolution, const std::string& resampling) {
        if (resampling != "vote" && resampling != "nearest") {
          throw py::value_error("resampling '" + resampling + "': expected vote or nearest");
        }
        const Resampling mode = resampling == "vote" ? Resampling::Vote : Resampling::Nearest;
        if (T.ndim() != 2 || T.shape(0) != 4 || T.shape(1) != 4) {
          throw py::value_error("T must be a 4x4 matrix");
        }
        const double* t = T.data();
        for (int i = 0; i < 16; ++i) {
          if (!std::isfinite(t[i])) throw py::value_error("T is not finite");
        }
        double copy[16];
        for (int i = 0; i < 16; ++i) copy[i] = t[i];
        TransformStats st;
        std::unique_ptr<OccupancyMap> out;
        {
          py::gil_scoped_release release;
          out = transform_map(src, copy, resolution, mode, &st);
        }
        py::dict d;
        d["source_leaves"] = st.source_leaves;
        d["samples"] = st.samples;
        d["target_voxels"] = st.target_voxels;
        return py::make_tuple(std::move(out), d);
      },
      py::arg("src"), py::arg("T"), py::arg("resolution"), py::arg("resampling") = "vote");

  m.def(
      "_map_to_stream",
      [](const OccupancyMap& map, bool binary) {
        std::string s;
        {
          py::gil_scoped_release release;
          s = write_map_stream(map, binary);
        }
        return py::bytes(s);
      },
      py::arg("map"), py::arg("binary") = false);
  m.def(
      "_map_from_stream",
      [](const py::bytes& data, const std::string& name) {
        std::string s = data;
        py::gil_scoped_release release;
        return read_map_stream(s, name);
      },
      py::arg("data"), py::arg("name") = "stream");
  m.def("_tree_data", [](const OccupancyMap& map) {
    std::string s;
    {
      py::gil_scoped_release release;
      s = write_tree_data(map);
    }
    return py::bytes(s);
  });
  m.def(
      "_map_from_tree_data",
      [](const py::bytes& data, double res, double hit, double miss, double cmin, double cmax,
         const std::string& name) {
        std::string s = data;
        MapParams p{res, hit, miss, cmin, cmax};
        p.validate();  // std::invalid_argument -> ValueError
        py::gil_scoped_release release;
        return read_tree_data(s, p, name);
      },
      py::arg("data"), py::arg("resolution"), py::arg("prob_hit"), py::arg("prob_miss"),
      py::arg("clamp_min"), py::arg("clamp_max"), py::arg("name") = "octomap message");
}

}  // namespace octofuse::bindings
