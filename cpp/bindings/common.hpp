// octofuse bindings: array conversion without copies, enum checks, and the define_X(m)
// functions of the module.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "octofuse/rules.hpp"
#include "octofuse/voxel_fusion.hpp"

#include <memory>
#include <utility>
#include <vector>

namespace octofuse::bindings {

namespace py = pybind11;

/// Moves a std::vector into a numpy array that owns it (no copy of the data).
template <class T>
py::array_t<T> to_numpy(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
  auto* heap = new std::vector<T>(std::move(v));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), owner);
}

/// Throws ValueError for a value outside the enum (pybind11 enums can be built from any int).
inline void check_enum(Rule r) {
  if (static_cast<int>(r) >= kNumRules) throw py::value_error("invalid fusion rule");
}
inline void check_enum(UnknownPolicy u) {
  if (static_cast<int>(u) >= kNumUnknownPolicies)
    throw py::value_error("invalid unknown-voxel policy");
}

/// One function per concept, called in this order by the module.
void define_rules(py::module_& m);    // Rule, UnknownPolicy, names, element-wise _fuse
void define_maps(py::module_& m);     // MapFileError, _OccupancyMap, _ScalarTree
void define_insert(py::module_& m);   // _insert_batch, thread limits
void define_fusion(py::module_& m);   // _fuse_maps, _fuse_into, _fuse_mutual
void define_compare(py::module_& m);  // _ReferenceMap, _compare_maps, _changed_voxels

}  // namespace octofuse::bindings
