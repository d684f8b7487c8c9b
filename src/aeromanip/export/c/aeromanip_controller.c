/*
 * The exported controller's step: what aeromanip's Python Controller.step does for a
 * weighted or RTI controller on the condensed model, in C (aeromanip_controller.h).
 *
 *   1. the parameters and row bounds from (x, u_prev, t): the generated prepare function;
 *   2. the guess: the last plan moved on (its last command repeated), or rest;
 *      the multipliers and the QP's active rows moved a stage on, or zero when cold;
 *   3. the SQP loop (condensed_loop.c, DAQP); a warm solve that fails is retried cold;
 *   4. the plan rolled out; on failure the last plan's next command (clipped), or stop.
 *
 * The scenario's sizes, constants and the generated functions' names come from
 * aeromanip_config.h (generated).
 */
#include "aeromanip_controller.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "aeromanip_config.h"
#include "sqp_loop.h"

struct aeromanip_controller {
  Sqp* sqp;
  Fn prepare, plan;
  double u_prev[AM_NX];
  double p[AM_NP], lbc[AM_NC], ubc[AM_NC];
  double U[AM_NU], guess[AM_NU], lam_c[AM_NC], lam_u[AM_NU], memory[AM_NC];
  double scratch[AM_NC > AM_NU ? AM_NC : AM_NU];
  double plan_x[(AM_N + 1) * AM_NX], plan_u[AM_NU];
  int has_plan, plan_age; /* a plan flies, and for how many steps since it was solved */
  int warm;               /* the last solve succeeded: its multipliers start this one */
  double opts[9];
};

aeromanip_controller* aeromanip_init(void) {
  aeromanip_controller* c = calloc(1, sizeof *c);
  if (!c) return 0;
  c->sqp = sqp_new(am_dims, am_hier_row, am_always, am_sizes, AM_N_SIZES, AM_SCREEN,
                   am_daqp, am_constants, AM_DATA, AM_DATA_WORK, AM_MERIT, AM_MERIT_WORK,
                   AM_HESS, AM_HESS_WORK);
  int ok = c->sqp != 0;
  ok = fn_new(&c->prepare, AM_PREPARE, AM_PREPARE_WORK) && ok;
  ok = fn_new(&c->plan, AM_PLAN, AM_PLAN_WORK) && ok;
  if (!ok) {
    aeromanip_free(c);
    return 0;
  }
  memcpy(c->opts, am_opts, sizeof c->opts);
  aeromanip_reset(c, 0);
  return c;
}

void aeromanip_free(aeromanip_controller* c) {
  if (!c) return;
  if (c->sqp) sqp_free(c->sqp);
  fn_free(&c->prepare);
  fn_free(&c->plan);
  free(c);
}

void aeromanip_reset(aeromanip_controller* c, const double* u_prev) {
  for (int i = 0; i < AM_NX; ++i) c->u_prev[i] = u_prev ? u_prev[i] : 0.0;
  c->has_plan = 0;
  c->plan_age = 0;
  c->warm = 0;
}

static void permute(double* v, const int* from, int n, double* scratch) {
  for (int i = 0; i < n; ++i) scratch[i] = v[from[i]];
  memcpy(v, scratch, sizeof(double) * (size_t)n);
}

static double clip(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* the last plan moved on to now (its last command repeated), or rest */
static void initial_guess(aeromanip_controller* c) {
  int steps = 1 + c->plan_age;
  for (int k = 0; k < AM_N; ++k) {
    int from = k + steps < AM_N ? k + steps : AM_N - 1;
    for (int i = 0; i < AM_NX; ++i)
      c->guess[k * AM_NX + i] = c->has_plan ? c->plan_u[from * AM_NX + i] : 0.0;
  }
}

/* one solve from `start` (clipped to the command bounds): warm with the last
   multipliers moved a stage on, or cold */
static int solve(aeromanip_controller* c, const double* start, int warm, SqpInfo* info) {
  for (int j = 0; j < AM_NU; ++j) c->U[j] = clip(start[j], am_lbU[j], am_ubU[j]);
  if (warm) {
    permute(c->lam_c, am_shift_rows, AM_NC, c->scratch);
    permute(c->lam_u, am_shift_vars, AM_NU, c->scratch);
    permute(c->memory, am_shift_rows, AM_NC, c->scratch);
  } else {
    memset(c->lam_c, 0, sizeof c->lam_c);
    memset(c->lam_u, 0, sizeof c->lam_u);
    memset(c->memory, 0, sizeof c->memory);
  }
  c->opts[8] = warm ? 1.0 : 0.0;
  return sqp_solve(c->sqp, c->opts, c->p, c->lbc, c->ubc, am_lbU, am_ubU, c->U, c->lam_c,
                   c->lam_u, c->memory, info);
}

static int finite_all(const double* v, int n) {
  for (int i = 0; i < n; ++i)
    if (!isfinite(v[i])) return 0;
  return 1;
}

static int succeeded(int status, const double* U) {
  int ok = status == AEROMANIP_SOLVER_SOLVED || status == AEROMANIP_SOLVER_ACCEPTABLE ||
           status == AEROMANIP_SOLVER_RTI_STEP;
  return ok && finite_all(U, AM_NU);
}

/* on failure: the last plan's next command (clipped to the bounds), or stop (the plan:
   rest at the start, the state the model predicts when the command lands) */
static aeromanip_status fall_back(aeromanip_controller* c, aeromanip_output* out) {
  if (c->has_plan && c->plan_age + 1 < AM_N) {
    c->plan_age += 1;
    for (int i = 0; i < AM_NX; ++i)
      out->u[i] = clip(c->plan_u[c->plan_age * AM_NX + i], am_u_lower[i], am_u_upper[i]);
    memcpy(out->plan_x, c->plan_x, sizeof c->plan_x);
    memcpy(out->plan_u, c->plan_u, sizeof c->plan_u);
    return AEROMANIP_FALLBACK;
  }
  c->has_plan = 0;
  memset(out->u, 0, sizeof out->u);
  memset(out->plan_u, 0, sizeof out->plan_u);
  for (int k = 0; k <= AM_N; ++k) memcpy(out->plan_x + k * AM_NX, c->p, sizeof(double) * AM_NX);
  return AEROMANIP_STOPPED;
}

aeromanip_status aeromanip_step(aeromanip_controller* c, const double* x, double t,
                                aeromanip_output* out) {
  if (!c || !x || !out || !finite_all(x, AM_NX) || !isfinite(t)) return AEROMANIP_BAD_INPUT;
  fn_call(&c->prepare, x, c->u_prev, &t, c->p, c->lbc, c->ubc, 0, 0);
  initial_guess(c);
  SqpInfo info;
  int warm = c->warm;
  int status = solve(c, c->guess, warm, &info);
  int iterations = info.iterations;
  if (!succeeded(status, c->U) && warm) { /* stale multipliers can mislead: retry cold */
    int go_on = status == AEROMANIP_SOLVER_MAX_ITERATIONS && finite_all(c->U, AM_NU);
    if (go_on) memcpy(c->guess, c->U, sizeof c->guess);
    status = solve(c, c->guess, 0, &info);
    iterations += info.iterations;
  }
  out->solver_status = status;
  out->iterations = iterations;
  out->cost = info.f;
  c->warm = succeeded(status, c->U);
  if (c->warm) {
    fn_call(&c->plan, c->p, c->U, 0, c->plan_x, 0, 0, 0, 0);
    memcpy(c->plan_u, c->U, sizeof c->plan_u);
    c->has_plan = 1;
    c->plan_age = 0;
    memcpy(out->u, c->U, sizeof out->u);
    memcpy(out->plan_x, c->plan_x, sizeof c->plan_x);
    memcpy(out->plan_u, c->plan_u, sizeof c->plan_u);
    out->status = AEROMANIP_OK;
  } else {
    out->status = fall_back(c, out);
  }
  memcpy(c->u_prev, out->u, sizeof c->u_prev);
  return (aeromanip_status)out->status;
}
