/* CW targeting + glideslope: a minimal guidance law written against rvd_guidance.h alone.
 * Every period it re-solves the Clohessy-Wiltshire two-point problem "be at point P after time T"
 * for the first impulse and commands it (clipped to the phase's delta-v limit):
 *   rendezvous: P = hold point on the docking axis, r1 + hold_m from the target, T = what is left
 *               of transfer_s (at least two periods);
 *   approach / docking: P = the point on the axis that a closing speed of glide_rate x distance
 *               (at most 0.8 v_max) reaches after two periods: an exponential glideslope; docking
 *               inside r2, docked inside r3 / 2.
 * It ignores the keep-out sphere and the corridor: a teaching example, not a safe law. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "rvd_guidance.h"

typedef struct {
  rvd_guidance_config c;                    /* a copy: config is valid only during create() */
  double hold_m, transfer_s, glide_rate, t0_s;
  int phase;
} law_t;

static double param(const rvd_guidance_config* c, const char* name, double fallback) {
  for (uint32_t i = 0; i < c->n_params; ++i)  /* the last one given wins */
    if (strcmp(c->params[i].name, name) == 0) fallback = c->params[i].value;
  return fallback;
}

static void* create(const rvd_guidance_config* c, char* error, size_t size) {
  law_t* law = (law_t*)calloc(1, sizeof *law);
  if (!law || c->mean_motion_rad_s <= 0.0) {
    if (size) strncpy(error, law ? "needs the orbit's mean motion" : "out of memory", size - 1);
    free(law);
    return NULL;
  }
  law->c = *c;
  law->c.params = NULL;
  law->hold_m = param(c, "hold_m", 50.0);
  law->transfer_s = param(c, "transfer_s", 1800.0);
  law->glide_rate = param(c, "glide_rate", 0.005);
  law->phase = RVD_PHASE_RENDEZVOUS;
  return law;
}

static void reset(void* p) { ((law_t*)p)->phase = RVD_PHASE_RENDEZVOUS; }
static void destroy(void* p) { free(p); }

/* v = q (x) v (x) q*, q = (w, x, y, z): a body vector in LVLH. */
static void rotate(const double q[4], const double v[3], double out[3]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  out[0] = (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y - w * z) * v[1] + 2 * (x * z + w * y) * v[2];
  out[1] = 2 * (x * y + w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z - w * x) * v[2];
  out[2] = 2 * (x * z - w * y) * v[0] + 2 * (y * z + w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2];
}

/* The velocity that takes the chaser from r to p in time t under CW (x radial, y along-track, z normal). */
static void cw_target_velocity(double n, double t, const double r[3], const double p[3], double v[3]) {
  const double c = cos(n * t), s = sin(n * t);
  const double b[3] = {p[0] - (4 - 3 * c) * r[0], p[1] - 6 * (s - n * t) * r[0] - r[1], p[2] - c * r[2]};
  const double a11 = s / n, a12 = 2 * (1 - c) / n, a22 = (4 * s - 3 * n * t) / n;  /* Phi_rv = [a11 a12; -a12 a22] */
  const double det = a11 * a22 + a12 * a12;
  v[0] = (a22 * b[0] - a12 * b[1]) / det;
  v[1] = (a12 * b[0] + a11 * b[1]) / det;
  v[2] = b[2] * n / s;
}

static int step(void* p, const rvd_nav_input* nav, double budget_s, rvd_guidance_output* out) {
  law_t* law = (law_t*)p;
  const rvd_guidance_config* c = &law->c;
  const double ex[3] = {1, 0, 0};
  double axis[3], port[3], aim[3], v[3];
  (void)budget_s;
  if (nav->first) law->t0_s = nav->t_s;
  rotate(nav->q_lvlh_body, ex, axis);
  rotate(nav->q_lvlh_body, c->port_body_m, port);
  double rel[3], along = 0, dist = 0;  /* relative to the port; distance along the axis */
  for (int i = 0; i < 3; ++i) rel[i] = nav->position_lvlh_m[i] - port[i], along += rel[i] * axis[i], dist += rel[i] * rel[i];
  dist = sqrt(dist);

  if (law->phase == RVD_PHASE_DOCKING && dist <= 0.5 * c->dock_tolerance_m) law->phase = RVD_PHASE_DOCKED;
  if (law->phase == RVD_PHASE_DOCKED) {
    out->phase = RVD_PHASE_DOCKED;
    out->status = RVD_STATUS_DOCKED;
    out->solver_status = RVD_SOLVER_NONE;
    return 0;
  }
  double t_go = 2 * c->phase[law->phase - 1].period_s;
  const double hold = c->keepout_radius_m + law->hold_m;
  if (law->phase == RVD_PHASE_RENDEZVOUS) {
    const double left = law->transfer_s - (nav->t_s - law->t0_s);
    double miss = 0;
    for (int i = 0; i < 3; ++i) aim[i] = port[i] + hold * axis[i], miss += pow(nav->position_lvlh_m[i] - aim[i], 2);
    if (left > t_go) t_go = left;
    else if (sqrt(miss) < 10.0) law->phase = RVD_PHASE_APPROACH;
  }
  if (law->phase != RVD_PHASE_RENDEZVOUS) {
    /* Docking before the overshoot plane r2: the approach glide covers at most this in two periods. */
    const double brake = 2 * c->phase[1].period_s * 0.8 * c->v_max_mps;
    if (law->phase == RVD_PHASE_APPROACH && along <= c->approach_stop_m + brake) law->phase = RVD_PHASE_DOCKING;
    t_go = 2 * c->phase[law->phase - 1].period_s;
    const double speed = fmin(law->glide_rate * along, 0.8 * c->v_max_mps);  /* closing speed, capped */
    double next = along - speed * t_go;
    if (next < 0) next = 0;
    for (int i = 0; i < 3; ++i) aim[i] = port[i] + next * axis[i];
  }
  cw_target_velocity(c->mean_motion_rad_s, t_go, nav->position_lvlh_m, aim, v);
  double dv[3], worst = 0;
  const double limit = 0.999 * c->phase[law->phase - 1].dv_max_mps;
  for (int i = 0; i < 3; ++i) dv[i] = v[i] - nav->velocity_lvlh_mps[i], worst = fmax(worst, fabs(dv[i]));
  for (int i = 0; i < 3; ++i) out->dv_lvlh_mps[i] = worst > limit ? dv[i] * limit / worst : dv[i];
  out->phase = (uint8_t)law->phase;
  out->status = RVD_STATUS_OK;
  out->solver_status = RVD_SOLVER_NONE;
  out->computed = 1;
  out->solve_time_us = -1.0;  /* the harness times the step */
  out->primal_residual = out->dual_residual = -1.0;
  out->n_named = 2;
  strcpy(out->named[0].name, "t_go_s");
  out->named[0].value = t_go;
  strcpy(out->named[1].name, "axis_distance_m");
  out->named[1].value = along;
  return 0;
}

const rvd_guidance_law* rvd_guidance_law_entry(void) {
  static const rvd_guidance_law law = {RVD_GUIDANCE_ABI_VERSION, "cw_target", create, reset, step, destroy};
  return &law;
}
