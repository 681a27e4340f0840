#include "flight_sw/guidance/plugin/mpc_law.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <new>

#include "flight_sw/guidance/guidance.hpp"

namespace rvd::guidance {

namespace {

double finite_or(double v, double fallback) { return std::isfinite(v) ? v : fallback; }

// One telemetry value, its name a literal that fits (a copy, not a formatted print: it is inside the
// counted step). Dropped when the table is full.
template <std::size_t L>
void put_named(rvd_guidance_output* out, const char (&name)[L], double value) {
  static_assert(L <= RVD_NAME_SIZE, "telemetry name too long");
  if (out->n_named >= RVD_MAX_NAMED) return;
  std::memcpy(out->named[out->n_named].name, name, L);
  out->named[out->n_named++].value = value;
}

uint8_t solver_status_code(const Command& c) {
  return solver_status_reported(c.solved, c.solver.status) ? static_cast<uint8_t>(c.solver.status)
                                                           : static_cast<uint8_t>(RVD_SOLVER_NONE);
}

// The law's state: the three-phase guidance, and the chaser's attitude controller where the truth has
// the chaser's rotation (attitude.hpp).
struct MpcLaw {
  explicit MpcLaw(const GuidanceParams& p) : guidance(p) {
    if (p.attitude.inertia_kgm2 > 0.0) attitude = std::make_unique<AttitudeMpc>(p);
  }
  Guidance guidance;
  std::unique_ptr<AttitudeMpc> attitude;
};

void* create(const rvd_guidance_config* config, char* error, size_t error_size) {
  try {
    GuidanceParams p = params_from_config(*config);
    if (config->native == nullptr && config->chaser_inertia_kgm2 > 0.0) {
      p.attitude.inertia_kgm2 = config->chaser_inertia_kgm2;
      p.attitude.torque_max_nm = config->torque_max_nm;
    }
    return new MpcLaw(p);
  } catch (const std::exception& e) {
    if (error && error_size) std::snprintf(error, error_size, "%s", e.what());
  }
  return nullptr;
}

void reset(void* law) { static_cast<MpcLaw*>(law)->guidance.reset(); }

int step(void* law, const rvd_nav_input* nav, double budget_s, rvd_guidance_output* out) {
  MpcLaw& m = *static_cast<MpcLaw*>(law);
  auto& g = m.guidance;
  NavInput in;
  in.step = nav->step;
  in.t_s = nav->t_s;
  for (int i = 0; i < 3; ++i) {
    in.x_lvlh(i) = nav->position_lvlh_m[i];
    in.x_lvlh(3 + i) = nav->velocity_lvlh_mps[i];
  }
  in.q_lvlh_body = Eigen::Quaterniond(nav->q_lvlh_body[0], nav->q_lvlh_body[1], nav->q_lvlh_body[2], nav->q_lvlh_body[3]);
  in.omega_body_rad_s = Eigen::Vector3d(nav->omega_body_rad_s[0], nav->omega_body_rad_s[1], nav->omega_body_rad_s[2]);
  in.quality.position_m = nav->sigma_position_m;
  in.quality.velocity_mps = nav->sigma_velocity_mps;
  for (int j = 0; j < 6; ++j) in.quality.thrust_scale[j] = nav->thrust_scale[j];
  in.quality.thrust_scale_sigma = nav->thrust_scale_sigma;

  if (nav->obstacles_fresh) {
    std::array<Obstacle, RVD_MAX_OBSTACLES> list{};
    const int n = static_cast<int>(std::min<uint32_t>(nav->n_obstacles, RVD_MAX_OBSTACLES));
    for (int k = 0; k < n; ++k) {
      const rvd_obstacle& src = nav->obstacles[k];
      Obstacle& o = list[k];
      o.id = src.id;
      o.t_state_s = nav->obstacles_t_s;
      o.t_seen_s = src.t_seen_s;
      for (int j = 0; j < 3; ++j) {
        o.position_lvlh_m(j) = src.position_lvlh_m[j];
        o.velocity_lvlh_mps(j) = src.velocity_lvlh_mps[j];
        o.semi_axes_m(j) = src.semi_axes_m[j];
      }
      o.q_lvlh_body = Eigen::Quaterniond(src.q_lvlh_body[0], src.q_lvlh_body[1], src.q_lvlh_body[2], src.q_lvlh_body[3]);
    }
    g.set_obstacles(list.data(), n, nav->obstacles_t_s, in.x_lvlh.head<3>());
    // The host sensed more than it could send: those are left out too, for lack of wire capacity.
    if (nav->obstacles_sensed > static_cast<uint32_t>(n)) g.count_dropped_obstacles(nav->obstacles_sensed - n);
  }

  if (nav->chaser_attitude_fresh && m.attitude) {  // the chaser's rotation: the decoupled part of the MPC
    const Eigen::Quaterniond qc(nav->q_lvlh_chaser[0], nav->q_lvlh_chaser[1], nav->q_lvlh_chaser[2], nav->q_lvlh_chaser[3]);
    if (qc.coeffs().allFinite() && std::abs(qc.norm() - 1.0) < 1e-3 && in.q_lvlh_body.coeffs().allFinite()) {
      const int k = g.phase() == Phase::Rendezvous ? 0 : g.phase() == Phase::Approach ? 1 : 2;
      const AttitudeMpc::Result r = m.attitude->step(k, yaw_rad(qc), nav->omega_chaser_rad_s[2],
                                                     yaw_rad(in.q_lvlh_body.normalized()), in.omega_body_rad_s.z());
      out->torque_body_nm[2] = r.torque_nm;
      in.chaser_attitude_error_rad = docking_attitude_error_rad(qc.normalized(), in.q_lvlh_body.normalized());
    }
  }
  const Command c = g.step(in, budget_s * 1e6);
  for (int i = 0; i < 3; ++i) out->dv_lvlh_mps[i] = c.dv_cmd_mps(i);
  out->phase = static_cast<uint8_t>(c.phase);
  out->status = static_cast<uint8_t>(c.status);
  out->solver_status = solver_status_code(c);
  out->computed = c.solved ? 1 : 0;
  out->iterations = static_cast<uint32_t>(c.solved ? c.solver.iterations : 0);
  out->solve_time_us = c.solved ? finite_or(c.solver.solve_time_us, 0.0) : 0.0;
  out->primal_residual = c.solved ? finite_or(c.solver.primal_residual, -1.0) : -1.0;
  out->dual_residual = c.solved ? finite_or(c.solver.dual_residual, -1.0) : -1.0;
  out->objective = c.solved ? finite_or(c.solver.objective, 0.0) : 0.0;
  if (c.solved && c.solver.active_set_changes > 0) {  // the active-set method ran: its work, as iterations are the IPM's
    put_named(out, "active_set_changes", c.solver.active_set_changes);
  }
  if (g.holding().active()) {  // the record's law_values: the holding radius this step planned with
    put_named(out, "holding_radius_m", g.holding().radius());
  }
  if (std::isfinite(in.chaser_attitude_error_rad)) {
    put_named(out, "attitude_error_deg", in.chaser_attitude_error_rad * 180.0 / 3.14159265358979323846);
  }
  const ObstacleSet& held = g.obstacles();
  out->obstacles_capacity = static_cast<uint32_t>(std::max(g.params().obstacle_capacity, 0));
  out->obstacles_held = static_cast<uint32_t>(held.count);
  out->obstacles_dropped_total = held.dropped_total;
  out->obstacles_rejected_total = held.rejected_total;
  for (int k = 0; k < held.count && k < RVD_MAX_OBSTACLES; ++k) out->obstacle_held_id[k] = held.items[k].id;
  return 0;
}

void destroy(void* law) { delete static_cast<MpcLaw*>(law); }

}  // namespace

const Guidance* mpc_law_guidance(const void* law_state) {
  return law_state ? &static_cast<const MpcLaw*>(law_state)->guidance : nullptr;
}

GuidanceParams params_from_config(const rvd_guidance_config& c) {
  if (c.native != nullptr) return *static_cast<const GuidanceParams*>(c.native);
  GuidanceParams p;
  p.thrusters.mass_kg = c.vehicle.mass_kg;
  p.thrusters.thrust_N = c.vehicle.thrust_n;
  p.thrusters.min_impulse_bit_s = c.vehicle.min_impulse_bit_s;
  // The orbit altitude whose two-body mean motion is n (the guidance's parameter is the altitude).
  if (c.mean_motion_rad_s > 0.0)
    p.orbit_altitude_m = std::cbrt(kEarthMu_m3_s2 / (c.mean_motion_rad_s * c.mean_motion_rad_s)) - kEarthRadius_m;
  PhaseParams* phases[3] = {&p.rendezvous, &p.approach, &p.docking};
  for (int i = 0; i < 3; ++i) {
    if (c.phase[i].period_s > 0.0) phases[i]->Ts_s = c.phase[i].period_s;
    if (c.phase[i].dv_max_mps > 0.0) phases[i]->u_max_mps = c.phase[i].dv_max_mps;
    if (c.phase[i].horizon > 0) phases[i]->N = static_cast<int>(c.phase[i].horizon);
  }
  if (c.keepout_radius_m > 0.0) p.keepout_radius_m = c.keepout_radius_m;
  if (c.approach_stop_m > 0.0) p.approach_stop_m = c.approach_stop_m;
  if (c.dock_tolerance_m > 0.0) p.dock_tolerance_m = c.dock_tolerance_m;
  if (c.v_max_mps > 0.0) p.v_max_mps = c.v_max_mps;
  if (c.approach_half_angle_deg > 0.0) p.rendezvous.los_half_angle_deg = p.approach.los_half_angle_deg = c.approach_half_angle_deg;
  if (c.docking_half_angle_deg > 0.0) p.docking.los_half_angle_deg = c.docking_half_angle_deg;
  p.port_body_m = Eigen::Vector3d(c.port_body_m[0], c.port_body_m[1], c.port_body_m[2]);
  p.finite_burns = c.finite_burns != 0;
  return p;
}

const rvd_guidance_law* mpc_law() {
  static const rvd_guidance_law law{RVD_GUIDANCE_ABI_VERSION, "fast_mpc_3phase", create, reset, step, destroy};
  return &law;
}

rvd_guidance_config generic_config(const GuidanceParams& p) {
  rvd_guidance_config c{};
  c.abi_version = RVD_GUIDANCE_ABI_VERSION;
  c.vehicle = {p.thrusters.mass_kg, p.thrusters.thrust_N, p.thrusters.min_impulse_bit_s};
  c.mean_motion_rad_s = p.mean_motion_rad_s();
  const PhaseParams* phases[3] = {&p.rendezvous, &p.approach, &p.docking};
  for (int i = 0; i < 3; ++i)
    c.phase[i] = {phases[i]->Ts_s, phases[i]->u_max_mps, static_cast<uint32_t>(phases[i]->N), 0};
  c.keepout_radius_m = p.keepout_radius_m;
  c.approach_stop_m = p.approach_stop_m;
  c.dock_tolerance_m = p.dock_tolerance_m;
  c.v_max_mps = p.v_max_mps;
  c.approach_half_angle_deg = p.approach.los_half_angle_deg;
  c.docking_half_angle_deg = p.docking.los_half_angle_deg;
  for (int i = 0; i < 3; ++i) c.port_body_m[i] = p.port_body_m(i);
  c.finite_burns = p.finite_burns ? 1 : 0;
  c.chaser_inertia_kgm2 = p.attitude.inertia_kgm2;
  c.torque_max_nm = p.attitude.torque_max_nm;
  return c;
}

}  // namespace rvd::guidance
