// Hostile input never crashes: rays OctoMap cannot trace, thread counts, worker exceptions,
// map files whose header or records lie, and files that are not regular files.
#include "octofuse/detail/parallel_for.hpp"
#include "octofuse/insert.hpp"
#include "octofuse/map_file.hpp"
#include "octofuse/scan_check.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>

#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <fstream>
#include <new>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace octofuse;

namespace {

std::string tmp_path(const std::string& name) { return "/tmp/octofuse_cpp_rel_" + name; }

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write_all(const std::string& path, const std::string& data) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << data;
}

// The message of the MapFileError that loading `path` throws ("" if none).
std::string load_error(const std::string& path) {
  try {
    read_map_file(path);
  } catch (const MapFileError& e) {
    return e.what();
  }
  return "";
}

template <class F>
std::string invalid_argument_of(F f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

bool is_ascii(const std::string& s) {
  for (char c : s)
    if (static_cast<unsigned char>(c) >= 128) return false;
  return true;
}

// A saved .ot map with its "size" header line replaced.
std::string ot_with_size(const std::string& name, const std::string& size) {
  const std::string path = tmp_path(name);
  write_map_file(octofuse_test::random_map(5, 0.5), path);
  std::string data = read_all(path);
  const std::size_t at = data.find("\nsize ");
  const std::size_t eol = data.find('\n', at + 1);
  data = data.substr(0, at) + "\nsize " + size + data.substr(eol);
  write_all(path, data);
  return path;
}

long max_rss_kb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

}  // namespace

TEST(ScanRays, RayLongerThanOctomapsKeyBufferIsRejected) {
  for (double res : {0.05, 0.005}) {
    MapParams p;
    p.resolution = res;
    OccupancyMap m(p);
    const double far = res == 0.05 ? 1600.0 : 150.0;  // diagonal rays of ~190,000 voxels
    const double pt[3] = {far, far, far}, origin[3] = {-far, -far, -far};
    const std::string msg = invalid_argument_of([&] { m.insert_scan(pt, 1, origin, -1.0); });
    EXPECT_NE(msg.find("point row 0"), std::string::npos) << msg;
    EXPECT_NE(msg.find("max_range"), std::string::npos) << msg;
    EXPECT_EQ(m.num_nodes(), 0u);         // nothing inserted
    m.insert_scan(pt, 1, origin, 100.0);  // cut to max_range: traced
    EXPECT_GT(m.num_leaves(), 0u);
  }
}

TEST(ScanRays, PointsOutsideTheTreesExtentAreRejectedNamingTheRow) {
  OccupancyMap m(MapParams{});  // 0.05 m: the tree spans [-1638.4, 1638.4) m
  const double origin[3] = {0, 0, 0};
  const double pts[9] = {1, 0, 0, 2, 0, 0, 1e30, 0, 0};
  std::string msg = invalid_argument_of([&] { m.insert_scan(pts, 3, origin, -1.0); });
  EXPECT_NE(msg.find("point row 2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("extent"), std::string::npos) << msg;
  const double edge[6] = {1638.3, 0, 0, 1638.45, 0, 0};
  msg = invalid_argument_of([&] { m.insert_scan(edge, 2, origin, -1.0); });
  EXPECT_NE(msg.find("point row 1"), std::string::npos) << msg;
  const double away[3] = {5000, 0, 0};
  msg = invalid_argument_of([&] { m.insert_scan(pts, 1, away, -1.0); });
  EXPECT_NE(msg.find("sensor origin"), std::string::npos) << msg;
  EXPECT_EQ(m.num_nodes(), 0u);
}

TEST(InsertBatch, RejectsBadScansNamingScanAndRowBeforeAnyMapChanges) {
  OccupancyMap m(MapParams{});
  std::vector<double> good = {1, 0, 0, 0, 1, 0}, bad = {1, 0, 0, 3200, 3200, 3200};
  std::vector<ScanInput> scans(8);
  for (std::size_t i = 0; i < scans.size(); ++i) {
    ScanInput& s = scans[i];
    s.xyz = i == 5 ? bad.data() : good.data();
    s.n = 2;
    const double pose[16] = {1, 0, 0, -1600, 0, 1, 0, -1600, 0, 0, 1, -1600, 0, 0, 0, 1};
    std::copy(pose, pose + 16, s.pose);
    if (i != 5) s.pose[3] = s.pose[7] = s.pose[11] = 0.0;
    s.targets = {&m};
  }
  for (unsigned threads : {1u, 4u}) {
    const std::string msg = invalid_argument_of([&] { insert_batch(scans, threads); });
    EXPECT_NE(msg.find("scan 5: point row 1"), std::string::npos) << msg;
    EXPECT_EQ(m.num_nodes(), 0u);
  }
}

TEST(InsertBatch, ThreadCountIsValidated) {
  OccupancyMap m(MapParams{});
  std::vector<double> pts = {1, 0, 0};
  ScanInput s;
  s.xyz = pts.data();
  s.n = 1;
  const double pose[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  std::copy(pose, pose + 16, s.pose);
  s.targets = {&m};
  const std::vector<ScanInput> scans(3, s);
  EXPECT_NE(invalid_argument_of([&] { insert_batch(scans, 0); }).find("threads = 0"),
            std::string::npos);
  EXPECT_NE(invalid_argument_of([&] { insert_batch(scans, 100000); }).find("threads = 100000"),
            std::string::npos);
  insert_batch(scans, kMaxThreads);  // more threads than scans: fine
  EXPECT_GT(m.num_leaves(), 0u);
  EXPECT_GE(default_threads(), 1u);
  EXPECT_LE(default_threads(), kMaxThreads);
}

TEST(ParallelFor, ExceptionsOfWorkerThreadsReachTheCaller) {
  const std::thread::id caller = std::this_thread::get_id();
  std::atomic<int> thrown{0};
  EXPECT_THROW(detail::parallel_for(1000, 4,
                                    [&](std::size_t i) {
                                      if (std::this_thread::get_id() != caller && i % 3 == 0) {
                                        ++thrown;
                                        throw std::bad_alloc();
                                      }
                                      std::this_thread::sleep_for(std::chrono::microseconds(50));
                                    }),
               std::bad_alloc);
  EXPECT_GE(thrown.load(), 1);
  std::atomic<std::size_t> sum{0};
  detail::parallel_for(100, 4, [&](std::size_t i) { sum += i; });
  EXPECT_EQ(sum.load(), 4950u);
}

TEST(MapFileHeader, SizeMustBeAWholeNodeCountTheDataHolds) {
  for (const char* size : {"0", "1e30", "inf", "18446744073709551616", "12.5", "-3", "99999999"}) {
    const std::string path = ot_with_size(std::string("size_") + size + ".ot", size);
    const std::string msg = load_error(path);
    EXPECT_NE(msg.find(path), std::string::npos) << size << ": " << msg;
    EXPECT_NE(msg.find("size") == std::string::npos ? msg.find("nodes") : 0, std::string::npos)
        << msg;
  }
  EXPECT_NE(load_error(ot_with_size("size_zero.ot", "0")).find("0 nodes"), std::string::npos);
  // an empty map saved and read back is still fine
  const std::string empty = tmp_path("empty.ot");
  write_map_file(OccupancyMap(MapParams{}), empty);
  EXPECT_EQ(read_map_file(empty)->num_nodes(), 0u);
}

TEST(MapFileHeader, ResolutionIsBounded) {
  const std::string path = tmp_path("res.ot");
  write_map_file(octofuse_test::random_map(6, 0.5), path);
  const std::string data = read_all(path);
  for (const char* res : {"1e-30", "1e+30", "0", "-1"}) {
    std::string d = data;
    const std::size_t at = d.find("\nres ");
    d = d.substr(0, at) + "\nres " + res + d.substr(d.find('\n', at + 1));
    write_all(path, d);
    const std::string msg = load_error(path);
    EXPECT_NE(msg.find(path), std::string::npos) << res << ": " << msg;
    EXPECT_NE(msg.find(res), std::string::npos) << res << ": " << msg;
  }
  EXPECT_THROW(OccupancyMap(MapParams{1e-30}), std::invalid_argument);
  EXPECT_THROW(OccupancyMap(MapParams{1e30}), std::invalid_argument);
}

TEST(MapFileHeader, NonUtf8BytesGiveAnAsciiMessageNamingTheFile) {
  const std::string path = tmp_path("bytes.ot");
  write_map_file(octofuse_test::random_map(7, 0.5), path);
  const std::string data = read_all(path);
  for (const char* from : {"id OcTree", "res ", "data\n"}) {
    std::string d = data;
    const std::size_t at = d.find(from);
    d[at + 1] = '\xff';
    write_all(path, d);
    const std::string msg = load_error(path);
    EXPECT_NE(msg.find(path), std::string::npos) << from << ": " << msg;
    EXPECT_TRUE(is_ascii(msg)) << msg;
  }
}

TEST(MapFileRecords, BtRecordsClaimingMoreThanTheFileHoldsAllocateNothing) {
  // every record down to depth 15 says "8 inner children", those at depth 15 "8 occupied
  // leaves": cut at 6 MB, the file claims far more nodes than it holds
  std::string data = "# Octomap OcTree binary file\nid OcTree\nsize 1\nres 0.1\ndata\n";
  const std::size_t budget = 6u << 20;
  std::vector<unsigned> stack = {0};
  while (!stack.empty() && data.size() < budget) {
    const unsigned depth = stack.back();
    stack.pop_back();
    if (depth < 15) {
      data += "\xff\xff";
      for (int i = 0; i < 8; ++i) stack.push_back(depth + 1);
    } else {
      data += "\xaa\xaa";
    }
  }
  const std::string path = tmp_path("claims.bt");
  write_all(path, data);
  const long before = max_rss_kb();
  const std::string msg = load_error(path);
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  EXPECT_LT(max_rss_kb() - before, 64 * 1024) << "kB allocated for a " << data.size() << " B file";
  write_all(path, data.substr(0, data.find("data\n") + 5) + "\xff\xff");
  EXPECT_NE(load_error(path).find("truncated"), std::string::npos);
}

TEST(MapFileKinds, FifosAndDevicesAreRefusedWithoutReading) {
  const std::string fifo = tmp_path("fifo.ot");
  std::remove(fifo.c_str());
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_NE(load_error(fifo).find("FIFO"), std::string::npos);  // would block if opened
  std::remove(fifo.c_str());
  EXPECT_NE(load_error("/dev/zero").find("character device"), std::string::npos);
  EXPECT_NE(load_error("/tmp").find("directory"), std::string::npos);
}
