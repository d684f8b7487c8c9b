/*
 * The exported controller's step: what aeromanip's Python Controller.step does for a
 * weighted or strict hierarchical controller on the condensed model, in C
 * (aeromanip_controller.h).
 *
 *   1. the parameters from (x, u_prev, rates, t): the generated parameters function;
 *   2. the guess: the first level's last answer moved on (its last command repeated),
 *      or the last plan's after a failed step, or rest;
 *   3. level by level (the weighted strategy has one): the level's row bounds (a
 *      generated function), its rows that hold a higher level's residuals pinned to
 *      their values at that level's answer, then the SQP loop (condensed_loop.c, DAQP)
 *      from the level above's answer, with the level's own multipliers and active rows
 *      moved a stage on; a warm solve that fails is retried cold. A lower level that
 *      fails leaves the higher levels' answer (AEROMANIP_PARTIAL);
 *   4. the plan rolled out; when the first level fails, the last plan's next command
 *      (clipped), or stop.
 *
 * The scenario's sizes, constants, levels and the generated functions' names come from
 * aeromanip_config.h (generated).
 */
#include "aeromanip_controller.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "aeromanip_config.h"
#include "sqp_loop.h"

/* C has no empty arrays: a problem without rows keeps one unused slot */
#define AM_ROWS (AM_NC > 0 ? AM_NC : 1)

/* one priority level's loop, bounds and warm state */
typedef struct {
  Sqp* sqp;
  Fn bounds, merit;
  int nc;
  double lbc[AM_ROWS], ubc[AM_ROWS], lam_c[AM_ROWS], lam_u[AM_NU], memory[AM_ROWS];
  double U[AM_NU]; /* the level's answer (its last one while it is warm) */
  double f;        /* the objective there */
  int warm;        /* the last solve succeeded: its multipliers start the next one */
} Level;

struct aeromanip_controller {
  Level level[AM_LEVELS];
  Fn parameters, plan;
  double u_prev[AM_NX], p[AM_NP];
  double guess[AM_NU], first[AM_NU]; /* the first level's last answer */
  double gc[AM_ROWS], scratch[AM_ROWS > AM_NU ? AM_ROWS : AM_NU];
  double plan_x[(AM_N + 1) * AM_NX], plan_u[AM_NU];
  int has_plan, plan_age; /* a plan flies, and for how many steps since it was solved */
  int has_first;          /* the last step solved: its first level's answer is the guess */
  double opts[9];
};

static int level_new(Level* lv, const AmLevel* cfg) {
  lv->sqp = sqp_new(cfg->dims, cfg->hier_row, cfg->always, cfg->sizes, cfg->n_sizes,
                    cfg->screen, am_daqp, am_constants, cfg->data, cfg->data_work, cfg->merit,
                    cfg->merit_work, cfg->hess, cfg->hess_work);
  lv->nc = cfg->dims[1];
  int ok = lv->sqp != 0;
  ok = fn_new(&lv->bounds, cfg->bounds, cfg->bounds_work) && ok;
  return fn_new(&lv->merit, cfg->merit, cfg->merit_work) && ok;
}

aeromanip_controller* aeromanip_init(void) {
  aeromanip_controller* c = calloc(1, sizeof *c);
  if (!c) return 0;
  int ok = fn_new(&c->parameters, AM_PARAMETERS, AM_PARAMETERS_WORK);
  ok = fn_new(&c->plan, AM_PLAN, AM_PLAN_WORK) && ok;
  for (int i = 0; i < AM_LEVELS; ++i) ok = level_new(&c->level[i], &am_levels[i]) && ok;
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
  for (int i = 0; i < AM_LEVELS; ++i) {
    if (c->level[i].sqp) sqp_free(c->level[i].sqp);
    fn_free(&c->level[i].bounds);
    fn_free(&c->level[i].merit);
  }
  fn_free(&c->parameters);
  fn_free(&c->plan);
  free(c);
}

void aeromanip_reset(aeromanip_controller* c, const double* u_prev) {
  for (int i = 0; i < AM_NX; ++i) c->u_prev[i] = u_prev ? u_prev[i] : 0.0;
  c->has_plan = 0;
  c->plan_age = 0;
  c->has_first = 0;
  for (int i = 0; i < AM_LEVELS; ++i) c->level[i].warm = 0;
}

static void permute(double* v, const int* from, int n, double* scratch) {
  for (int i = 0; i < n; ++i) scratch[i] = v[from[i]];
  memcpy(v, scratch, sizeof(double) * (size_t)n);
}

static double clip(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* the first level's last answer moved on a step, or the last plan moved on to now
   (its last command repeated), or rest */
static void initial_guess(aeromanip_controller* c) {
  const double* from_u = c->has_first ? c->first : (c->has_plan ? c->plan_u : 0);
  int steps = c->has_first ? 1 : 1 + c->plan_age;
  for (int k = 0; k < AM_N; ++k) {
    int from = k + steps < AM_N ? k + steps : AM_N - 1;
    for (int i = 0; i < AM_NX; ++i)
      c->guess[k * AM_NX + i] = from_u ? from_u[from * AM_NX + i] : 0.0;
  }
}

/* one solve of level i from `start` (clipped to the command bounds): warm with its last
   multipliers moved a stage on, or cold */
static int solve(aeromanip_controller* c, int i, const double* start, int warm, SqpInfo* info) {
  Level* lv = &c->level[i];
  for (int j = 0; j < AM_NU; ++j) lv->U[j] = clip(start[j], am_lbU[j], am_ubU[j]);
  if (warm) {
    permute(lv->lam_c, am_levels[i].shift_rows, lv->nc, c->scratch);
    permute(lv->lam_u, am_shift_vars, AM_NU, c->scratch);
    permute(lv->memory, am_levels[i].shift_rows, lv->nc, c->scratch);
  } else {
    memset(lv->lam_c, 0, sizeof lv->lam_c);
    memset(lv->lam_u, 0, sizeof lv->lam_u);
    memset(lv->memory, 0, sizeof lv->memory);
  }
  c->opts[8] = warm ? 1.0 : 0.0;
  return sqp_solve(lv->sqp, c->opts, c->p, lv->lbc, lv->ubc, am_lbU, am_ubU, lv->U, lv->lam_c,
                   lv->lam_u, lv->memory, info);
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

/* level i's row bounds: its own, and the rows that hold a higher level's residuals at
   their values at that level's answer (Hierarchical._bounds, strict); 0 if a generated
   function failed */
static int level_bounds(aeromanip_controller* c, int i) {
  const AmLevel* cfg = &am_levels[i];
  Level* lv = &c->level[i];
  if (fn_call(&lv->bounds, c->p, 0, 0, lv->lbc, lv->ubc, 0, 0, 0)) return 0;
  double f;
  for (int k = 0, at = -1; k < cfg->n_pins; ++k) {
    int row = cfg->pins[2 * k], higher = cfg->pins[2 * k + 1];
    if (higher != at) { /* the pins come grouped by the level they hold */
      if (fn_call(&lv->merit, c->level[higher].U, c->p, 0, &f, c->gc, 0, 0, 0)) return 0;
      at = higher;
    }
    lv->lbc[row] = lv->ubc[row] = c->gc[row];
  }
  return 1;
}

/* level i solved from `start`; a warm solve that fails is retried cold (from where it
   stopped if it only ran out of iterations). The solver's status. */
static int solve_level(aeromanip_controller* c, int i, const double* start, int* iterations) {
  Level* lv = &c->level[i];
  if (!level_bounds(c, i)) {
    lv->warm = 0;
    return AEROMANIP_SOLVER_MODEL_FAILED;
  }
  SqpInfo info;
  int warm = lv->warm;
  int status = solve(c, i, start, warm, &info);
  *iterations += info.iterations;
  if (!succeeded(status, lv->U) && warm) { /* stale multipliers can mislead: retry cold */
    int go_on = status == AEROMANIP_SOLVER_MAX_ITERATIONS && finite_all(lv->U, AM_NU);
    status = solve(c, i, go_on ? lv->U : start, 0, &info);
    *iterations += info.iterations;
  }
  lv->f = info.f;
  lv->warm = succeeded(status, lv->U);
  return status;
}

/* on failure: the last plan's next command (clipped to the bounds), or stop (the plan:
   rest at the start, the state the model predicts when the command lands) */
static aeromanip_status fall_back(aeromanip_controller* c, aeromanip_output* out) {
  out->cost = NAN;
  out->levels = 0;
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

/* the answer of the last level solved flies: its plan, and the first level's answer
   kept as the next guess */
static aeromanip_status fly(aeromanip_controller* c, int solved, aeromanip_output* out) {
  const Level* lv = &c->level[solved - 1];
  if (fn_call(&c->plan, c->p, lv->U, 0, c->plan_x, 0, 0, 0, 0)) return fall_back(c, out);
  memcpy(c->plan_u, lv->U, sizeof c->plan_u);
  memcpy(c->first, c->level[0].U, sizeof c->first);
  c->has_plan = c->has_first = 1;
  c->plan_age = 0;
  memcpy(out->u, c->plan_u, sizeof out->u);
  memcpy(out->plan_x, c->plan_x, sizeof c->plan_x);
  memcpy(out->plan_u, c->plan_u, sizeof c->plan_u);
  out->cost = lv->f;
  return solved == AM_LEVELS ? AEROMANIP_OK : AEROMANIP_PARTIAL;
}

/* the solve's parameters from x, the command in flight and the actual rates (the
   command in flight where not measured); nonzero if the generated function failed */
static int parameters(aeromanip_controller* c, const double* x, const double* rates,
                      double t) {
  Fn* fn = &c->parameters;
  fn->arg[0] = x;
  fn->arg[1] = c->u_prev;
  fn->arg[2] = rates ? rates : c->u_prev;
  fn->arg[3] = &t;
  fn->res[0] = c->p;
  return fn->f(fn->arg, fn->res, fn->iw, fn->w, 0);
}

aeromanip_status aeromanip_step_rates(aeromanip_controller* c, const double* x,
                                      const double* rates, double t, aeromanip_output* out) {
  if (!c || !x || !out) return AEROMANIP_BAD_INPUT;
  if (!finite_all(x, AM_NX) || (rates && !finite_all(rates, AM_NX)) || !isfinite(t))
    return (aeromanip_status)(out->status = AEROMANIP_BAD_INPUT);
  int status = AEROMANIP_SOLVER_MODEL_FAILED, iterations = 0, solved = 0;
  if (!parameters(c, x, rates, t)) {
    initial_guess(c);
    for (; solved < AM_LEVELS; ++solved) {
      const double* start = solved ? c->level[solved - 1].U : c->guess;
      status = solve_level(c, solved, start, &iterations);
      if (!succeeded(status, c->level[solved].U)) break;
    }
  }
  out->solver_status = status;
  out->iterations = iterations;
  out->levels = solved;
  if (solved) {
    out->status = fly(c, solved, out);
  } else {
    c->has_first = 0;
    out->status = fall_back(c, out);
  }
  if (out->status == AEROMANIP_FALLBACK || out->status == AEROMANIP_STOPPED) c->has_first = 0;
  memcpy(c->u_prev, out->u, sizeof c->u_prev);
  return (aeromanip_status)out->status;
}

aeromanip_status aeromanip_step(aeromanip_controller* c, const double* x, double t,
                                aeromanip_output* out) {
  return aeromanip_step_rates(c, x, 0, t, out);
}
