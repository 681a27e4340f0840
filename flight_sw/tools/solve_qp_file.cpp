// flight_sw's solver on the flight CPUs: solves the OCP QPs of a file one after another, each solve
// between two solve markers, so that the QEMU block profiler prices every solve as a region (the
// flight_sw side of python -m rvd_pil.bench.target_solvers; rvd_pil/bench/peer_drivers/daqp_solve_file.c
// is DAQP's).
//
//   rvd_solve_qp_file FILE
//
// FILE, little-endian, written by rvd_pil/bench/target_solvers.py: "RVDOCP01", uint32 count, then per
// QP int32 N, nx, interior_point (1: the interior point, as the guidance flies the rendezvous; 0: the
// converged mode's own choice), int32 nu[N+1], nc[N+1], ns[N+1]; per stage i < N the doubles A_i, B_i
// (column-major), b_i; per stage i <= N Q_i, R_i, q_i, r_i, C_i, D_i, d_i; per stage the int32 idxs_i
// and the doubles zs_i, Zs_i; x0.
// Per QP, as the host benchmark: the solver's settings (tol 1e-8, cold; the interior point with the
// guidance's rendezvous cold start) and setup() (the condensing, once per phase in the flight) before
// the marker, solve() inside it.
// Prints per QP: "qp K status S changes C iterations I u v v v ..." (the inputs of stages 0..N).
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "flight_sw/guidance/params.hpp"
#include "flight_sw/solver/elapsed.hpp"
#include "flight_sw/solver/fast_mpc.hpp"

namespace {

using rvd::solver::Matrix;
using rvd::solver::Vector;

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "rvd_solve_qp_file: %s\n", what);
  std::exit(2);
}

struct Reader {
  std::FILE* f;
  void bytes(void* p, size_t n) {
    if (std::fread(p, 1, n, f) != n) fail("file ends early");
  }
  int32_t i32() {
    int32_t v;
    bytes(&v, 4);
    return v;
  }
  void fill(Matrix& m) { bytes(m.data(), sizeof(double) * static_cast<size_t>(m.size())); }  // column-major
  void fill(Vector& v) { bytes(v.data(), sizeof(double) * static_cast<size_t>(v.size())); }
};

void mark(rvd::MarkerOp op, uint32_t step) {
  std::uint64_t slot = rvd::kSlotRequest;
  rvd::marker_call(op, step, &slot);
}

}  // namespace

int main(int argc, char** argv) {
  using namespace rvd::solver;
  if (argc != 2) fail("usage: rvd_solve_qp_file FILE");
  Reader in{std::fopen(argv[1], "rb")};
  if (!in.f) fail("cannot open the QP file");
  char magic[8];
  in.bytes(magic, 8);
  if (std::memcmp(magic, "RVDOCP01", 8) != 0) fail("not an OCP-QP file (magic RVDOCP01)");
  uint32_t count;
  in.bytes(&count, 4);
  // One QP and one solver per shape, reused: the QP filled in place and the solver set up again for
  // each, as a guidance does (its QP and solver live as long as the phase). Stable addresses also
  // keep the cache model's view as a flight's, where the solve reads what the last one touched.
  struct Slot {
    OcpQpDims dims;
    bool interior_point;
    OcpQp qp;
    FastMpcSolver solver;
    Vector x0;
  };
  std::vector<std::unique_ptr<Slot>> slots;
  auto same = [](const OcpQpDims& a, const OcpQpDims& b) {
    return a.N == b.N && a.nx == b.nx && a.nu == b.nu && a.nc == b.nc && a.ns == b.ns;
  };
  for (uint32_t k = 0; k < count; ++k) {
    OcpQpDims dims;
    dims.N = in.i32();
    dims.nx = in.i32();
    const bool interior_point = in.i32() != 0;
    if (dims.N < 1 || dims.N > 1000 || dims.nx < 1 || dims.nx > 100) fail("implausible QP dimensions");
    for (auto* v : {&dims.nu, &dims.nc, &dims.ns}) {
      v->resize(dims.N + 1);
      for (int& x : *v)
        if ((x = in.i32()) < 0 || x > 10000) fail("implausible QP dimensions");
    }
    bool soft = false;
    for (int s : dims.ns) soft = soft || s > 0;
    if (!soft) dims.ns.clear();
    if (const std::string err = dims.validate(); !err.empty()) fail(err.c_str());
    Slot* slot = nullptr;
    for (auto& s : slots)
      if (s->interior_point == interior_point && same(s->dims, dims)) slot = s.get();
    if (!slot) {
      Settings s;  // as the Python binding's OcpSolver(nx, nu, nc, ns, mode, tol=1e-8, warm_start=False)
      s.tol = 1e-8;
      s.max_iter = 100;
      s.warm_start = false;
      if (interior_point) {  // the rendezvous' cold start as the guidance sets it (the host benchmark alike)
        s.active_set_max_inputs = 0;
        s.cold_slack_floor = rvd::guidance::GuidanceParams::default_rendezvous().solver.cold_slack_floor;
      }
      slots.push_back(std::unique_ptr<Slot>(new Slot{dims, interior_point, OcpQp(dims), FastMpcSolver(dims, s), Vector(dims.nx)}));
      slot = slots.back().get();
    }
    OcpQp& qp = slot->qp;
    for (int i = 0; i < dims.N; ++i) in.fill(qp.A[i]), in.fill(qp.B[i]), in.fill(qp.b[i]);
    for (int i = 0; i <= dims.N; ++i)
      in.fill(qp.Q[i]), in.fill(qp.R[i]), in.fill(qp.q[i]), in.fill(qp.r[i]), in.fill(qp.C[i]), in.fill(qp.D[i]),
          in.fill(qp.d[i]);
    for (int i = 0; i <= dims.N && soft; ++i) {
      for (int& j : qp.idxs[i]) j = in.i32();
      in.fill(qp.zs[i]), in.fill(qp.Zs[i]);
    }
    in.fill(slot->x0);
    if (const std::string err = qp.validate(); !err.empty()) fail(("QP " + std::to_string(k) + ": " + err).c_str());
    FastMpcSolver& solver = slot->solver;
    solver.setup(qp);
    mark(rvd::kMarkerBegin, k);
    const Status st = solver.solve(qp, slot->x0);
    mark(rvd::kMarkerEnd, k);
    const Info& info = solver.info();
    std::printf("qp %u status %s changes %d iterations %d u", k, to_string(st), info.active_set_changes, info.iterations);
    for (const Vector& u : solver.u())
      for (long j = 0; j < u.size(); ++j) std::printf(" %.17g", u(j));
    std::printf("\n");
  }
  std::fclose(in.f);
  return 0;
}
