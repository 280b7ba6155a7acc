// Mesh file I/O: round trips in every format and encoding, malformed input, templates, atomic writes.
// Run: cmake --build build -j2 && ./build/larap_tests --gtest_filter='MeshIo*'
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include "mesh_io/writers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using larap::PolygonMesh;

namespace {

// A fresh directory per test, removed afterwards.
class MeshIo : public ::testing::Test {
 protected:
  void SetUp() override {
    std::random_device rd;
    dir_ = fs::temp_directory_path() / ("larap_io_" + std::to_string(rd()) + "_" + std::to_string(rd()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  std::string write(const std::string& name, const std::string& bytes) const {
    std::ofstream(path(name), std::ios::binary) << bytes;
    return path(name);
  }
  fs::path dir_;
};

std::string slurp(const std::string& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// Triangle, quad and pentagon over 7 vertices whose coordinates need all 17 digits.
PolygonMesh mixed_mesh() {
  PolygonMesh m;
  m.vertices.resize(7, 3);
  m.vertices << 0.1, 1.0 / 3.0, -0.0,  //
      1e-300, 1e300, -2.5,            //
      3.141592653589793, 2.718281828459045, 1.4142135623730951,  //
      -7, 8, 9,                       //
      123456789.123456789, -1e-17, 5e-324,  //
      0.30000000000000004, 1, 2,      //
      -1, -2, -3;
  m.face_offsets = {0, 3, 7, 12};
  m.face_indices = {0, 1, 2, 0, 2, 3, 4, 6, 5, 4, 3, 2};
  return m;
}

PolygonMesh point_cloud() {
  PolygonMesh m;
  m.vertices.resize(2, 3);
  m.vertices << 1, 2, 3, 4, 5, 6;
  return m;
}

void expect_same(const PolygonMesh& a, const PolygonMesh& b) {
  ASSERT_EQ(a.num_vertices(), b.num_vertices());
  for (int64_t i = 0; i < a.num_vertices(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double x = a.vertices(i, c), y = b.vertices(i, c);
      EXPECT_EQ(std::memcmp(&x, &y, sizeof x), 0) << "vertex " << i << " coord " << c << ": " << x << " vs " << y;
    }
  EXPECT_EQ(a.face_offsets, b.face_offsets);
  EXPECT_EQ(a.face_indices, b.face_indices);
}

// Expects parse `fn(text)` to throw ParseError whose message contains `what`.
template <class Fn>
void expect_parse_error(Fn fn, const std::string& text, const std::string& what) {
  try {
    fn(text, "bad");
    ADD_FAILURE() << "no ParseError for input:\n" << text;
  } catch (const larap::ParseError& e) {
    EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << "message: " << e.what();
    EXPECT_EQ(std::string(e.what()).rfind("bad:", 0), 0u) << "message: " << e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "wrong exception type: " << e.what();
  }
}

const auto obj = [](const std::string& s, const std::string& n) { return larap::parse_obj(s, n); };
const auto ply = [](const std::string& s, const std::string& n) { return larap::parse_ply(s, n); };
const auto off = [](const std::string& s, const std::string& n) { return larap::parse_off(s, n); };

// Binary PLY writer for tests: values given as doubles, packed as `type` in either byte order.
struct PlyBuilder {
  bool big;
  std::string out;
  template <class T>
  void put(double v) {
    T t = static_cast<T>(v);
    unsigned char b[sizeof(T)];
    std::memcpy(b, &t, sizeof(T));
    const bool host_big = [] {
      const uint16_t one = 1;
      unsigned char c;
      std::memcpy(&c, &one, 1);
      return c == 0;
    }();
    if (big != host_big) std::reverse(b, b + sizeof(T));
    out.append(reinterpret_cast<const char*>(b), sizeof(T));
  }
};

}  // namespace

// ------------------------------------------------------------------ round trips

TEST_F(MeshIo, RoundTripEveryFormatExactly) {
  const PolygonMesh m = mixed_mesh();
  for (const char* name : {"a.obj", "b.ply", "c.off", "D.OBJ", "e.PLY"}) {
    larap::save_mesh(path(name), m);
    SCOPED_TRACE(name);
    expect_same(m, larap::load_mesh(path(name)));
    EXPECT_FALSE(fs::exists(path(name) + ".tmp"));
  }
  larap::save_mesh(path("ascii.ply"), m, /*ascii=*/true);
  EXPECT_EQ(slurp(path("ascii.ply")).find("format ascii 1.0"), slurp(path("ascii.ply")).find("format"));
  expect_same(m, larap::load_mesh(path("ascii.ply")));
  EXPECT_NE(slurp(path("b.ply")).find("format binary_little_endian 1.0"), std::string::npos);
}

TEST_F(MeshIo, PointCloudsAreValidEverywhere) {
  const PolygonMesh m = point_cloud();
  for (const char* name : {"p.obj", "p.ply", "p.off"}) {
    larap::save_mesh(path(name), m);
    const PolygonMesh back = larap::load_mesh(path(name));
    expect_same(m, back);
    EXPECT_EQ(back.num_faces(), 0);
  }
}

TEST_F(MeshIo, LargeFacesUseWidePlyCounts) {
  PolygonMesh m;
  m.vertices.resize(300, 3);
  for (int i = 0; i < 300; ++i) m.vertices.row(i) << std::cos(i * 0.02), std::sin(i * 0.02), 0;
  m.face_offsets = {0, 300};
  for (int i = 0; i < 300; ++i) m.face_indices.push_back(i);
  larap::save_mesh(path("big.ply"), m);
  expect_same(m, larap::load_mesh(path("big.ply")));
}

TEST_F(MeshIo, PlyBigAndLittleEndianAllScalarTypes) {
  // x, y, z of each scalar type; an extra scalar and list on vertices; an unrelated element
  // between vertices and faces; an extra property after the index list.
  const char* types[] = {"char", "uchar", "short", "ushort", "int", "uint", "float", "double",
                         "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"};
  const double verts[3][3] = {{0, 1, 2}, {3, 4, 5}, {6, 7, 126}};
  for (const bool big : {false, true})
    for (const char* type : types) {
      SCOPED_TRACE(std::string(type) + (big ? " big" : " little"));
      const std::string t = type;
      PlyBuilder b{big, ""};
      b.out = std::string("ply\nformat ") + (big ? "binary_big_endian" : "binary_little_endian") +
              " 1.0\ncomment test\nobj_info x\nelement vertex 3\nproperty " + t + " x\nproperty " + t +
              " y\nproperty " + t + " z\nproperty uchar red\nproperty list ushort float uv\n"
              "element edge 2\nproperty int a\nproperty list uchar short b\n"
              "element face 2\nproperty list uint16 uint vertex_indices\nproperty float quality\nend_header\n";
      auto put_scalar = [&](double v) {
        if (t == "char" || t == "int8") b.put<int8_t>(v);
        else if (t == "uchar" || t == "uint8") b.put<uint8_t>(v);
        else if (t == "short" || t == "int16") b.put<int16_t>(v);
        else if (t == "ushort" || t == "uint16") b.put<uint16_t>(v);
        else if (t == "int" || t == "int32") b.put<int32_t>(v);
        else if (t == "uint" || t == "uint32") b.put<uint32_t>(v);
        else if (t == "float" || t == "float32") b.put<float>(v);
        else b.put<double>(v);
      };
      for (const auto& v : verts) {
        for (double c : v) put_scalar(c);
        b.put<uint8_t>(9);
        b.put<uint16_t>(2);
        b.put<float>(0.5);
        b.put<float>(0.25);
      }
      for (int e = 0; e < 2; ++e) {
        b.put<int32_t>(e);
        b.put<uint8_t>(e);
        for (int k = 0; k < e; ++k) b.put<int16_t>(k);
      }
      b.put<uint16_t>(3);
      for (double i : {0, 1, 2}) b.put<uint32_t>(i);
      b.put<float>(1);
      b.put<uint16_t>(1);
      b.put<uint32_t>(2);
      b.put<float>(1);
      const PolygonMesh m = larap::parse_ply(b.out, "t.ply");
      ASSERT_EQ(m.num_vertices(), 3);
      for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c) EXPECT_EQ(m.vertices(i, c), verts[i][c]);
      EXPECT_EQ(m.face_offsets, (std::vector<int64_t>{0, 3, 4}));
      EXPECT_EQ(m.face_indices, (std::vector<int64_t>{0, 1, 2, 2}));
    }
}

TEST_F(MeshIo, PlyAsciiVariants) {
  const std::string text =
      "ply\r\nformat ascii 1.0\r\ncomment crlf header\r\nelement vertex 4\r\nproperty float x\r\n"
      "property float y\r\nproperty float z\r\nproperty list uchar float n\r\nelement face 2\r\n"
      "property list int int vertex_index\r\nend_header\r\n"
      "0 0 0 0\r\n1 0 0 2 0.5 0.5\r\n1 1 0 0\r\n0 1 +1e-3 0\r\n3 0 1 2\r\n4 0 1 2 3\r\n";
  const PolygonMesh m = larap::parse_ply(text);
  EXPECT_EQ(m.num_vertices(), 4);
  EXPECT_EQ(m.vertices(3, 2), 1e-3);
  EXPECT_EQ(m.face_offsets, (std::vector<int64_t>{0, 3, 7}));
}

TEST_F(MeshIo, ObjVariants) {
  const std::string text =
      "\xEF\xBB\xBF# BOM and comments\r\nmtllib x.mtl\r\no thing\r\n"
      "v 0 0 0 1 0 0\r\nv 1 0 0 0 1 0\r\nv 1 1 0   # trailing comment\r\nv 0 1 \\\r\n 0\r\n"
      "vt 0 0\nvn 0 0 1\ng group\nusemtl m\ns 1\n"
      "f 1/1/1 2/1/1 3/1/1\nf 1//1 3//1 4//1\nf 1/1 2/1 3/1 4/1\nf -4 -3 \\\n -2\nl 1 2\np 1\n";
  const PolygonMesh m = larap::parse_obj(text);
  ASSERT_EQ(m.num_vertices(), 4);
  EXPECT_EQ(m.vertices(3, 1), 1);
  EXPECT_EQ(m.vertices(3, 2), 0);
  EXPECT_EQ(m.face_offsets, (std::vector<int64_t>{0, 3, 6, 10, 13, 15}));  // `l 1 2`: a loose edge
  EXPECT_EQ(m.face_indices, (std::vector<int64_t>{0, 1, 2, 0, 2, 3, 0, 1, 2, 3, 0, 1, 2, 0, 1}));
}

TEST_F(MeshIo, ObjRelativeIndicesCountVerticesSoFar) {
  const PolygonMesh m = larap::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf -1 -2 1\n");
  EXPECT_EQ(m.face_indices, (std::vector<int64_t>{0, 1, 2, 3, 2, 0}));
  // A positive index may refer to a vertex defined later in the file.
  EXPECT_EQ(larap::parse_obj("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").num_faces(), 1);
}

TEST_F(MeshIo, OffVariants) {
  EXPECT_EQ(larap::parse_off("COFF\n3 1 0\n0 0 0 1 0 0 1\n1 0 0 0 1 0 1\n0 1 0 0 0 1 1\n3 0 1 2 255 0 0\n")
                .face_indices,
            (std::vector<int64_t>{0, 1, 2}));
  const PolygonMesh m = larap::parse_off("NOFF 3 1 0 # counts on the magic line\n\n# c\n0 0 0 0 0 1\r\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 2 1 0\n");
  EXPECT_EQ(m.face_indices, (std::vector<int64_t>{2, 1, 0}));
  EXPECT_EQ(larap::parse_off("OFF\n2 0\n1 2 3\n4 5 6\n").num_vertices(), 2);
}

// ------------------------------------------------------------------ malformed input

TEST_F(MeshIo, MalformedObjThrowsParseError) {
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  expect_parse_error(obj, "", "no vertices");
  expect_parse_error(obj, "# only a comment\n", "no vertices");
  expect_parse_error(obj, tri + "f 1 2 4\n", "bad:4: face vertex index 4 is out of range");
  expect_parse_error(obj, tri + "f 0 1 2\n", "bad:4: face vertex index 0");
  expect_parse_error(obj, tri + "f -4 1 2\n", "points before the first vertex");
  expect_parse_error(obj, tri + "f 1 2 x\n", "bad face vertex 'x'");
  expect_parse_error(obj, tri + "f 1/x 2 3\n", "bad face vertex");
  expect_parse_error(obj, tri + "f 1/1/1/1 2 3\n", "bad face vertex");
  expect_parse_error(obj, tri + "f 99999999999999999999 1 2\n", "bad face vertex");
  expect_parse_error(obj, tri + "f\n", "face without vertices");
  expect_parse_error(obj, "v 0 0\n", "bad:1: vertex needs 3 coordinates");
  expect_parse_error(obj, "v 0 0 zero\n", "'zero' is not a number");
  expect_parse_error(obj, "v 0 0 ++1\n", "not a number");
  expect_parse_error(obj, "v 0 0 1e999\n", "non-finite");
  expect_parse_error(obj, "v nan 0 0\n", "non-finite");
  expect_parse_error(obj, "v 0 0 inf\n", "non-finite");
}

TEST_F(MeshIo, MalformedPlyThrowsParseError) {
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
  const std::string face = "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string verts = "0 0 0\n1 0 0\n0 1 0\n";
  expect_parse_error(ply, "", "not a PLY file");
  expect_parse_error(ply, "plyx\n", "not a PLY file");
  expect_parse_error(ply, head, "header has no end_header");
  expect_parse_error(ply, "ply\nelement vertex 1\nproperty float x\nend_header\n", "no format line");
  expect_parse_error(ply, "ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown PLY encoding");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nproperty float x\nend_header\n", "property before any element");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex -1\nend_header\n", "negative element count");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1x\nend_header\n", "bad element count");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "no property y");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement face 0\nend_header\n", "no vertex element");
  expect_parse_error(ply, head + "property quad w\nend_header\n", "unknown property type");
  expect_parse_error(ply, head + "blah\nend_header\n", "unknown header keyword");
  expect_parse_error(ply, head + "element vertex 3\nend_header\n", "declared twice");
  expect_parse_error(ply, head + "element face 1\nproperty list float int vertex_indices\nend_header\n" + verts + "3 0 1 2\n",
                     "count type must be an integer");
  expect_parse_error(ply, head + "element face 1\nproperty list uchar float vertex_indices\nend_header\n" + verts + "3 0 1 2\n",
                     "must be a list of an integer type");
  expect_parse_error(ply, head + "element face 1\nproperty uchar flags\nend_header\n" + verts + "1\n", "no vertex_indices");
  expect_parse_error(ply, head + face + verts + "3 0 1 3\n", "bad:13: face 0 refers to vertex 3");
  expect_parse_error(ply, head + face + verts + "3 0 -1 2\n", "refers to vertex -1");
  expect_parse_error(ply, head + face + verts + "3 0 1\n", "unexpected end of file");
  expect_parse_error(ply, head + face + verts + "0\n", "face 0 has no vertices");
  expect_parse_error(ply, head + face + verts + "200 0 1 2\n", "list of 200 values");
  expect_parse_error(ply, head + face + "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n", "expected a number, got 'zero'");
  expect_parse_error(ply, head + face + verts + "3 0 1 2.5\n", "expected an integer");
  expect_parse_error(ply, head + face + "0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n", "non-finite");
  // Counts the remaining bytes cannot hold are refused before anything is allocated.
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
                          "property float z\nend_header\n0 0 0\n", "declares 1000000000 items but only");
  expect_parse_error(ply, "ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty float x\n"
                          "property float y\nproperty float z\nend_header\n", "too large");
  expect_parse_error(ply, "ply\nformat binary_little_endian 1.0\nelement vertex 99999999999999999999999\nend_header\n",
                     "bad element count");
}

TEST_F(MeshIo, MalformedBinaryPlyReportsByteOffsets) {
  const std::string head =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list int int vertex_indices\nend_header\n";
  PlyBuilder b{false, head};
  for (int i = 0; i < 9; ++i) b.put<float>(i % 2);
  const std::string verts = b.out;
  // Truncated inside the vertices.
  expect_parse_error(ply, verts.substr(0, verts.size() - 5), "declares 3 items but only 31 bytes remain");
  // Absurd list length.
  PlyBuilder huge{false, verts};
  huge.put<int32_t>(1 << 30);
  huge.put<int32_t>(0);
  expect_parse_error(ply, huge.out, "bad:byte " + std::to_string(verts.size() + 4) + ": list of 1073741824 values");
  // Negative list length.
  PlyBuilder neg{false, verts};
  neg.put<int32_t>(-3);
  expect_parse_error(ply, neg.out, "negative list length -3");
  // Truncated inside a face.
  PlyBuilder cut{false, verts};
  cut.put<int32_t>(3);
  cut.put<int32_t>(0);
  cut.put<int32_t>(1);
  expect_parse_error(ply, cut.out + "\x02", "list of 3 values but only");
  // Non-finite float coordinate.
  PlyBuilder inf{false, head};
  inf.put<float>(std::numeric_limits<float>::infinity());
  for (int i = 0; i < 8; ++i) inf.put<float>(0);
  inf.put<int32_t>(3);
  for (int i = 0; i < 3; ++i) inf.put<int32_t>(i);
  expect_parse_error(ply, inf.out, "non-finite");
}

TEST_F(MeshIo, MalformedOffThrowsParseError) {
  expect_parse_error(off, "", "empty file");
  expect_parse_error(off, "# nothing\n\n", "empty file");
  expect_parse_error(off, "OFX\n1 0 0\n0 0 0\n", "not an OFF file");
  expect_parse_error(off, "4OFF\n1 0 0\n0 0 0 0\n", "unsupported OFF variant");
  expect_parse_error(off, "OFF BINARY\n", "binary OFF");
  expect_parse_error(off, "OFF\n", "missing vertex/face counts");
  expect_parse_error(off, "OFF\n3\n", "needs vertex and face counts");
  expect_parse_error(off, "OFF\n3 1 0 7\n", "too many values");
  expect_parse_error(off, "OFF\n-1 0 0\n", "negative count");
  expect_parse_error(off, "OFF\nthree 1 0\n", "bad count 'three'");
  expect_parse_error(off, "OFF\n1000000000000 0 0\n0 0 0\n", "exceed what the file's");
  expect_parse_error(off, "OFF\n3 0 0\n0 0 0\n1 1 1\n# no third vertex, only a comment\n", "file ends after 2 of 3 vertices");
  expect_parse_error(off, "OFF\n1 0 0\n0.0 0.0\n", "vertex needs 3 coordinates");
  expect_parse_error(off, "OFF\n1 0 0\n0 0 x\n", "'x' is not a number");
  expect_parse_error(off, "OFF\n1 0 0\nnan 0 0\n", "non-finite");
  const std::string tri = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n";
  expect_parse_error(off, tri + "3 0 1 3\n", "bad:6: face vertex 3 is out of range");
  expect_parse_error(off, tri + "3 0 -1 2\n", "face vertex -1 is out of range");
  expect_parse_error(off, tri + "0\n", "face size 0");
  expect_parse_error(off, tri + "-3 0 1 2\n", "face size -3");
  expect_parse_error(off, tri + "x 0 1 2\n", "bad face size");
  expect_parse_error(off, tri + "1000000 0 1 2\n", "lists only 3 vertices");
  expect_parse_error(off, tri + "3 0 1 y\n", "bad face vertex 'y'");
  expect_parse_error(off, tri, "file ends after 0 of 1 faces");
}

// ------------------------------------------------------------------ regressions
// Inputs that once misbehaved (found in review before fuzzing; the fuzzers found nothing further
// in 3 x 7 minutes). Each must end in ParseError or parse cleanly, under ASan/UBSan too.

TEST_F(MeshIo, RegressionBinarySkipStopsAtTheEnd) {
  // An element nobody reads, of fixed size, claiming one byte more than remains: the block skip
  // once moved past the end (a one-byte slack meant for ascii), wrapping the remaining count.
  const std::string head =
      "ply\nformat binary_little_endian 1.0\nelement junk 2\nproperty int a\n"
      "element vertex 1\nproperty uchar x\nproperty uchar y\nproperty uchar z\nend_header\n";
  expect_parse_error(ply, head + std::string(7, '\0'), "element 'junk' declares 2 items but only 7 bytes remain");
  expect_parse_error(ply, head + std::string(10, '\0'), "element 'vertex' declares 1 items but only 2 bytes remain");
  EXPECT_EQ(larap::parse_ply(head + std::string(11, '\0')).num_vertices(), 1);
  // Same for a skipped binary list one byte short.
  const std::string list_head =
      "ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty uchar x\nproperty uchar y\n"
      "property uchar z\nproperty list uchar short extra\nend_header\n";
  expect_parse_error(ply, list_head + std::string("\0\0\0\x02\0\0\0", 7), "list of 2 values but only 3 bytes remain");
}

TEST_F(MeshIo, RegressionCountsNearTheLimits) {
  // Counts at the integer limits must not overflow the size checks.
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 1\nproperty list int int vertex_indices\nend_header\n"
                          "0 0 0\n2147483647 0\n", "list of 2147483647 values");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 1\nproperty list int int vertex_indices\nend_header\n"
                          "0 0 0\n9223372036854775807 0\n", "list of 9223372036854775807 values");
  expect_parse_error(ply, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 1\nproperty list int int vertex_indices\nend_header\n"
                          "0 0 0\n3 0 0 -9223372036854775808\n", "refers to vertex -9223372036854775808");
  expect_parse_error(off, "OFF\n9223372036854775807 9223372036854775807 0\n", "exceed what the file's");
  expect_parse_error(obj, "v 0 0 0\nf -9223372036854775808\n", "points before the first vertex");
  expect_parse_error(obj, "v 0 0 0\nf 9223372036854775807\n", "out of range");
  // A line continuation at the very end of the file.
  EXPECT_EQ(larap::parse_obj("v 0 0 0\nf 1 \\").num_faces(), 1);
  EXPECT_EQ(larap::parse_obj("v 0 0 \\\n0\\\n").num_vertices(), 1);
}

// ------------------------------------------------------------------ files

TEST_F(MeshIo, TemplateObjKeepsEverythingButPositions) {
  const std::string tpl =
      "# exported\r\nmtllib m.mtl\r\no part\r\nv 0 0 0 0.1 0.2 0.3\r\nv 1 0 0\r\nv 0 1 0 # c\r\n"
      "vt 0.5 0.5\r\nvn 0 0 1\r\ng g\r\nusemtl red\r\ns off\r\nf 1/1/1 2/1/1 3/1/1\r\n";
  write("tpl.obj", tpl);
  PolygonMesh m = larap::parse_obj(tpl);
  m.vertices << 10, 11, 12, 0.1, 0.2, 1.0 / 3.0, -5, -6, -7;
  larap::save_mesh(path("out.obj"), m, false, path("tpl.obj"));
  const std::string out = slurp(path("out.obj"));
  EXPECT_EQ(out,
            "# exported\r\nmtllib m.mtl\r\no part\r\nv 10 11 12 0.1 0.2 0.3\r\nv 0.1 0.2 0.3333333333333333\r\n"
            "v -5 -6 -7 # c\r\nvt 0.5 0.5\r\nvn 0 0 1\r\ng g\r\nusemtl red\r\ns off\r\nf 1/1/1 2/1/1 3/1/1\r\n");
  expect_same(m, larap::load_mesh(path("out.obj")));

  // Overwriting the template itself works (it is read completely before the write).
  larap::save_mesh(path("tpl.obj"), m, false, path("tpl.obj"));
  EXPECT_EQ(slurp(path("tpl.obj")), out);
  EXPECT_FALSE(fs::exists(path("tpl.obj.tmp")));
}

TEST_F(MeshIo, TemplateWithOtherVertexCountGivesPlainObj) {
  write("tpl.obj", "v 0 0 0\nv 1 0 0\nvt 0 0\nf 1/1 2/1 1/1\n");
  const PolygonMesh m = mixed_mesh();
  larap::save_mesh(path("out.obj"), m, false, path("tpl.obj"));
  const std::string out = slurp(path("out.obj"));
  EXPECT_EQ(out.find("vt"), std::string::npos);
  expect_same(m, larap::load_mesh(path("out.obj")));
  // A template is meaningless for other formats and is ignored there.
  larap::save_mesh(path("out.off"), m, false, path("tpl.obj"));
  expect_same(m, larap::load_mesh(path("out.off")));
  // A template that does not exist is an error, not silently dropped.
  EXPECT_THROW(larap::save_mesh(path("out2.obj"), m, false, path("nope.obj")), larap::FileNotFound);
  EXPECT_FALSE(fs::exists(path("out2.obj")));
}

TEST_F(MeshIo, FailedWritesKeepTheExistingFile) {
  const PolygonMesh good = mixed_mesh();
  larap::save_mesh(path("keep.obj"), good);
  const std::string before = slurp(path("keep.obj"));
  PolygonMesh bad = good;
  bad.vertices(2, 1) = std::nan("");
  EXPECT_THROW(larap::save_mesh(path("keep.obj"), bad), larap::InvalidInput);
  PolygonMesh out_of_range = good;
  out_of_range.face_indices[0] = 7;
  EXPECT_THROW(larap::save_mesh(path("keep.obj"), out_of_range), larap::InvalidInput);
  EXPECT_EQ(slurp(path("keep.obj")), before);

  // The rename onto a non-empty directory fails: the temporary file is removed again.
  fs::create_directories(path("dir.obj"));
  write("dir.obj/inside", "x");
  EXPECT_THROW(larap::save_mesh(path("dir.obj"), good), larap::IOFailure);
  EXPECT_FALSE(fs::exists(path("dir.obj.tmp")));
  EXPECT_THROW(larap::save_mesh(path("no/such/dir/x.obj"), good), larap::IOFailure);
}

TEST_F(MeshIo, LoadErrors) {
  EXPECT_THROW(larap::load_mesh(path("missing.obj")), larap::FileNotFound);
  EXPECT_THROW(larap::load_mesh(path("missing/x.ply")), larap::FileNotFound);
  fs::create_directories(path("d.off"));
  EXPECT_THROW(larap::load_mesh(path("d.off")), larap::IOFailure);
  write("t.stl", "solid");
  EXPECT_THROW(larap::load_mesh(path("t.stl")), larap::InvalidInput);
  write("trunc.obj", "v 0 0 0\nv 1 0");
  try {
    larap::load_mesh(path("trunc.obj"));
    ADD_FAILURE();
  } catch (const larap::ParseError& e) {
    EXPECT_EQ(std::string(e.what()), path("trunc.obj") + ":2: vertex needs 3 coordinates");
  }
}

TEST(MeshIoFormat, FromPathIsCaseInsensitive) {
  EXPECT_EQ(larap::format_from_path("a/b.OBJ"), larap::MeshFormat::OBJ);
  EXPECT_EQ(larap::format_from_path("x.Ply"), larap::MeshFormat::PLY);
  EXPECT_EQ(larap::format_from_path("/t/y.v2.off"), larap::MeshFormat::OFF);
  EXPECT_THROW(larap::format_from_path("x.stl"), larap::InvalidInput);
  EXPECT_THROW(larap::format_from_path("noext"), larap::InvalidInput);
  EXPECT_THROW(larap::format_from_path("dir.obj/noext"), larap::InvalidInput);
}

TEST(MeshIoShared, PublicMeshesLoad) {
#ifdef LARAP_SOURCE_DIR
  const fs::path dir = fs::path(LARAP_SOURCE_DIR) / ".." / "shared" / "data" / "meshes";
#else
  const fs::path dir = fs::path("..") / "shared" / "data" / "meshes";
#endif
  if (!fs::is_directory(dir)) GTEST_SKIP() << "no shared meshes at " << dir;
  int loaded = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string ext = entry.path().extension().string();
    if (ext != ".obj" && ext != ".off" && ext != ".ply") continue;
    SCOPED_TRACE(entry.path().string());
    const PolygonMesh m = larap::load_mesh(entry.path().string());
    EXPECT_GT(m.num_vertices(), 0);
    EXPECT_GT(m.num_faces(), 0);
    ++loaded;
  }
  EXPECT_GT(loaded, 0);
}

// ------------------------------------------------------------------ loose edges (OBJ `l`)

TEST_F(MeshIo, ObjLinesAreLooseEdges) {
  const PolygonMesh m = larap::parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nl 3 4/1 1\nl -1 -2\n", "lines");
  EXPECT_EQ(m.face_offsets, (std::vector<int64_t>{0, 3, 5, 7, 9}));
  EXPECT_EQ(m.face_indices, (std::vector<int64_t>{0, 1, 2, 2, 3, 3, 0, 3, 2}));
  ASSERT_EQ(larap::segments(m).size(), 3u);
  // Written back as `l` lines, read back the same.
  const std::string text = larap::io_detail::write_obj(m);
  EXPECT_NE(text.find("\nl 3 4\n"), std::string::npos);
  EXPECT_NE(text.find("\nf 1 2 3\n"), std::string::npos);
  const PolygonMesh back = larap::parse_obj(text, "back");
  EXPECT_EQ(back.face_offsets, m.face_offsets);
  EXPECT_EQ(back.face_indices, m.face_indices);
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  expect_parse_error(obj, tri + "l 1\n", "bad:4: line needs at least 2 vertices");
  expect_parse_error(obj, tri + "l\n", "line without vertices");
  expect_parse_error(obj, tri + "l 1 x\n", "bad line vertex 'x'");
  expect_parse_error(obj, tri + "l 1 5\n", "bad:4: line vertex index 5 is out of range");
  // A face of one repeated vertex pair stays a face when written (`l 3 3` is no line).
  PolygonMesh twice = larap::parse_obj(tri + "f 3 3\n", "twice");
  EXPECT_NE(larap::io_detail::write_obj(twice).find("\nf 3 3\n"), std::string::npos);
}
