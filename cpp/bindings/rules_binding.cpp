// octofuse bindings: per-voxel rules over numpy arrays.
#include "common.hpp"

#include "octofuse/fuse_arrays.hpp"

#include <string>

namespace octofuse::bindings {

namespace {

using CArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

py::tuple fuse(int rule, CArray a, CArray b, bool probabilities, double l0,
               const std::string& name_a, const std::string& name_b) {
  if (rule < 0 || rule >= kNumRules) throw py::value_error("invalid rule index");
  if (a.size() != b.size()) throw py::value_error("inputs must have the same number of elements");
  const std::size_t n = static_cast<std::size_t>(a.size());
  std::vector<py::ssize_t> shape(a.shape(), a.shape() + a.ndim());
  CArray value(shape), omega(shape), loss(shape);
  ArrayStatus st;
  {
    const double* pa = a.data();
    const double* pb = b.data();
    double *pv = value.mutable_data(), *pw = omega.mutable_data(), *pl = loss.mutable_data();
    py::gil_scoped_release release;
    st = fuse_arrays(static_cast<Rule>(rule), pa, pb, n, probabilities, l0, pv, pw, pl);
  }
  if (st.what != BadInput::None) {
    const std::string idx = std::to_string(st.index);
    const std::string& nm = st.input == 1 ? name_b : name_a;
    const double va = a.data()[st.index], vb = b.data()[st.index];
    switch (st.what) {
      case BadInput::NaN:
        throw py::value_error(nm + " is NaN at flat index " + idx);
      case BadInput::OutOfRange:
        throw py::value_error(nm + " = " + std::to_string(st.input == 1 ? vb : va) +
                              " at flat index " + idx + " is not a probability in [0, 1]");
      case BadInput::Contradiction:
        throw py::value_error("contradictory certainties at flat index " + idx + ": " + name_a +
                              " and " + name_b + " are certain of opposite outcomes (" +
                              std::to_string(va) + ", " + std::to_string(vb) +
                              "); no fusion rule can combine them");
      case BadInput::None:
        break;
    }
  }
  return py::make_tuple(value, omega, loss);
}

}  // namespace

void define_rules(py::module_& m) {
  py::list names;
  for (int i = 0; i < kNumRules; ++i) names.append(kRuleNames[i]);
  m.attr("RULE_NAMES") = py::tuple(names);
  m.def("_fuse", &fuse, py::arg("rule"), py::arg("a"), py::arg("b"), py::arg("probabilities"),
        py::arg("l0"), py::arg("name_a") = "a", py::arg("name_b") = "b",
        "Element-wise fusion of two equally shaped float64 arrays; returns (value, omega, "
        "info_loss).");
}

}  // namespace octofuse::bindings
