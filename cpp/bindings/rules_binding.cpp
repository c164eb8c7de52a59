// octofuse bindings: the Rule and UnknownPolicy enums (C++ holds their names) and the
// per-voxel rules over numpy arrays.
#include "common.hpp"

#include "octofuse/fuse_arrays.hpp"
#include "octofuse/voxel_fusion.hpp"

#include <cctype>
#include <string>

namespace octofuse::bindings {

namespace {

using CArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

/// "naive-bayes" -> "NAIVE_BAYES": the Python name of an enum value.
std::string identifier(const char* name) {
  std::string id;
  for (const char* c = name; *c != '\0'; ++c) {
    id += *c == '-' ? '_' : static_cast<char>(std::toupper(static_cast<unsigned char>(*c)));
  }
  return id;
}

template <int N>
std::string joined(const char* const (&names)[N]) {
  std::string out;
  for (int i = 0; i < N; ++i) out += (i ? ", " : "") + std::string(names[i]);
  return out;
}

template <class Enum, int N>
Enum from_name(const std::string& name, const char* const (&names)[N], const char* what,
               const char* plural) {
  for (int i = 0; i < N; ++i)
    if (name == names[i]) return static_cast<Enum>(i);
  throw py::value_error(std::string("unknown ") + what + " '" + name + "'; valid " + plural +
                        " are: " + joined(names));
}

py::tuple fuse(Rule rule, CArray a, CArray b, bool probabilities, double l0,
               const std::string& name_a, const std::string& name_b) {
  check_enum(rule);
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
    st = fuse_arrays(rule, pa, pb, n, probabilities, l0, pv, pw, pl);
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
  py::enum_<Rule> rule(m, "Rule", "A per-voxel fusion rule; RULE_NAMES[int(rule)] is its name.");
  for (int i = 0; i < kNumRules; ++i)
    rule.value(identifier(kRuleNames[i]).c_str(), static_cast<Rule>(i));
  py::enum_<UnknownPolicy> unknown(
      m, "UnknownPolicy",
      "What a voxel only one map knows becomes: COPY keeps its value, PRIOR fuses it with the "
      "prior (p = 0.5).");
  for (int i = 0; i < kNumUnknownPolicies; ++i) {
    unknown.value(identifier(kUnknownPolicyNames[i]).c_str(), static_cast<UnknownPolicy>(i));
  }

  py::list rule_names, policy_names;
  for (const char* n : kRuleNames) rule_names.append(n);
  for (const char* n : kUnknownPolicyNames) policy_names.append(n);
  m.attr("RULE_NAMES") = py::tuple(rule_names);
  m.attr("UNKNOWN_POLICY_NAMES") = py::tuple(policy_names);

  m.def(
      "rule_from_name",
      [](const std::string& name) {
        return from_name<Rule>(name, kRuleNames, "fusion rule", "rules");
      },
      py::arg("name"), "The Rule of a name in RULE_NAMES; ValueError listing them otherwise.");
  m.def(
      "unknown_policy_from_name",
      [](const std::string& name) {
        return from_name<UnknownPolicy>(name, kUnknownPolicyNames, "unknown-voxel policy",
                                        "policies");
      },
      py::arg("name"),
      "The UnknownPolicy of a name in UNKNOWN_POLICY_NAMES; ValueError listing them otherwise.");

  m.def("_fuse", &fuse, py::arg("rule"), py::arg("a"), py::arg("b"), py::arg("probabilities"),
        py::arg("l0"), py::arg("name_a") = "a", py::arg("name_b") = "b",
        "Element-wise fusion of two equally shaped float64 arrays; returns (value, omega, "
        "info_loss).");
}

}  // namespace octofuse::bindings
