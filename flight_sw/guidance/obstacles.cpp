#include "flight_sw/guidance/obstacles.hpp"

#include <algorithm>
#include <cmath>

namespace rvd::guidance {

bool obstacle_usable(const Obstacle& o) {
  if (!std::isfinite(o.t_state_s) || !std::isfinite(o.t_seen_s) || !o.position_lvlh_m.allFinite() ||
      !o.velocity_lvlh_mps.allFinite() || !o.semi_axes_m.allFinite() || !o.q_lvlh_body.coeffs().allFinite())
    return false;
  if (!(o.semi_axes_m.minCoeff() > 0.0) || o.semi_axes_m.maxCoeff() > 1e5) return false;
  return std::abs(o.q_lvlh_body.norm() - 1.0) <= 1e-3;
}

Eigen::Vector3d obstacle_position(const Obstacle& o, double t_s, double n_rad_s, ObstaclePrediction model) {
  const double dt = t_s - o.t_state_s;
  if (model == ObstaclePrediction::NaturalMotion) {
    Vector6d x;
    x << o.position_lvlh_m, o.velocity_lvlh_mps;
    return (cw_stm(n_rad_s, dt) * x).head<3>();
  }
  return o.position_lvlh_m + dt * o.velocity_lvlh_mps;
}

Eigen::Matrix3d obstacle_shape(const Obstacle& o, double margin_m) {
  const Eigen::Matrix3d R = o.q_lvlh_body.normalized().toRotationMatrix();
  const Eigen::Vector3d axes = o.semi_axes_m.array() + margin_m;
  return R * axes.array().square().inverse().matrix().asDiagonal() * R.transpose();
}

double obstacle_surface_distance_m(const Obstacle& o, const Eigen::Vector3d& r, double t_s, double n_rad_s,
                                   ObstaclePrediction model) {
  const Eigen::Vector3d d = r - obstacle_position(o, t_s, n_rad_s, model);
  const double scaled = std::sqrt(std::max(d.dot(obstacle_shape(o, 0.0) * d), 0.0));
  return scaled > 0.0 ? d.norm() * (1.0 - 1.0 / scaled) : -o.semi_axes_m.minCoeff();
}

void select_obstacles(const Obstacle* list, int n, const Eigen::Vector3d& chaser, double t_s, double n_rad_s,
                      ObstaclePrediction model, ObstacleSet& set) {
  std::array<double, kMaxObstacles> dist{};
  const std::array<Obstacle, kMaxObstacles> before = set.items;  // to carry each held one's history
  const int held_before = set.count;
  set.count = 0;
  set.received = static_cast<uint32_t>(std::max(n, 0));
  for (int k = 0; k < n; ++k) {
    const Obstacle& o = list[k];
    if (!obstacle_usable(o)) {
      ++set.rejected_total;
      continue;
    }
    const double d = obstacle_surface_distance_m(o, chaser, t_s, n_rad_s, model);
    // Insertion into the sorted set; when full, the farthest goes (counted as dropped).
    int pos = set.count;
    while (pos > 0 && dist[pos - 1] > d) --pos;
    if (pos >= kMaxObstacles) {
      ++set.dropped_total;
      continue;
    }
    if (set.count == kMaxObstacles) ++set.dropped_total;
    const int last = std::min(set.count, kMaxObstacles - 1);
    for (int j = last; j > pos; --j) {
      set.items[j] = set.items[j - 1];
      dist[j] = dist[j - 1];
    }
    set.items[pos] = o;
    dist[pos] = d;
    set.count = std::min(set.count + 1, kMaxObstacles);
  }
  for (int k = 0; k < set.count; ++k) {
    Obstacle& o = set.items[k];
    int j = 0;
    while (j < held_before && before[j].id != o.id) ++j;
    if (j < held_before) {
      o.first_normal = before[j].first_normal;
      o.t_first_held_s = before[j].t_first_held_s;
    } else {  // newly held: the rotating hyperplane starts facing the chaser
      const Eigen::Vector3d d = chaser - obstacle_position(o, t_s, n_rad_s, model);
      o.first_normal = d.norm() > 1e-9 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d::UnitX();
      o.t_first_held_s = t_s;
    }
  }
}

ObstacleRow rotating_hyperplane(const Obstacle& o, const Eigen::Vector3d& centre, const Eigen::Matrix3d& S_inverse,
                                const Eigen::Vector3d& goal, double t_s, double rate_rad_s) {
  const Eigen::Vector3d n0 = o.first_normal;
  Eigen::Vector3d nf = goal - centre;
  nf = nf.norm() > 1e-9 ? Eigen::Vector3d(nf.normalized()) : n0;
  Eigen::Vector3d axis = n0.cross(nf);
  const double total = std::atan2(axis.norm(), n0.dot(nf));
  if (axis.norm() < 1e-12) axis = n0.unitOrthogonal();
  const double angle = std::clamp(rate_rad_s * (t_s - o.t_first_held_s), 0.0, total);
  ObstacleRow row;
  row.normal = Eigen::AngleAxisd(angle, axis.normalized()) * n0;
  row.bound_m = row.normal.dot(centre) + std::sqrt(row.normal.dot(S_inverse * row.normal));
  return row;
}

ObstacleRow linearize_obstacle(const Eigen::Vector3d& centre, const Eigen::Matrix3d& S, const Eigen::Vector3d& p,
                               const Eigen::Vector3d& fallback_direction) {
  Eigen::Vector3d d = p - centre;
  if (!(d.norm() > 1e-9)) d = fallback_direction;  // at the centre: any side will do; take the chaser's
  if (!(d.norm() > 1e-9)) d = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d d0 = d / std::sqrt(d.dot(S * d));  // r0 - r_obs, on the boundary
  const Eigen::Vector3d E = S * d0;                          // the gradient / 2 at r0
  ObstacleRow row;
  const double norm = E.norm();
  row.normal = E / norm;
  // 2 E'(r - r_obs) - d0'S d0 >= 1 with d0'S d0 = 1:  E'(r - r_obs) >= 1, i.e. n'r >= n'r_obs + 1/|E|.
  row.bound_m = row.normal.dot(centre) + 1.0 / norm;
  return row;
}

}  // namespace rvd::guidance
