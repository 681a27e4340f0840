/* rvd_cpg.h: one table entry per CVXPYgen-generated phase QP (generate.py writes them), so that a law
 * can hold several generated problems (one per phase and horizon) in one executable.
 *
 * Parameters, in this order (sizes[] gives each one's length, 0 when the problem has no such block):
 *   x0         6        chaser state at stage 0, LVLH [m, m/s]
 *   A, B       36, 18   CW dynamics x_{i+1} = A x_i + B u_i, row-major (set once)
 *   q          6(N+1)   linear state cost of stages 0..N (the OCP's q_i = -2 Q x_ref,i), stage-major
 *   ubox       6N       input box per stage: u <= ubox[0..2], -u <= ubox[3..5] [m/s]
 *   keepout_C, keepout_d   per stage 1..N one position row  c'rho_i <= d (keep-out plane / overshoot plane)
 *   cone_C, cone_d         4 position rows per stage (every stage 1..N; rendezvous: stage N only), each
 *                          row's 3 coefficients in turn, soft (penalty lambda) except in docking
 *   speed_C, speed_d       per stage 1..N one velocity row (approach closing-speed cap)
 *   vel_d                  per stage 1..N: v <= vel_d[0..2], -v <= vel_d[3..5] (docking |v|_inf)
 * Cost: sum_{i<N} x_i'Q x_i + u_i'R u_i + x_N'Q_f x_N + q'x + lambda 1's: our OCP's objective exactly.
 */
#ifndef RVD_CPG_H
#define RVD_CPG_H

#ifdef __cplusplus
extern "C" {
#endif

enum {
  RVD_CPG_X0, RVD_CPG_A, RVD_CPG_B, RVD_CPG_Q, RVD_CPG_UBOX, RVD_CPG_KEEPOUT_C, RVD_CPG_KEEPOUT_D,
  RVD_CPG_CONE_C, RVD_CPG_CONE_D, RVD_CPG_SPEED_C, RVD_CPG_SPEED_D, RVD_CPG_VEL_D, RVD_CPG_STOP_C, RVD_CPG_STOP_D,
  RVD_CPG_N_PARAMS
};

enum { RVD_CPG_SOLVED = 0, RVD_CPG_MAX_ITER = 1, RVD_CPG_INFEASIBLE = 2, RVD_CPG_NUMERICAL_ERROR = 4,
       RVD_CPG_OTHER = 6 };

typedef struct rvd_cpg_problem {
  int phase;               /* RVD_PHASE_RENDEZVOUS, _APPROACH or _DOCKING */
  int N;                   /* horizon */
  const char* solver;      /* "QOCOGEN" or "OSQP" */
  int sizes[RVD_CPG_N_PARAMS];
  double lambda;           /* soft rows' penalty per unit of violation */
  double stop_penalty;     /* the docking stop plane's, per metre past it (0: no plane) */
  const double* Q;         /* 6x6, row-major, dissertation units (cost x'Qx) */
  const double* Qf;        /* 6x6 terminal */
  const double* R;         /* 3x3 */
  void (*settings)(void);  /* the solver's defaults, then generate.py's tolerances */
  void (*set)(int which, const double* values);  /* one parameter, sizes[which] values */
  void (*solve)(void);
  int (*status)(void);     /* RVD_CPG_* */
  const double* (*x)(void);      /* 6(N+1), stage-major */
  const double* (*u)(void);      /* 3N */
  const double* (*slack)(void);  /* the cone rows' slacks, or NULL */
  double (*objective)(void);
  int (*iterations)(void);
  double (*primal_residual)(void);
  double (*dual_residual)(void);
} rvd_cpg_problem;

extern const rvd_cpg_problem* const rvd_cpg_problems[];
extern const int rvd_cpg_n_problems;

#ifdef __cplusplus
}
#endif

#endif /* RVD_CPG_H */
