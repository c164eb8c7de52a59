// octofuse bindings: the _core extension module (type conversion and GIL release only).
#include "common.hpp"

PYBIND11_MODULE(_core, m) {
  m.doc() = "octofuse compiled core (internal; use the octofuse package)";
  octofuse::bindings::define_rules(m);
  octofuse::bindings::define_maps(m);
  octofuse::bindings::define_insert(m);
  octofuse::bindings::define_fusion(m);
  octofuse::bindings::define_compare(m);
}
