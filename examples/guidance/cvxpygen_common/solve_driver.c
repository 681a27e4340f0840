/* solve_driver.c: one generated problem (generate.py's output for one phase and horizon) solved outside
 * the flight software, for studies of the generated solver (bench_problem.py builds and runs it).
 *
 *   solve_driver PARAMS [REPEAT] [SETTING=VALUE ...]
 *
 * PARAMS: a text file of the problem's parameters, one per line, "index count v_1 ... v_count" (index:
 * rvd_cpg.h's RVD_CPG_* order). The law's settings first (generate.py's, as the flight law sets them),
 * then the given QOCOGEN settings (max_iters, bisect_iters, iter_ref_iters, kkt_static_reg,
 * kkt_dynamic_reg, abstol, reltol, abstol_inacc, reltol_inacc, verbose). The parameters are set once;
 * each of the REPEAT solves (default 1) is bracketed by the instruction counter's markers (the QEMU
 * plugin rvd_pil/qemu/plugin/insn_count.c, flight_sw/app/solve_marker.hpp's ABI), so that under
 * qemu-user with the plugin its log holds one "step instructions" line per solve. Prints per solve:
 * "solve K status S iterations I objective J u0 U1 U2 U3 pri_res R dua_res D".
 *
 * Built with -DRVD_PREFIX=r30 (the problem's prefix) and the problem's rvd_*.c wrappers and rvd_glue.c.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "rvd_cpg.h"

#define RVD_CAT2(a, b) a##_##b
#define RVD_CAT(a, b) RVD_CAT2(a, b)
#define RVD_PFX(name) RVD_CAT(RVD_PREFIX, name)

extern const rvd_cpg_problem RVD_PFX(rvd_problem);
#if defined(RVD_QOCOGEN)
void RVD_PFX(cpg_set_solver_max_iters)(int);
void RVD_PFX(cpg_set_solver_bisect_iters)(int);
void RVD_PFX(cpg_set_solver_iter_ref_iters)(int);
void RVD_PFX(cpg_set_solver_verbose)(int);
void RVD_PFX(cpg_set_solver_kkt_static_reg)(double);
void RVD_PFX(cpg_set_solver_kkt_dynamic_reg)(double);
void RVD_PFX(cpg_set_solver_abstol)(double);
void RVD_PFX(cpg_set_solver_reltol)(double);
void RVD_PFX(cpg_set_solver_abstol_inacc)(double);
void RVD_PFX(cpg_set_solver_reltol_inacc)(double);
#endif

static void marker(long op, long step) {
#if defined(__linux__) && (defined(__arm__) || defined(__aarch64__))
  static uint64_t slot __attribute__((aligned(8)));
  int saved = errno;
  slot = 0x525644534c4f543fULL; /* "RVDSLOT?" */
  syscall(0x5256, op, step, &slot);
  errno = saved;
#else
  (void)op, (void)step;
#endif
}

static int setting(const char* arg) {
  const char* eq = strchr(arg, '=');
  if (!eq) return 0;
  size_t n = (size_t)(eq - arg);
  double v = atof(eq + 1);
#if defined(RVD_QOCOGEN)
#define RVD_INT(name) if (n == strlen(#name) && !strncmp(arg, #name, n)) { RVD_PFX(cpg_set_solver_##name)((int)v); return 1; }
#define RVD_DBL(name) if (n == strlen(#name) && !strncmp(arg, #name, n)) { RVD_PFX(cpg_set_solver_##name)(v); return 1; }
  RVD_INT(max_iters) RVD_INT(bisect_iters) RVD_INT(iter_ref_iters) RVD_INT(verbose)
  RVD_DBL(kkt_static_reg) RVD_DBL(kkt_dynamic_reg) RVD_DBL(abstol) RVD_DBL(reltol) RVD_DBL(abstol_inacc)
  RVD_DBL(reltol_inacc)
#endif
  (void)n, (void)v;
  return 0;
}

int main(int argc, char** argv) {
  const rvd_cpg_problem* p = &RVD_PFX(rvd_problem);
  if (argc < 2) {
    fprintf(stderr, "usage: %s PARAMS [REPEAT] [SETTING=VALUE ...]\n", argv[0]);
    return 2;
  }
  FILE* f = fopen(argv[1], "r");
  if (!f) {
    perror(argv[1]);
    return 2;
  }
  static double values[100000];
  int which, count;
  while (fscanf(f, "%d %d", &which, &count) == 2) {
    if (which < 0 || which >= RVD_CPG_N_PARAMS || count != p->sizes[which] || count > 100000) {
      fprintf(stderr, "%s: parameter %d with %d values, the problem has %d\n", argv[1], which, count,
              which >= 0 && which < RVD_CPG_N_PARAMS ? p->sizes[which] : -1);
      return 2;
    }
    for (int i = 0; i < count; ++i)
      if (fscanf(f, "%lf", &values[i]) != 1) {
        fprintf(stderr, "%s: short parameter %d\n", argv[1], which);
        return 2;
      }
    p->set(which, values);
  }
  fclose(f);
  int repeat = 1, a = 2;
  if (a < argc && !strchr(argv[a], '=')) repeat = atoi(argv[a++]);
  p->settings();
  for (; a < argc; ++a)
    if (!setting(argv[a])) {
      fprintf(stderr, "unknown setting %s\n", argv[a]);
      return 2;
    }
  for (int k = 0; k < repeat; ++k) {
    marker(1, k);
    p->solve();
    marker(2, k);
    const double* u = p->u();
    printf("solve %d status %d iterations %d objective %.17g u0 %.17g %.17g %.17g pri_res %.3e dua_res %.3e\n", k,
           p->status(), p->iterations(), p->objective(), u[0], u[1], u[2], p->primal_residual(), p->dual_residual());
  }
  return 0;
}
