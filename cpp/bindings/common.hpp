// octofuse bindings: shared helpers (array conversion without copies).
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

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

void define_rules(py::module_& m);
void define_maps(py::module_& m);

}  // namespace octofuse::bindings
