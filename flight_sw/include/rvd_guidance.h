/* rvd_guidance.h: the guidance plug-in interface of the rvd-pil flight software (C ABI, C99 / C++).
 *
 * A guidance law is four functions behind one table, rvd_guidance_law. The flight software (the
 * "harness") owns everything around the law and does the same for every law:
 *
 *   host --nav--> link --> navigation filter --> [ law.step ] --> checks --> thruster allocation
 *                                                                             --cmd--> host
 *
 *   - the link (Zenoh, message authentication), the deadline monitor, the navigation filter;
 *   - the instruction-count markers (QEMU plugin) and the PMU counter bracket the law's step, so
 *     instructions per step, estimated target times and in-guest times need nothing from the law;
 *   - the checks of what the law returns and the safe action (zero thrust) when it fails;
 *   - thruster allocation: the law commands an impulsive delta-v per LVLH axis, the harness turns it
 *     into the pulse widths of six on/off thrusters (+x, -x, +y, -y, +z, -z) with the vehicle's mass,
 *     thrust and minimum impulse bit;
 *   - telemetry and the run record.
 *
 * Frames and units (every field below): LVLH is the target's local-vertical local-horizontal frame,
 * x radial outward (R-bar), y along-track (V-bar), z along the orbit normal, origin at the target's
 * centre of mass. The target's body frame has the docking axis along body +x. SI units: m, m/s, s,
 * rad, kg, N. Quaternions are (w, x, y, z), Hamilton convention.
 *
 * Phases: a law reports which of the harness's phases it is in (RVD_PHASE_*); each phase has its own
 * control period and delta-v limit (rvd_guidance_config.phase). A law without phases stays in one,
 * e.g. RVD_PHASE_DOCKING, and reports RVD_PHASE_DOCKED when it is done.
 *
 * Rules for a law (the harness checks what it can see, records what happened and commands zero
 * thrust for that step; see rvd_guidance_status):
 *   - step() must not allocate (the harness compares the heap in use before and after), must return
 *     within its budget (a later answer is discarded: zero thrust; except a law's own deadline
 *     fallback: solver_status RVD_SOLVER_TIME_LIMIT with status SHIFTED_PLAN or ZERO_THRUST), and must
 *     return finite numbers with |dv_lvlh_mps[i]| <= phase[p].dv_max_mps (else zero thrust);
 *   - with the chaser's attitude in the nav (the planar truth), |torque_body_nm[i]| <= torque_max_nm, finite
 *     (else zero thrust and zero torque);
 *   - a step that crashes (SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT) disables the law for the rest of
 *     the run: zero thrust from then on;
 *   - create() may allocate; it returns NULL with a reason in `error` for an unusable configuration.
 */
#ifndef RVD_GUIDANCE_H
#define RVD_GUIDANCE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Within a version fields are only appended to the structs below (the chaser's rotation was), so a
 * law built against an earlier header of the same version reads and writes a prefix of them. */
#define RVD_GUIDANCE_ABI_VERSION 1u

/* Phase codes (as on the link's cmd message). */
enum {
  RVD_PHASE_RENDEZVOUS = 1, /* far range, around the keep-out sphere */
  RVD_PHASE_APPROACH = 2,   /* inside the approach corridor, down to the overshoot plane */
  RVD_PHASE_DOCKING = 3,    /* inside the docking cone, onto the port */
  RVD_PHASE_DOCKED = 4      /* done: the harness commands zero thrust from now on */
};

/* What a step did (rvd_guidance_output.status; the link's cmd guidance_status). 0-5 are the law's;
 * RVD_STATUS_LAW_FAULT is set by the harness only. */
enum {
  RVD_STATUS_OK = 0,            /* dv_lvlh_mps is this step's solution */
  RVD_STATUS_SHIFTED_PLAN = 1,  /* no new solution: the previous plan's next delta-v */
  RVD_STATUS_ZERO_THRUST = 2,   /* no new solution and no plan left: zero */
  RVD_STATUS_INVALID_STATE = 3, /* the navigation input was rejected by the law */
  RVD_STATUS_DOCKED = 4,        /* the end condition holds */
  RVD_STATUS_RECOVERED = 5,     /* a recovery problem (relaxed constraints) gave dv_lvlh_mps */
  RVD_STATUS_LAW_FAULT = 6      /* harness: the law failed this step (NaN, out of limit, crash, overrun,
                                   allocation, disabled); zero thrust was commanded */
};

/* Solver status codes (rvd_guidance_output.solver_status), for laws that solve an optimisation. */
enum {
  RVD_SOLVER_SOLVED = 0,
  RVD_SOLVER_MAX_ITER = 1,
  RVD_SOLVER_INFEASIBLE = 2,
  RVD_SOLVER_INVALID_INPUT = 3,
  RVD_SOLVER_NUMERICAL_ERROR = 4,
  RVD_SOLVER_TIME_LIMIT = 5,    /* the budget ran out: the harness counts an overrun */
  RVD_SOLVER_NONE = 255         /* no solver ran this step */
};

/* The chaser vehicle the thrusters act on (the scenario's; the harness allocates with these too). */
typedef struct rvd_vehicle {
  double mass_kg;           /* chaser mass [kg], constant over the run */
  double thrust_n;          /* nominal force of each of the six thrusters [N] */
  double min_impulse_bit_s; /* shortest pulse a valve makes [s]: delta-v needing a shorter one is dropped */
} rvd_vehicle;

/* One phase's timing and authority. */
typedef struct rvd_phase_limits {
  double period_s;   /* control period Ts [s]: the delta-v is applied at the nav time, the next nav
                        comes period_s later */
  double dv_max_mps; /* largest |delta-v| per LVLH axis per period [m/s] the harness accepts */
  uint32_t horizon;  /* prediction horizon N [steps] asked for (laws that predict; others ignore it) */
  uint32_t reserved; /* 0 */
} rvd_phase_limits;

/* A named number: a law parameter (--set law.NAME=VALUE) or a telemetry value. */
#define RVD_NAME_SIZE 24 /* bytes, NUL-terminated, letters, digits, '_' and '.' */
typedef struct rvd_named_value {
  char name[RVD_NAME_SIZE];
  double value;
} rvd_named_value;

/* Everything a law is created from. The harness fills it from the scenario (vehicle, orbit,
 * geometry), its error model and its options; it stays valid only during create(). */
typedef struct rvd_guidance_config {
  uint32_t abi_version;          /* RVD_GUIDANCE_ABI_VERSION of the harness */
  uint32_t n_params;             /* entries in params */
  rvd_vehicle vehicle;           /* the chaser */
  double mean_motion_rad_s;      /* n of the target's circular orbit [rad/s] (Clohessy-Wiltshire) */
  rvd_phase_limits phase[3];     /* index 0 rendezvous, 1 approach, 2 docking */
  /* Geometry of the approach (the harness's host judges safety on the truth against these). */
  double keepout_radius_m;        /* r1: keep-out sphere about the target CoM, outside the corridor [m] */
  double approach_stop_m;         /* r2: overshoot plane, distance along the docking axis from the CoM [m] */
  double dock_tolerance_m;        /* r3: docked within this distance of the port [m] */
  double v_max_mps;               /* docking phase |v|_inf bound, LVLH [m/s] */
  double approach_half_angle_deg; /* approach corridor: four-sided pyramid about the docking axis, apex
                                     at the target CoM [deg] */
  double docking_half_angle_deg;  /* docking cone: pyramid about the docking axis, apex at the port [deg] */
  double port_body_m[3];          /* docking port in the target body frame [m]; docking axis body +x */
  /* Error model of this run (the scenario's sensors and thrusters, 0 when switched off). */
  double sigma_position_m;   /* navigation noise, 1 sigma per LVLH axis [m] */
  double sigma_velocity_mps; /* [m/s] */
  double thrust_error_sigma; /* thrust amplitude error, 1 sigma, fraction of the delta-v */
  uint32_t finite_burns;     /* 1: each pulse burns over its length from the period start; 0: impulsive */
  uint32_t reserved;         /* 0 */
  const rvd_named_value* params; /* n_params law parameters (--set law.NAME=VALUE), in the given order */
  const void* native;        /* the built-in MPC's full C++ parameters; NULL for every other law */
  /* The chaser's rotation, where the truth has it (the planar truth of an air-bearing table; 0 otherwise):
   * I theta'' = tau about LVLH z. A law then commands a torque with every step (rvd_guidance_output). */
  double chaser_inertia_kgm2;  /* about z [kg m^2] */
  double torque_max_nm;        /* |torque| per axis the harness accepts [N m] */
} rvd_guidance_config;

/* An ellipsoidal keep-out zone the chaser senses: {r : (r - c)' S (r - c) <= 1} with
 * S = R diag(a^-2, b^-2, c^-2) R', R = LVLH <- obstacle body, c the centre. */
#define RVD_MAX_OBSTACLES 8 /* per navigation input (as many as the link carries) */
typedef struct rvd_obstacle {
  uint32_t id;                 /* the host's id, stable over the run */
  uint32_t reserved;           /* 0 */
  double t_seen_s;             /* simulation time it was first sensed [s] */
  double position_lvlh_m[3];   /* centre at obstacles_t_s, LVLH [m] */
  double velocity_lvlh_mps[3]; /* centre velocity, LVLH [m/s] */
  double semi_axes_m[3];       /* a, b, c along the obstacle's body x, y, z [m], > 0 */
  double q_lvlh_body[4];       /* attitude, LVLH <- obstacle body, (w, x, y, z) */
} rvd_obstacle;

/* One navigation input: the navigation filter's estimate at the nav time. */
typedef struct rvd_nav_input {
  uint32_t step;               /* control step k, 0-based */
  uint32_t first;              /* 1 on the first step of a run (after reset()) */
  double t_s;                  /* simulation time of the measurement [s] */
  double position_lvlh_m[3];   /* chaser position relative to the target CoM, LVLH [m] */
  double velocity_lvlh_mps[3]; /* chaser velocity relative to the target, LVLH [m/s] (d/dt in LVLH) */
  double q_lvlh_body[4];       /* target attitude, LVLH <- body, (w, x, y, z) */
  double omega_body_rad_s[3];  /* target rate relative to LVLH, body axes [rad/s] */
  double sigma_position_m;     /* filter's 1-sigma position error, worst axis [m] */
  double sigma_velocity_mps;   /* filter's 1-sigma velocity error, worst axis [m/s] */
  double thrust_scale[6];      /* estimated realised / nominal force of thrusters +x,-x,+y,-y,+z,-z (1 nominal) */
  double thrust_scale_sigma;   /* 1-sigma error of thrust_scale, worst thruster */
  uint32_t valid;              /* 0 when the filter rejected the measurement: the raw one is passed */
  uint32_t reserved;           /* 0 */
  /* Obstacles: a fresh list arrives with the nav it belongs to (obstacles_fresh = 1); between
   * lists the law keeps the last one (obstacles_fresh = 0, n_obstacles = 0). */
  uint32_t obstacles_fresh;    /* 1: obstacles[0..n_obstacles-1] replace the law's list this step */
  uint32_t n_obstacles;        /* entries used in obstacles (<= RVD_MAX_OBSTACLES) */
  uint32_t obstacles_sensed;   /* obstacles the chaser senses (> n_obstacles: the host sent the nearest) */
  uint32_t reserved3;          /* 0 */
  double obstacles_t_s;        /* simulation time of the obstacles' states [s] */
  rvd_obstacle obstacles[RVD_MAX_OBSTACLES];
  /* The chaser's own attitude, in runs whose truth has it (the planar truth); fresh with every nav there. */
  uint32_t chaser_attitude_fresh; /* 1: the two fields below are this step's measurement */
  uint32_t reserved4;             /* 0 */
  double q_lvlh_chaser[4];        /* chaser attitude, LVLH <- chaser body, (w, x, y, z); its docking axis is body +x */
  double omega_chaser_rad_s[3];   /* chaser body rate relative to LVLH, chaser body axes [rad/s] */
} rvd_nav_input;

#define RVD_MAX_NAMED 16 /* telemetry values per step */

/* What a step returns. The harness zeroes it before every step. */
typedef struct rvd_guidance_output {
  double dv_lvlh_mps[3];   /* impulsive delta-v to apply at t_s, LVLH [m/s]; |each| <= dv_max_mps */
  uint8_t phase;           /* RVD_PHASE_*, after this step's switching (selects period and limits) */
  uint8_t status;          /* RVD_STATUS_* (0-5) */
  uint8_t solver_status;   /* RVD_SOLVER_* (RVD_SOLVER_NONE for a law without a solver) */
  uint8_t computed;        /* 1: the law computed this step (a solve ran): the step counts in the per-phase
                              solve log, its time and instructions in the telemetry's totals; 0: nothing
                              ran worth counting (docked, input rejected, budget spent before the solve) */
  uint32_t iterations;     /* solver iterations this step (0 without a solver) */
  double solve_time_us;    /* time of the solve on the flight clock (budget_s's) [us]; < 0: the harness
                              reports the whole step's time instead */
  double primal_residual;  /* inf-norm; < 0 when not applicable */
  double dual_residual;    /* inf-norm; < 0 when not applicable */
  double objective;        /* objective value at the returned point (0 when not applicable) */
  uint32_t n_named;        /* telemetry values used in `named` (<= RVD_MAX_NAMED) */
  uint32_t reserved2;      /* 0 */
  rvd_named_value named[RVD_MAX_NAMED]; /* anything the law wants logged, by name (record: law_values) */
  /* What the law holds of the obstacles (reported on the link's obstacle_status; 0 for a law
   * that ignores obstacles). */
  uint32_t obstacles_capacity;      /* obstacles the law plans around at most */
  uint32_t obstacles_held;          /* obstacles it plans around now (the nearest, <= capacity) */
  uint32_t obstacles_dropped_total; /* entries left out for lack of capacity, so far in the run */
  uint32_t obstacles_rejected_total;/* entries refused (bad shape or attitude), so far in the run */
  uint32_t obstacle_held_id[RVD_MAX_OBSTACLES]; /* ids held, nearest first */
  /* Torque on the chaser for this period (chaser body axes [N m], |each| <= config torque_max_nm), held from
   * the burn start to the period's end; used only when the nav had the chaser's attitude. */
  double torque_body_nm[3];
} rvd_guidance_output;

/* A law. `create` may allocate; it is called at start (from the command line's configuration) and
 * again when the host's configuration (vehicle, settings) arrives before the first step: the new
 * instance replaces the old one, which is then destroyed. `reset` starts a new run (step 0, before
 * its first step); `step` is one control period; `destroy` frees everything. */
typedef struct rvd_guidance_law {
  uint32_t abi_version; /* RVD_GUIDANCE_ABI_VERSION the law was built against */
  const char* name;     /* short name, reported in hello and written to the record */
  /* NULL on failure, with a one-line reason written to error[0..error_size-1] (NUL-terminated). */
  void* (*create)(const rvd_guidance_config* config, char* error, size_t error_size);
  void (*reset)(void* law);
  /* budget_s: time the step may take on the flight clock [s] (> 0): this computer's, or under QEMU user
   * mode with --target-clock target time (instructions x CPI / f_clk); the harness checks the step
   * on that clock. A C++ law measures it with rvd::solver::clock_now() / elapsed_us()
   * (flight_sw/solver/elapsed.hpp); a law on its own clock sees host time under emulation. Returns 0;
   * non-zero is a law fault (zero thrust). The whole step is counted (instructions, cycle model): a
   * law that reads a clock in it should convert the reading without a value-dependent path (on
   * Armv7, libgcc's int64-to-double routine is one; elapsed.hpp's is not), or its estimate varies
   * with the clock. */
  int (*step)(void* law, const rvd_nav_input* nav, double budget_s, rvd_guidance_output* out);
  void (*destroy)(void* law);
} rvd_guidance_law;

/* A law's sources define this once; the flight executable built with them calls it at start. */
const rvd_guidance_law* rvd_guidance_law_entry(void);

#ifdef __cplusplus
}
#endif

#endif /* RVD_GUIDANCE_H */
