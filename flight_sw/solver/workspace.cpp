#include "flight_sw/solver/workspace.hpp"

#include <algorithm>

#include "flight_sw/solver/active_set.hpp"

namespace rvd::solver::detail {

Workspace::Workspace(const OcpQpDims& dims, ActiveSet* dense) : dims_(dims) {
  N = dims.N;
  nx = dims.nx;
  for (int i = 0; i <= N; ++i) {
    nu_max = std::max(nu_max, dims.nu[i]);
    rows += dims.nc[i];
    inputs += dims.nu[i];
  }
  fixed_kernels = nx == 6;
  for (int i = 0; i < N; ++i) fixed_kernels = fixed_kernels && dims.nu[i] == 3;
  fixed_kernels = fixed_kernels && (dims.nu[N] == 0 || dims.nu[N] == 3);
  Arena a;
  carve(a);  // plan: count the bytes
  if (dense) dense->carve(a);
  bytes_ = a.used() + 64;
  block_.reset(new unsigned char[bytes_]);
  auto base = reinterpret_cast<unsigned char*>((reinterpret_cast<size_t>(block_.get()) + 63) / 64 * 64);
  a.start(base);
  carve(a);  // create
  if (dense) dense->carve(a), dense->init();
  for (int i = 0; i <= N; ++i) {
    nu[i] = dims.nu[i];
    nc[i] = dims.nc[i];
    uo[i + 1] = uo[i] + nu[i];
    ro[i + 1] = ro[i] + nc[i];
    lo[i + 1] = lo[i] + nu[i] * nu[i];
  }
  for (int k = 0; k < rows; ++k) act[k] = 1.0;
}

void Workspace::carve(Arena& a) {
  const size_t n1 = static_cast<size_t>(N) + 1, X = n1 * nx, U = inputs, M = rows, D = static_cast<size_t>(N) * nx;
  nu = a.take<int>(n1);
  uo = a.take<int>(n1 + 1);
  nc = a.take<int>(n1);
  ro = a.take<int>(n1 + 1);
  lo = a.take<int>(n1 + 1);
  b_tail = a.take<int>(n1);
  q_diag = a.take<int>(n1);
  r_diag = a.take<int>(n1);
  act = a.take<double>(M);
  soft = a.take<double>(M);
  ptr = a.take<int>(M + 1);
  mid = a.take<int>(M + 1);
  col = a.take<int>(M * (nu_max + nx));
  val = a.take<double>(M * (nu_max + nx));
  ub_row = a.take<int>(U);
  soft_list = a.take<int>(M);
  for (int** v : {&srows.bu_row, &srows.bu_idx, &srows.bx_row, &srows.bx_idx, &srows.gen_row, &srows.gen_uo,
                  &srows.gen_xo, &srows.gen_end})
    *v = a.take<int>(M);
  srows.bu_val = a.take<double>(M);
  srows.bx_val = a.take<double>(M);
  lb_row = a.take<int>(U);
  x = a.take<double>(X);
  u = a.take<double>(U);
  pi = a.take<double>(D);
  for (double** v : {&t, &lam, &sig, &mu, &dv, &zs, &Zs, &rin, &rsig, &gz, &w, &weff, &hs, &rc, &rcs, &vrow, &dt_aff,
                     &dlam_aff, &dsig_aff, &dmu_aff, &sigt, &inv_t, &inv_s, &inv_h, &asoft, &inv_lam, &inv_mu})
    *v = a.take<double>(M);
  rdx = a.take<double>(X);
  rdu = a.take<double>(U);
  rdyn = a.take<double>(D);
  gx = a.take<double>(X);
  gu = a.take<double>(U);
  P = a.take<double>(n1 * nx * nx);
  size_t uu = 0, ux = 0;
  for (int i = 0; i <= N; ++i) {
    const size_t m = dims_.nu[i];
    uu += m * m;
    ux += m * nx;
  }
  L = a.take<double>(uu);
  Y = a.take<double>(ux);
  l = a.take<double>(U);
  p = a.take<double>(X);
  for (Step* s : {&step, &spare, &corr}) {
    s->dx = a.take<double>(X);
    s->du = a.take<double>(U);
    s->dpi = a.take<double>(D);
    s->dt = a.take<double>(M);
    s->dlam = a.take<double>(M);
    s->dsig = a.take<double>(M);
    s->dmu = a.take<double>(M);
  }
  edyn = a.take<double>(D);
  s_xx = a.take<double>(static_cast<size_t>(nx) * nx);
  s_xx2 = a.take<double>(static_cast<size_t>(nx) * nx);
  s_ux = a.take<double>(static_cast<size_t>(nu_max) * nx);
  tn = a.take<double>(nx);
  tm = a.take<double>(nu_max + nx);
  xt = a.take<double>(X);
  ut = a.take<double>(U);
  pit = a.take<double>(D);
}

}  // namespace rvd::solver::detail
