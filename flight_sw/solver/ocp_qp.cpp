#include "flight_sw/solver/ocp_qp.hpp"

#include <sstream>

namespace rvd::solver {

OcpQpDims OcpQpDims::uniform(int N, int nx, int nu, int nc, int nu_N, int nc_N) {
  OcpQpDims d;
  d.N = N;
  d.nx = nx;
  d.nu.assign(N + 1, nu);
  d.nc.assign(N + 1, nc);
  d.nu[N] = nu_N;
  d.nc[N] = nc_N < 0 ? nc : nc_N;
  return d;
}

std::string OcpQpDims::validate() const {
  std::ostringstream err;
  if (N < 1) err << "horizon N must be >= 1 (got " << N << "); ";
  if (nx < 1) err << "nx must be >= 1 (got " << nx << "); ";
  if (static_cast<int>(nu.size()) != N + 1) err << "nu needs N+1 = " << N + 1 << " entries (got " << nu.size() << "); ";
  if (static_cast<int>(nc.size()) != N + 1) err << "nc needs N+1 = " << N + 1 << " entries (got " << nc.size() << "); ";
  for (size_t i = 0; i < nu.size(); ++i)
    if (nu[i] < 0) err << "nu[" << i << "] < 0; ";
  for (size_t i = 0; i < nc.size(); ++i)
    if (nc[i] < 0) err << "nc[" << i << "] < 0; ";
  if (!ns.empty()) {
    if (ns.size() != nc.size()) err << "ns needs N+1 = " << N + 1 << " entries or none (got " << ns.size() << "); ";
    for (size_t i = 0; i < ns.size() && i < nc.size(); ++i)
      if (ns[i] < 0 || ns[i] > nc[i]) err << "ns[" << i << "] must be in 0..nc[" << i << "]; ";
  }
  return err.str();
}

OcpQp::OcpQp(const OcpQpDims& dims_) : dims(dims_) {
  const int N = dims.N, nx = dims.nx;
  if (!dims.validate().empty()) return;  // validate() reports it; nothing sensible to size
  A.assign(N, Matrix::Zero(nx, nx));
  b.assign(N, Vector::Zero(nx));
  B.resize(N);
  for (int i = 0; i < N; ++i) B[i] = Matrix::Zero(nx, dims.nu[i]);
  Q.assign(N + 1, Matrix::Zero(nx, nx));
  q.assign(N + 1, Vector::Zero(nx));
  R.resize(N + 1);
  r.resize(N + 1);
  C.resize(N + 1);
  D.resize(N + 1);
  d.resize(N + 1);
  for (int i = 0; i <= N; ++i) {
    R[i] = Matrix::Zero(dims.nu[i], dims.nu[i]);
    r[i] = Vector::Zero(dims.nu[i]);
    C[i] = Matrix::Zero(dims.nc[i], nx);
    D[i] = Matrix::Zero(dims.nc[i], dims.nu[i]);
    d[i] = Vector::Zero(dims.nc[i]);
  }
  if (!dims.ns.empty()) {
    idxs.resize(N + 1);
    zs.resize(N + 1);
    Zs.resize(N + 1);
    for (int i = 0; i <= N; ++i) {
      idxs[i].assign(dims.ns[i], 0);
      for (int k = 0; k < dims.ns[i]; ++k) idxs[i][k] = k;  // a placeholder: callers say which rows
      zs[i] = Vector::Zero(dims.ns[i]);
      Zs[i] = Vector::Zero(dims.ns[i]);
    }
  }
}

namespace {
template <class M>
void check_block(std::ostringstream& err, const char* name, size_t i, const M& m, long rows, long cols) {
  if (m.rows() != rows || m.cols() != cols) {
    err << name << "[" << i << "] is " << m.rows() << "x" << m.cols() << ", expected " << rows << "x" << cols
        << "; ";
  } else if (!m.allFinite()) {
    err << name << "[" << i << "] has NaN or Inf; ";
  }
}
}  // namespace

std::string OcpQp::validate() const {
  std::string dims_err = dims.validate();
  if (!dims_err.empty()) return dims_err;
  std::ostringstream err;
  const size_t N = static_cast<size_t>(dims.N);
  const long nx = dims.nx;
  if (A.size() != N || B.size() != N || b.size() != N) err << "A, B, b need N = " << N << " entries; ";
  if (Q.size() != N + 1 || q.size() != N + 1 || R.size() != N + 1 || r.size() != N + 1 || C.size() != N + 1 ||
      D.size() != N + 1 || d.size() != N + 1)
    err << "Q, q, R, r, C, D, d need N+1 = " << N + 1 << " entries; ";
  if (!err.str().empty()) return err.str();
  for (size_t i = 0; i < N; ++i) {
    check_block(err, "A", i, A[i], nx, nx);
    check_block(err, "B", i, B[i], nx, dims.nu[i]);
    check_block(err, "b", i, b[i], nx, 1);
  }
  for (size_t i = 0; i <= N; ++i) {
    check_block(err, "Q", i, Q[i], nx, nx);
    check_block(err, "q", i, q[i], nx, 1);
    check_block(err, "R", i, R[i], dims.nu[i], dims.nu[i]);
    check_block(err, "r", i, r[i], dims.nu[i], 1);
    check_block(err, "C", i, C[i], dims.nc[i], nx);
    check_block(err, "D", i, D[i], dims.nc[i], dims.nu[i]);
    check_block(err, "d", i, d[i], dims.nc[i], 1);
  }
  if (dims.ns.empty()) return err.str();
  if (idxs.size() != N + 1 || zs.size() != N + 1 || Zs.size() != N + 1) {
    err << "idxs, zs, Zs need N+1 = " << N + 1 << " entries; ";
    return err.str();
  }
  for (size_t i = 0; i <= N; ++i) {
    const int ns = dims.ns[i];
    if (static_cast<int>(idxs[i].size()) != ns) err << "idxs[" << i << "] needs " << ns << " entries; ";
    check_block(err, "zs", i, zs[i], ns, 1);
    check_block(err, "Zs", i, Zs[i], ns, 1);
    for (size_t k = 0; k < idxs[i].size(); ++k) {
      const int j = idxs[i][k];
      if (j < 0 || j >= dims.nc[i]) err << "idxs[" << i << "][" << k << "] = " << j << " is not a row; ";
      for (size_t t = 0; t < k; ++t)
        if (idxs[i][t] == j) err << "idxs[" << i << "] lists row " << j << " twice; ";
    }
    if (zs[i].size() == ns && Zs[i].size() == ns && ((zs[i].array() < 0.0).any() || (Zs[i].array() < 0.0).any()))
      err << "zs[" << i << "], Zs[" << i << "] must be >= 0; ";
  }
  return err.str();
}

const char* to_string(Status s) {
  switch (s) {
    case Status::Solved: return "solved";
    case Status::MaxIter: return "max_iter";
    case Status::Infeasible: return "infeasible";
    case Status::InvalidInput: return "invalid_input";
    case Status::NumericalError: return "numerical_error";
    case Status::TimeLimit: return "time_limit";
  }
  return "unknown";
}

}  // namespace rvd::solver
