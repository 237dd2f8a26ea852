// TetGen .node/.ele reading: good files (comments, 0- and 1-based, attributes and markers, 2D,
// the opposite orientation convention) and bad ones, each with the file, line, field and
// expectation it must name. Files are written to a temporary directory.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "slurry/io/tetgen.h"

namespace {

namespace fs = std::filesystem;
using slurry::IoError;
using slurry::io::read_tetgen;

fs::path temp_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_tetgen_test_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

// A unit cube cut into five tetrahedra, 1-based, with comments, one attribute and markers.
const char* kCubeNode = R"(# cube.node
8 3 1 1   # points, dimension, attributes, markers
1  0 0 0  0.5 1
2  1 0 0  0.5 1
3  0 1 0  0.5 1
4  1 1 0  0.5 1

5  0 0 1  0.5 1
6  1 0 1  0.5 1
7  0 1 1  0.5 1
8  1 1 1  0.5 1
)";
const char* kCubeEle = R"(5 4 1
# the central tetrahedron on the even corners, then the four corner tetrahedra, all
# negatively oriented (the reader flips a consistently opposite orientation)
1  1 4 6 7  3
2  2 1 4 6  3
3  3 4 1 7  3
4  5 1 6 7  3
5  8 4 7 6  3
)";

TEST(TetGen, ReadsCommentsAttributesMarkersAndOneBasedIndices) {
  const auto dir = temp_dir("good");
  write(dir / "cube.node", kCubeNode);
  write(dir / "cube.ele", kCubeEle);
  for (const fs::path& p : {dir / "cube", dir / "cube.node", dir / "cube.ele"}) {
    const auto m = read_tetgen<3>(p);
    ASSERT_EQ(m.vertex_count(), 8u);
    ASSERT_EQ(m.element_count(), 5u);
    EXPECT_EQ(m.x[7], Eigen::Vector3d(1, 1, 1));
    double volume = 0;
    for (std::size_t e = 0; e < m.element_count(); ++e) {
      EXPECT_GT(m.signed_volume(e), 0) << "element " << e << " not positively oriented";
      volume += m.signed_volume(e);
    }
    EXPECT_NEAR(volume, 1.0, 1e-14);
    EXPECT_EQ(slurry::fem::boundary_faces(m).size(), 12u);  // two triangles per cube face
  }
  EXPECT_EQ(slurry::io::tetgen_dimension(dir / "cube"), 3);
}

TEST(TetGen, ZeroBasedTwoDimensionalTriangles) {
  const auto dir = temp_dir("tri");
  write(dir / "sq.node", "4 2 0 0\n0 0 0\n1 1 0\n2 1 1\n3 0 1\n");
  write(dir / "sq.ele", "2 3 0\n0 0 1 2\n1 0 2 3\n");
  const auto m = read_tetgen<2>(dir / "sq");
  EXPECT_EQ(m.element_count(), 2u);
  EXPECT_EQ(m.elements[1][2], 3);
  EXPECT_NEAR(m.signed_volume(0) + m.signed_volume(1), 1.0, 1e-15);
}

// Clockwise triangles throughout (another generator's convention) are flipped, not rejected.
TEST(TetGen, ConsistentOppositeOrientationIsFlipped) {
  const auto dir = temp_dir("cw");
  write(dir / "sq.node", "4 2 0 0\n1 0 0\n2 1 0\n3 1 1\n4 0 1\n");
  write(dir / "sq.ele", "2 3 0\n1 1 3 2\n2 1 4 3\n");
  const auto m = read_tetgen<2>(dir / "sq");
  EXPECT_GT(m.signed_volume(0), 0);
  EXPECT_GT(m.signed_volume(1), 0);
}

TEST(TetGen, RoundTripsThroughWriteTetgen) {
  const auto dir = temp_dir("roundtrip");
  const auto m = slurry::fem::box_mesh<3>(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(2, 1, 1), Eigen::Vector3i(4, 2, 2));
  slurry::io::write_tetgen<3>(dir / "box", m);
  const auto r = read_tetgen<3>(dir / "box.node");
  ASSERT_EQ(r.vertex_count(), m.vertex_count());
  ASSERT_EQ(r.element_count(), m.element_count());
  for (std::size_t i = 0; i < m.vertex_count(); ++i) EXPECT_EQ(r.x[i], m.x[i]);
  for (std::size_t e = 0; e < m.element_count(); ++e) EXPECT_EQ(r.elements[e], m.elements[e]);
}

struct BadCase {
  const char* name;
  const char* node;
  const char* ele;
  const char* expected;  // substring of the message
};

const BadCase kBad[] = {
    {"missing_coordinate", "2 3 0 0\n1 0 0 0\n2 1 0\n", "1 4 0\n1 1 2 1 2\n", "m.node:3: point 1, z: missing (expected a number)"},
    {"not_a_number", "1 3 0 0\n1 0 zero 0\n", "1 4 0\n1 1 1 1 1\n", "m.node:2: point 0, y: expected a finite number, got \"zero\""},
    {"wrong_dimension", "1 2 0 0\n1 0 0\n", "1 4 0\n", "m.node:1: dimension: expected 3 (the scene's dimension), got 2"},
    {"first_index", "1 3 0 0\n5 0 0 0\n", "1 4 0\n", "m.node:2: point 0, index: expected 0 or 1"},
    {"gap_in_indices", "3 3 0 0\n1 0 0 0\n3 1 0 0\n4 0 1 0\n", "1 4 0\n",
     "m.node:3: point 1, index: expected 2 (points numbered consecutively), got 3"},
    {"truncated_node", "4 3 0 0\n1 0 0 0\n2 1 0 0\n", "1 4 0\n", "m.node:3: the file ends early (expected point 3 of 4)"},
    {"extra_value", "4 3 0 0\n1 0 0 0 7\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "1 4 0\n1 1 2 3 4\n",
     "m.node:2: point 0: unexpected extra value \"7\""},
    {"quadratic_tets", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "1 10 0\n",
     "m.ele:1: vertices per element: expected 4 (linear tetrahedra), got 10"},
    {"index_out_of_range", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "# one tet\n1 4 0\n1 1 2 3 9\n",
     "m.ele:3: element 0, vertex 3: expected a point index in [1, 4], got 9"},
    {"degenerate", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 1 0\n", "1 4 0\n1 1 2 3 4\n",
     "m.ele:2: element 1: is degenerate (zero volume; expected four points not in one plane)"},
    {"repeated_vertex", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "1 4 0\n1 1 2 2 4\n",
     "m.ele:2: element 1: repeats point 2"},
    {"inverted", "5 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n", "3 4 0\n1 1 2 3 4\n2 1 2 3 5\n3 2 3 1 4\n",
     "m.ele:3: element 2: is inverted: its orientation is opposite to that of the other 2 elements"},
    {"extra_element", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "1 4 0\n1 1 2 3 4\n2 1 2 3 4\n",
     "m.ele:3: end of file: expected no more elements after 1"},
    // Headers announcing 2^30 items in a short file fail at its end, before allocating them.
    {"node_header_2_30", "1073741824 3 0 0\n1 0 0 0\n", "1 4 0\n", "m.node:2: the file ends early (expected point 2 of 1073741824)"},
    {"ele_header_2_30", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", "1073741824 4 0\n1 1 2 3 4\n",
     "m.ele:2: the file ends early (expected element 2 of 1073741824)"},
};

class BadTetGen : public testing::TestWithParam<BadCase> {};

TEST_P(BadTetGen, MessageNamesFileLineFieldAndExpectation) {
  const auto dir = temp_dir(GetParam().name);
  write(dir / "m.node", GetParam().node);
  write(dir / "m.ele", GetParam().ele);
  try {
    read_tetgen<3>(dir / "m");
    FAIL() << "accepted a bad mesh";
  } catch (const IoError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(GetParam().expected), std::string::npos) << "message: " << msg << "\nexpected: " << GetParam().expected;
  }
}

INSTANTIATE_TEST_SUITE_P(Table, BadTetGen, testing::ValuesIn(kBad),
                         [](const testing::TestParamInfo<BadCase>& i) { return std::string(i.param.name); });

TEST(TetGen, MissingFileIsAnIoErrorNamingIt) {
  try {
    read_tetgen<3>("/nonexistent/mesh");
    FAIL();
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/mesh.node: no such file (expected a TetGen mesh file)"), std::string::npos) << e.what();
  }
}

}  // namespace
