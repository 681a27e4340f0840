/* A faulty guidance law (see law.toml): the harness must survive each fault, say so, and command
 * zero thrust. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "rvd_guidance.h"

typedef struct {
  int fault, from_step;
  double dv_max_mps[3];
  void* leaked[64];
  int n_leaked;
} law_t;

static void* create(const rvd_guidance_config* c, char* error, size_t size) {
  law_t* law = (law_t*)calloc(1, sizeof *law);
  (void)error, (void)size;
  law->from_step = 3;
  for (uint32_t i = 0; i < c->n_params; ++i) {
    if (!strcmp(c->params[i].name, "fault")) law->fault = (int)c->params[i].value;
    if (!strcmp(c->params[i].name, "from_step")) law->from_step = (int)c->params[i].value;
  }
  for (int i = 0; i < 3; ++i) law->dv_max_mps[i] = c->phase[i].dv_max_mps;
  return law;
}

static void reset(void* p) { (void)p; }
static void destroy(void* p) { free(p); }

static double now_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int step(void* p, const rvd_nav_input* nav, double budget_s, rvd_guidance_output* out) {
  law_t* law = (law_t*)p;
  out->phase = RVD_PHASE_RENDEZVOUS;
  out->status = RVD_STATUS_OK;
  out->solver_status = RVD_SOLVER_NONE;
  out->computed = 1;
  out->solve_time_us = -1.0;
  out->dv_lvlh_mps[0] = 0.5 * law->dv_max_mps[0];  /* a valid command: half the limit, radial */
  if ((int)nav->step < law->from_step) return 0;
  switch (law->fault) {
    case 1: out->dv_lvlh_mps[1] = nan(""); break;
    case 2: out->dv_lvlh_mps[2] = 2.0 * law->dv_max_mps[0]; break;
    case 3: { volatile int* volatile bad = NULL; *bad = 1; break; }
    case 4: { const double t0 = now_s(); while (now_s() - t0 < 2.0 * budget_s) {} break; }
    case 5: if (law->n_leaked < 64) law->leaked[law->n_leaked++] = malloc(4096); break;
    case 6: for (;;) { struct timespec t = {1, 0}; nanosleep(&t, NULL); }
    case 7: return -1;
  }
  return 0;
}

const rvd_guidance_law* rvd_guidance_law_entry(void) {
  static const rvd_guidance_law law = {RVD_GUIDANCE_ABI_VERSION, "test_faulty", create, reset, step, destroy};
  return &law;
}
