/* DAQP on the flight CPUs: solves the condensed QPs of a file one after another, each solve between
 * two solve markers, so that the QEMU block profiler prices every solve as a region (the DAQP side
 * of python -m rvd_pil.bench.target_solvers; flight_sw/tools/solve_qp_file.cpp is the other).
 *
 *   daqp_solve_file FILE
 *
 * FILE, little-endian, written by rvd_pil/bench/target_solvers.py: "RVDDNS01", uint32 count, then
 * per QP int32 n, m and the doubles H (n x n), f (n), A (m x n, row-major), bupper (m), blower (m).
 * Every row is a general row (no simple bounds), as the host benchmark gives them to DAQP.
 * Per QP, DAQP's setup (its LDP form: the Cholesky factor of H, M = R^-T A', v = R^-T f) runs
 * before the marker, daqp_solve (iterations, the primal answer, the copy-out) inside it.
 * Prints per QP: "qp K exitflag E iterations I x v v v ...".
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <sys/syscall.h>

#include "api.h"

/* The solve-marker ABI of flight_sw/solver/elapsed.hpp: syscall(0x5256, op, step, &slot). */
static void marker(long op, long step) {
  volatile uint64_t slot = 0x525644534c4f543fULL; /* kSlotRequest */
  syscall(0x5256, op, step, &slot);
}

static void fail(const char* what) {
  fprintf(stderr, "daqp_solve_file: %s\n", what);
  exit(2);
}

static void read_exact(FILE* f, void* p, size_t bytes) {
  if (fread(p, 1, bytes, f) != bytes) fail("file ends early");
}

static double* read_doubles(FILE* f, size_t n) {
  double* p = (double*)malloc(sizeof(double) * (n ? n : 1));
  if (!p) fail("out of memory");
  read_exact(f, p, sizeof(double) * n);
  return p;
}

int main(int argc, char** argv) {
  if (argc != 2) fail("usage: daqp_solve_file FILE");
  FILE* f = fopen(argv[1], "rb");
  if (!f) fail("cannot open the QP file");
  char magic[8];
  uint32_t count;
  read_exact(f, magic, 8);
  if (memcmp(magic, "RVDDNS01", 8) != 0) fail("not a condensed-QP file (magic RVDDNS01)");
  read_exact(f, &count, 4);
  for (uint32_t k = 0; k < count; ++k) {
    int32_t nm[2];
    read_exact(f, nm, 8);
    const int n = nm[0], m = nm[1];
    if (n <= 0 || m < 0 || n > 4096 || m > 65536) fail("implausible QP dimensions");
    double* H = read_doubles(f, (size_t)n * n);
    double* g = read_doubles(f, n);
    double* A = read_doubles(f, (size_t)m * n);
    double* bu = read_doubles(f, m);
    double* bl = read_doubles(f, m);
    int* sense = (int*)calloc(m ? m : 1, sizeof(int));
    double* x = (double*)malloc(sizeof(double) * n);
    double* lam = (double*)malloc(sizeof(double) * (m ? m : 1));
    if (!sense || !x || !lam) fail("out of memory");

    DAQPProblem qp = {n, m, 0, H, g, A, bu, bl, sense, NULL, 0, 0};
    DAQPWorkspace work;
    memset(&work, 0, sizeof work);
    allocate_daqp_settings(&work); /* the host benchmark's settings (rvd_pil/bench/solvers.py) */
    work.settings->eps_prox = -1.0;
    work.settings->primal_tol = 1e-6;
    work.settings->dual_tol = 1e-6;
    work.settings->iter_limit = 100000;
    double setup_time = 0.0;
    DAQPResult res;
    memset(&res, 0, sizeof res);
    res.x = x, res.lam = lam;
    const int setup = setup_daqp_main(&qp, &work, &setup_time, 0);
    if (setup >= 0) {
      marker(1, (long)k);
      daqp_solve(&res, &work);
      marker(2, (long)k);
    } else {
      res.exitflag = setup;
    }
    printf("qp %u exitflag %d iterations %d x", k, res.exitflag, res.iter);
    for (int i = 0; i < n; ++i) printf(" %.17g", x[i]);
    printf("\n");
    if (setup >= 0) {
      free_daqp_workspace(&work);
      free_daqp_ldp(&work);
    }
    free(H), free(g), free(A), free(bu), free(bl), free(sense), free(x), free(lam);
  }
  fclose(f);
  return 0;
}
