/*
 * A whole controller step in C: what Python's Controller.step does for a weighted or
 * strict hierarchical controller on the condensed model (controller_step.c). The
 * scenario's sizes, constants and generated Functions come in an AmConfig at run time:
 * an export fills one from its generated aeromanip_config.h, the Python controller from
 * its own compiled model (nmpc/backends/sqp/compiled_step.py).
 */
#ifndef AEROMANIP_CONTROLLER_STEP_H
#define AEROMANIP_CONTROLLER_STEP_H

#include "model_fn.h"

/* one priority level's loop and bounds */
typedef struct {
  const int* dims;              /* nU, nc, nr, nh, np */
  const int* hier_row;          /* nh: the row that bounds each hierarchy residual */
  const unsigned char* always;  /* nc: rows always given to the QP */
  const int* sizes;             /* the screened QP's row counts */
  int n_sizes;
  double screen;
  const int* shift_rows;        /* nc: the row that predicts each one a step on */
  const int* pins;              /* n_pins x 2: a row pinned, the higher level it holds */
  int n_pins;
  casadi_fn data, merit, hess, bounds;
  casadi_work_fn data_work, merit_work, hess_work, bounds_work;
} AmLevel;

/* the scenario's controller */
typedef struct {
  int nx, N, nU, np, n_levels;
  const AmLevel* levels;
  const double* daqp;       /* compiled_loop.DAQP_SETTINGS */
  const double* constants;  /* compiled_loop.CONSTANTS */
  const double* opts;       /* SqpBackend._loop_opts (OPT_COUNT, sqp_loop.h) */
  const int* shift_vars;    /* nU: the command that predicts each one a step on */
  const double *lbU, *ubU;  /* nU: the commands' bounds in the condensed QP */
  const double *u_lower, *u_upper; /* nx: the command's bounds (the fallback's clip) */
  casadi_fn parameters, plan;
  casadi_work_fn parameters_work, plan_work;
  /* a host that seeds cold solves itself (Python's IPOPT seed) sets host_seeds: a step
     that would solve a level cold, or whose warm answer costs more than seed_ratio
     times the level's last one plus seed_floor (not in RTI), is undone (AM_HOST) */
  int host_seeds;
  double seed_ratio, seed_floor;
} AmConfig;

/* a step's outcome (the numbers of aeromanip_status in an export's header) */
enum { AM_OK = 0, AM_FALLBACK = 1, AM_STOPPED = 2, AM_BAD_INPUT = 3, AM_PARTIAL = 4,
       AM_HOST = 5 /* host_seeds: the step is the host's to take; nothing changed */ };

/* a level's solve in a step left to the host (AM_HOST), kept for the host to take
   instead of solving again (the step itself is undone) */
typedef struct {
  double *U, *lam_c, *lam_u, *memory; /* the answer, its multipliers and active rows */
  double f, seconds, qp_excess;
  int status, iterations, qp_exitflag, qp_finite;
  int valid; /* the level was solved in that step */
} AmTried;

/* one level's warm state and its last solve, readable and writable by the caller
   (Python keeps NumPy views of the arrays) */
typedef struct {
  double *U, *lam_c, *lam_u, *memory; /* nU, nc, nU, nc: the answer and its multipliers */
  double *lbc, *ubc;                  /* nc: the last solve's row bounds */
  double f;                           /* the objective at U */
  int warm;        /* the last solve succeeded: its multipliers start the next one */
  int status;      /* the last solve's (the loop's codes), 0 if not reached */
  int iterations;  /* its QPs, a cold retry's included */
  double seconds;  /* its time [s] */
  int qp_exitflag, qp_finite; /* of a QP that failed: DAQP's flag, its answer finite? */
  double qp_excess;           /* how far that answer crossed its bounds */
  AmTried tried;              /* its solve in the last step left to the host */
} AmLevelState;

/* the controller's memory between steps */
typedef struct {
  double *u_prev, *p;            /* nx: the command in flight; np: the last parameters */
  double *first;                 /* nU: the first level's last answer (the next guess) */
  double *plan_x, *plan_u;       /* (N+1) nx, N nx: the plan that flies */
  int has_plan, plan_age, has_first;
} AmState;

/* what a step writes (the caller's buffers) */
typedef struct {
  double *u, *plan_x, *plan_u; /* nx, (N+1) nx, N nx */
  int status, solver_status, iterations, levels;
  double cost;
} AmOutput;

typedef struct AmController AmController;

/* the controller of cfg (which must outlive it) at rest; NULL if out of memory */
AmController* am_new(const AmConfig* cfg);
void am_free(AmController* c);
void am_reset(AmController* c, const double* u_prev);
/* one step from the measured state x at the time t [s] (rates: the measured actual
   rates, NULL: the command in flight); allocates nothing */
int am_step(AmController* c, const double* x, const double* rates, double t, AmOutput* out);
/* forget the last step's command and plan (it came too late to fly): the previous plan
   flies on, a step older, its command for now taken as the command in flight
   (Controller.discard); nothing if no step since the last discard or reset */
void am_discard(AmController* c);
AmState* am_state(AmController* c);
AmLevelState* am_level_state(AmController* c, int i);

#endif
