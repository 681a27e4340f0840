// The QP data container: sizes follow the dimensions, bad shapes and NaN are reported.
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/solver/ocp_qp.hpp"

using namespace rvd::solver;

TEST_CASE("uniform dimensions size every block") {
  OcpQp qp(OcpQpDims::uniform(4, 6, 3, 2, 0));
  CHECK(qp.validate().empty());
  CHECK(qp.A.size() == 4);
  CHECK(qp.R.size() == 5);
  CHECK(qp.R[4].rows() == 0);
  CHECK(qp.D[4].cols() == 0);
  CHECK(qp.C[2].rows() == 2);
}

TEST_CASE("validate reports wrong sizes and NaN") {
  OcpQp qp(OcpQpDims::uniform(3, 6, 3, 1));
  qp.B[1].resize(6, 2);
  CHECK(qp.validate().find("B[1]") != std::string::npos);
  qp.B[1].setZero(6, 3);
  qp.q[2](0) = std::nan("");
  CHECK(qp.validate().find("q[2] has NaN") != std::string::npos);
  OcpQpDims bad = OcpQpDims::uniform(3, 6, 3, 1);
  bad.nu.pop_back();
  CHECK(!bad.validate().empty());
}
