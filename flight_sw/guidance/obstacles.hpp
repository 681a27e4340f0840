// Moving ellipsoidal keep-out zones in the phase QPs, by the direct linearization of Dong, Ghiglino et
// al. ("Fast model predictive control with moving obstacle avoidance", eqs. 6-8).
//
// A zone is {r : (r - r_obs)' S (r - r_obs) <= 1}. On stage i the constraint is linearized about the
// chaser position p_i the previous plan predicts for t + i Ts: with d = p_i - r_obs,i and the boundary
// point r0 = r_obs,i + d / sqrt(d'Sd) between the centre and p_i, the first-order expansion of
// f(r) = (r - r_obs)' S (r - r_obs) about r0 (with the gradient taken at r0, the paper's correction)
// reads 1 <= 2 (r0 - r_obs)' S (r - r_obs) - (r0 - r_obs)' S (r0 - r_obs). Since f(r0) = 1 this is the
// tangent plane n' (r - r_obs,i) >= 1 / |E| with E = S (r0 - r_obs), n = E / |E|: the row is unit in r,
// so its slack is in metres. Since the zone is convex the plane never cuts into it: a plan outside
// the plane is outside the zone. The phase QPs put two such rows per obstacle on each stage (its own
// plane and the next stage's), so that the path between two samples stays out as well (README).
//
// Capacity is fixed at compile time (kMaxObstacles); a longer list keeps the obstacles nearest the
// chaser (distance to the zone's surface along the line to its centre) and counts the rest.
#pragma once

#include <Eigen/Dense>

#include <array>
#include <cstdint>

#include "flight_sw/guidance/cw.hpp"

namespace rvd::guidance {

constexpr int kMaxObstacles = 4;  // obstacle rows per stage of every phase QP when obstacles are on

enum class ObstaclePrediction : uint8_t {
  ConstantVelocity = 0,  // r_obs(t) = r + v (t - t_state): the model of the paper above
  NaturalMotion = 1      // unforced Clohessy-Wiltshire motion of the obstacle's centre
};

enum class ObstacleMethod : uint8_t {
  DirectLinearization = 0,  // the tangent plane about the previous plan's prediction (above)
  // Park, Di Cairano and Kolmanovsky's rotating hyperplane, as used by Weiss, Petersen, Baldwin et al.
  // ("Spacecraft relative motion guidance ... with a suddenly appearing obstacle", eq. 12): when the
  // obstacle is first held, the plane tangent to it facing the chaser; its normal then turns at a
  // constant rate about normal x (direction to the target) until it points from the obstacle to
  // the target. Rows active only while the chaser is within hyperplane_active_range_m of the zone.
  RotatingHyperplane = 1
};

struct Obstacle {
  uint32_t id = 0;
  double t_state_s = 0.0;  // time of position/velocity
  double t_seen_s = 0.0;   // first sensed
  Eigen::Vector3d position_lvlh_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d velocity_lvlh_mps = Eigen::Vector3d::Zero();
  Eigen::Vector3d semi_axes_m = Eigen::Vector3d::Ones();
  Eigen::Quaterniond q_lvlh_body = Eigen::Quaterniond::Identity();
  // Set by select_obstacles when the guidance first holds it (kept while it stays held): the
  // rotating hyperplane's start, the unit direction from the centre to the chaser then, and when.
  Eigen::Vector3d first_normal = Eigen::Vector3d::UnitX();
  double t_first_held_s = 0.0;
};

// The obstacles the guidance plans around (the nearest kMaxObstacles of what it was told).
struct ObstacleSet {
  std::array<Obstacle, kMaxObstacles> items{};
  int count = 0;
  uint32_t received = 0;       // entries in the last list given
  uint32_t dropped_total = 0;  // entries left out for lack of capacity, over the run
  uint32_t rejected_total = 0; // entries refused (non-finite, axes <= 0, not a unit quaternion), over the run
};

// False for an entry the guidance must not plan with (NaN/Inf, semi-axes <= 0 or > 1e5 m, attitude
// not a unit quaternion).
bool obstacle_usable(const Obstacle& o);

// Distance from `r` to the zone's surface along the line to its centre (negative inside), at time t.
double obstacle_surface_distance_m(const Obstacle& o, const Eigen::Vector3d& r, double t_s, double n_rad_s,
                                   ObstaclePrediction model);

// Centre of the zone at time t_s.
Eigen::Vector3d obstacle_position(const Obstacle& o, double t_s, double n_rad_s, ObstaclePrediction model);

// Shape matrix S = R diag((a + m)^-2, (b + m)^-2, (c + m)^-2) R' of the zone grown by margin_m.
Eigen::Matrix3d obstacle_shape(const Obstacle& o, double margin_m);

// Replace `set` by the usable entries of list[0..n) nearest `chaser` at t_s (at most kMaxObstacles),
// nearest first; counts the dropped and the refused. Allocates nothing.
void select_obstacles(const Obstacle* list, int n, const Eigen::Vector3d& chaser, double t_s, double n_rad_s,
                      ObstaclePrediction model, ObstacleSet& set);

// One linearized row: n' r >= b (n unit), about the predicted chaser position p at time t_s.
struct ObstacleRow {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitX();
  double bound_m = 0.0;
};
// The rotating hyperplane's row at time t_s (normal n, n'r >= n'c + sqrt(n' S^-1 n): tangent to the zone).
ObstacleRow rotating_hyperplane(const Obstacle& o, const Eigen::Vector3d& centre, const Eigen::Matrix3d& S_inverse,
                                const Eigen::Vector3d& goal, double t_s, double rate_rad_s);

ObstacleRow linearize_obstacle(const Eigen::Vector3d& centre, const Eigen::Matrix3d& S, const Eigen::Vector3d& p,
                               const Eigen::Vector3d& fallback_direction);

}  // namespace rvd::guidance
