// octofuse bindings: fusion of whole maps (into a new map, in place, both ways at once).
#include "common.hpp"

#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/insert.hpp"

#include <cmath>
#include <string>

namespace octofuse::bindings {

namespace {

/// (voxels fused, voxels copied, loss summed over the fused voxels, leaves of the message):
/// finest voxels, nats, leaves.
py::tuple counts_tuple(const FusionCounts& c) {
  return py::make_tuple(c.fused, c.copied, c.loss_sum, c.msg_leaves);
}

}  // namespace

void define_fusion(py::module_& m) {
  m.def(
      "_fuse_into",
      [](OccupancyMap& dst, const OccupancyMap& msg, Rule rule, UnknownPolicy unknown,
         ScalarTree* loss, int threads) {
        if (threads < 1 || threads > static_cast<int>(kMaxThreads)) {
          throw py::value_error("threads = " + std::to_string(threads) + ": expected 1 to " +
                                std::to_string(kMaxThreads));
        }
        check_enum(rule);
        check_enum(unknown);
        if (&dst == &msg) throw py::value_error("cannot fuse a map into itself in place");
        check_compatible(dst, msg);
        if (loss != nullptr && std::fabs(loss->getResolution() - dst.params().resolution) >
                                   1e-9 * dst.params().resolution) {
          throw py::value_error("information-loss map has another resolution than the map");
        }
        FuseIntoStats st;
        {
          py::gil_scoped_release release;
          st = fuse_into(dst, msg, rule, unknown, loss, static_cast<unsigned>(threads));
        }
        return counts_tuple(st);
      },
      py::arg("dst"), py::arg("msg"), py::arg("rule"), py::arg("unknown"),
      py::arg("loss").none(true), py::arg("threads") = 1);

  m.def(
      "_subtract_into",
      [](OccupancyMap& dst, const OccupancyMap& msg) {
        if (&dst == &msg) throw py::value_error("cannot subtract a map from itself in place");
        check_compatible(dst, msg);
        py::gil_scoped_release release;
        subtract_into(dst, msg);
      },
      py::arg("dst"), py::arg("msg"));

  m.def(
      "_fuse_mutual",
      [](OccupancyMap& a, OccupancyMap& b, Rule rule, UnknownPolicy unknown, ScalarTree* loss_a,
         ScalarTree* loss_b) {
        check_enum(rule);
        check_enum(unknown);
        if (&a == &b) throw py::value_error("cannot exchange a map with itself");
        if (loss_a != nullptr && loss_a == loss_b)
          throw py::value_error("the two loss maps must differ");
        check_compatible(a, b);
        std::pair<FuseIntoStats, FuseIntoStats> st;
        {
          py::gil_scoped_release release;
          st = fuse_mutual(a, b, rule, unknown, loss_a, loss_b);
        }
        return py::make_tuple(counts_tuple(st.first), counts_tuple(st.second));
      },
      py::arg("a"), py::arg("b"), py::arg("rule"), py::arg("unknown"), py::arg("loss_a").none(true),
      py::arg("loss_b").none(true));

  m.def(
      "_fuse_maps",
      [](const OccupancyMap& a, const OccupancyMap& b, Rule rule, UnknownPolicy unknown) {
        check_enum(rule);
        check_enum(unknown);
        check_compatible(a, b);
        FusionResult r;
        {
          py::gil_scoped_release release;
          r = fuse_maps(a, b, rule, unknown);
        }
        return py::make_tuple(std::move(r.map), std::move(r.info_loss), counts_tuple(r.counts));
      },
      py::arg("a"), py::arg("b"), py::arg("rule"), py::arg("unknown"));
}

}  // namespace octofuse::bindings
