// octofuse bindings: the _core extension module (type conversion and GIL release only).
#include "common.hpp"

namespace octofuse::bindings {
void define_transform(py::module_& m);  // _transform_map, OctoMap streams in memory
void define_arith(py::module_& m);      // log-odds arithmetic on whole maps (channel filters)
}  // namespace octofuse::bindings

PYBIND11_MODULE(_core, m) {
  m.doc() = "octofuse compiled core (internal; use the octofuse package)";
  octofuse::bindings::define_rules(m);
  octofuse::bindings::define_maps(m);
  octofuse::bindings::define_insert(m);
  octofuse::bindings::define_fusion(m);
  octofuse::bindings::define_compare(m);
  octofuse::bindings::define_transform(m);
  octofuse::bindings::define_arith(m);
}
