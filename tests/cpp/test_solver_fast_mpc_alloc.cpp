// solve() must not touch the heap: every allocation path of this executable (operator new/delete
// and the C allocator) is replaced by counting wrappers, and the count must not move across
// solve() calls in both modes, warm and cold, feasible and infeasible, and with bad input.
#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <cstdlib>

#include "alloc_counter.hpp"
#include "flight_sw/solver/fast_mpc.hpp"
#include "test_solver_problems.hpp"

using namespace rvd::solver;
using namespace rvd::solver::testing;
using rvd::testing::allocations_during;

TEST_CASE("the counters see allocations") {
  MESSAGE("allocations counted by " << std::string(rvd::testing::kAllocationCounting));
  const long n = allocations_during([] {
    Vector v = Vector::Ones(100);
    void* volatile p = std::malloc(16);  // volatile: the compiler may not elide the pair
    std::free(p);
    CHECK(v.sum() == 100.0);
  });
  CHECK(n >= 2);  // Eigen's malloc and the explicit one (a sanitizer may add its own)
  const long m = allocations_during([] {
    int* volatile p = new int(3);
    CHECK(*p == 3);
    delete p;
  });
  CHECK(m >= 1);  // operator new
}

TEST_CASE("solve() allocates nothing, in every mode and outcome") {
  for (int N : {5, 30}) {
    OcpQp qp = docking_like(N, 0.0);
    OcpQp bad = qp;
    bad.q[2](1) = std::nan("");
    OcpQp infeasible = qp;
    infeasible.d[N](0) = -1e3;  // the cone's first facet pushed far out of reach: no plan exists
    OcpQp reweighted = qp;  // other weights: the active-set path condenses again inside solve()
    reweighted.Q[1] *= 2.0;
    reweighted.R[0] *= 0.5;
    OcpQp turned = qp;  // new row values on the same nonzeros (a turning target's cone): taken in place
    turned.C[N] *= 1.01;
    OcpQp reshaped = qp;  // other nonzeros: every row prepared again
    reshaped.C[1].setConstant(1e-3);
    reshaped.d[1].setConstant(1e3);
    Vector x0 = docking_x0();

    Vector x1 = x0;  // the next period's initial state: the plan's x1 (sized before counting)
    FastMpcSolver converged(qp.dims);
    FastMpcSolver barrier(qp.dims, fixed_barrier_settings(1e-3, 30));
    Status s1 = Status::InvalidInput, s2 = s1, s3 = s1, s4 = s1, s5 = s1, s6 = s1, s7 = s1, s8 = s1, s9 = s1, s10 = s1;
    int ipm_iterations = -1;
    const long n = allocations_during([&] {
      s1 = converged.solve(qp, x0);  // cold (the active set: condenses A, B, Q, R first)
      ipm_iterations = converged.info().iterations;
      x1 = converged.x()[1];
      converged.shift_warm_start();
      s2 = converged.solve(qp, x1);  // warm
      s3 = barrier.solve(qp, x0);    // cold: primal-dual start, then Newton
      x1 = barrier.x()[1];
      barrier.shift_warm_start();
      s4 = barrier.solve(qp, x1);  // warm
      s5 = converged.solve(infeasible, x0);
      s6 = converged.solve(bad, x0);
      converged.settings().time_limit_us = 1e-3;
      converged.solve(qp, x0);
      converged.settings().time_limit_us = 0;
      s7 = converged.solve(reweighted, x0);
      s8 = converged.solve(turned, x0);
      s9 = converged.solve(reshaped, x0);
      s10 = converged.solve(qp, x0);
    });
    CHECK(n == 0);
    CHECK(ipm_iterations == 0);  // the active-set path answered
    CHECK(s7 == Status::Solved);
    CHECK(s8 == Status::Solved);
    CHECK(s9 == Status::Solved);
    CHECK(s10 == Status::Solved);
    CHECK(s1 == Status::Solved);
    CHECK(s2 == Status::Solved);
    CHECK(s3 == Status::Solved);
    CHECK(s4 == Status::Solved);
    CHECK(s5 == Status::Infeasible);
    CHECK(s6 == Status::InvalidInput);
  }
  // The generic-size path (nx != 6).
  Vector x0;
  const OcpQp planar = planar_like(15, x0);
  FastMpcSolver converged(planar.dims), barrier(planar.dims, fixed_barrier_settings(1e-4, 40));
  Status a = Status::InvalidInput, b = a, c = a;
  const long n = allocations_during([&] {
    a = converged.solve(planar, x0);
    b = barrier.solve(planar, x0);
    barrier.shift_warm_start();
    c = barrier.solve(planar, x0);
  });
  CHECK(n == 0);
  CHECK(a == Status::Solved);
  CHECK(b == Status::Solved);
  CHECK((c == Status::Solved || c == Status::MaxIter));
}
