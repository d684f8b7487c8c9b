/*
 * The compiled SQP loop's shared types (condensed_loop.c, condensed_qp.c).
 */
#ifndef AEROMANIP_SQP_LOOP_H
#define AEROMANIP_SQP_LOOP_H

#include <stddef.h>

#include "daqp/api.h"
#include "dense_linalg.h"
#include "model_fn.h"

/* the outcome of a solve (Python maps them to IPOPT-like status words) */
enum { ST_SOLVED = 1, ST_ACCEPTABLE = 2, ST_MAX_ITER = 3, ST_INVALID = 4, ST_QP_FAILED = 5,
       ST_RTI = 6, ST_MODEL_FAILED = 7, ST_FEASIBLE_AT_MAX_ITER = 8 };
enum { HESS_AUTO = 0, HESS_EXACT = 1, HESS_GN = 2 };

#define MAX_SIZES 16

/* the Python loop's constants (solver.py, dense_qp.py, convexify.py), passed by sqp_new */
typedef struct {
  double screen_rounds, cross_tol, exact_from_iteration, armijo, backtrack, min_step;
  double damping_start, damping_growth, penalty_margin, penalty_floor;
  double convexify_decades, eigen_floor, shift_first, shift_step, shift_count;
  double max_soc, kappa_soc, soc_min_rise;
} Constants;

typedef struct {
  int nU, nc, nr, nh, np, has_hess;
  Constants k;
  Fn data, merit, hess;
  int* hier_row;          /* nh: the row (of nc) that bounds each hierarchy residual */
  unsigned char* always;  /* nc: rows always given to the QP solver */
  int sizes[MAX_SIZES], n_sizes;  /* row counts below which the screened QP is tried */
  double screen;
  DAQPSettings settings;
  /* the model at the iterate and at a trial point */
  double *R, *J, *c, *A, *Jh, *grad, *H, *trial_c;
  /* QP data and answers */
  double *qd, *qlam_a, *qlam_x, *lba, *uba, *lbx, *ubx, *Ad, *soc_c;
  double *sd, *slam_a, *slam_x;  /* the corrected step */
  /* DAQP's inputs (A row-major) and scratch */
  double *dH, *dA, *dlo, *dup, *dlam, *rlam, *tmp, *L, *C, *V, *Hc, *T;
  int *sense, *rows;
  unsigned char* near;
  /* DAQP's workspace and its LDP's buffers, allocated once for nU variables and nc rows */
  DAQPWorkspace work;
  double *w_scaling, *w_M, *w_dupper, *w_dlower, *w_Rinv, *w_v, *w_R;
  /* the inverse factor of the Hessian (packed, before DAQP scales it), kept while the
     QP's Hessian is unchanged (hessian() invalidates it): the screened QP's rounds and
     the second-order correction reuse it */
  double* factor;
  const double* factor_of; /* the Hessian buffer it is the factor of */
  int factor_valid;
  int* w_sense;
} Sqp;

typedef struct {
  double f;
  int iterations;
  int qp_exitflag;     /* DAQP's, of the QP that failed */
  int qp_finite;       /* its answer finite? */
  double qp_excess;    /* how far it crossed its bounds */
} SqpInfo;



typedef struct {
  int ok, exitflag, finite;
  double excess;
} QpOutcome;

QpOutcome qp_solve(Sqp* s, const double* H, const double* g, const double* A,
                   const double* lba, const double* uba, const double* lbx, const double* ubx,
                   double* memory, double* d, double* lam_a, double* lam_x);
int hessian(Sqp* s, const double* U, const double* p, const double* lam_c,
            const double* lam_u, int exact, double regularization, double damping, int shift);

/* the places of sqp_solve's options (SqpBackend._loop_opts, in this order) */
enum {
  OPT_MAX_ITER,
  OPT_TOL,
  OPT_ACCEPTABLE_TOL,
  OPT_CONSTR_VIOL_TOL,
  OPT_ACCEPTABLE_ITER,
  OPT_RTI,
  OPT_HESSIAN, /* HESS_* */
  OPT_REGULARIZATION,
  OPT_WARM, /* the multipliers are given */
  OPT_ACCEPT_AT_MAX_ITER,
  OPT_COUNT
};

/* the loop's entry points (condensed_loop.c) */
Sqp* sqp_new(const int* dims, const int* hier_row, const unsigned char* always,
             const int* sizes, int n_sizes, double screen, const double* daqp,
             const double* consts, casadi_fn data, casadi_work_fn data_work, casadi_fn merit_fn,
             casadi_work_fn merit_work, casadi_fn hess, casadi_work_fn hess_work);
int sqp_solve(Sqp* s, const double* opts, const double* p, const double* lbc,
              const double* ubc, const double* lbU, const double* ubU, double* U,
              double* lam_c, double* lam_u, double* memory, SqpInfo* info);
void sqp_free(Sqp* s);

#endif
