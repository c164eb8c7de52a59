// octofuse bindings: log-odds arithmetic on whole maps (exact fusion by channel filters).
#include "common.hpp"

#include "octofuse/arith.hpp"

namespace octofuse::bindings {

void define_arith(py::module_& m) {
  m.def(
      "_open_clamping", [](OccupancyMap& map) { open_clamping(map); }, py::arg("map"));
  m.def(
      "_negate_values",
      [](OccupancyMap& map) {
        py::gil_scoped_release release;
        negate_values(map);
      },
      py::arg("map"));
  m.def(
      "_clamp_values",
      [](OccupancyMap& map) {
        py::gil_scoped_release release;
        clamp_values(map);
      },
      py::arg("map"));
  m.def(
      "_clamped_copy",
      [](const OccupancyMap& map) {
        py::gil_scoped_release release;
        return clamped_copy(map);
      },
      py::arg("map"));
  m.def(
      "_assign_values",
      [](OccupancyMap& map, OccupancyMap& channel, const OccupancyMap& msg) {
        py::gil_scoped_release release;
        return assign_values(map, channel, msg);
      },
      py::arg("map"), py::arg("channel"), py::arg("msg"));
}

}  // namespace octofuse::bindings
