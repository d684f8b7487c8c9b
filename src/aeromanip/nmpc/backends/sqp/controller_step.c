/*
 * A controller step in C (controller_step.h): Python's Controller.step for a weighted or
 * strict hierarchical controller on the condensed model.
 *
 *   1. the parameters from (x, u_prev, rates, t): the generated parameters function;
 *   2. the guess: the first level's last answer moved on (its last command repeated),
 *      or the last plan's after a failed step, or rest;
 *   3. level by level (the weighted strategy has one): the level's row bounds (a
 *      generated function), its rows that hold a higher level's residuals pinned to
 *      their values at that level's answer, then the SQP loop (condensed_loop.c, DAQP)
 *      from the level above's answer, with the level's own multipliers and active rows
 *      moved a stage on; a warm solve that fails is retried cold. A lower level that
 *      fails leaves the higher levels' answer (AM_PARTIAL);
 *   4. the plan rolled out; when the first level fails, the last plan's next command
 *      (clipped), or stop.
 *
 * Every buffer is allocated by am_new; am_step allocates nothing.
 */
#include "controller_step.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "sqp_loop.h"

enum { ST_HOST = 100 }; /* host_seeds: the solve is the host's to take */

typedef struct {
  AmLevelState s;
  Sqp* sqp;
  Fn bounds, merit;
  /* its warm state before the step (host_seeds: restored when the step is the host's) */
  double *U0, *lam_c0, *lam_u0, *memory0, f0;
  int warm0;
} Level;

struct AmController {
  const AmConfig* cfg;
  AmState s;
  AmState before; /* the memory before the last step (am_discard) */
  int has_before;
  Level* level;
  Fn parameters, plan;
  double *guess, *gc, *scratch;
  double opts[OPT_COUNT];
};

/* a clock for the levels' times [s] (0 where C11's timespec_get is missing) */
static double seconds(void) {
#ifdef TIME_UTC
  struct timespec ts;
  if (timespec_get(&ts, TIME_UTC)) return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
  return 0.0;
}

static double* zeros(int n) { return calloc((size_t)(n > 0 ? n : 1), sizeof(double)); }

static int level_new(Level* lv, const AmConfig* cfg, const AmLevel* l) {
  int nU = cfg->nU, nc = l->dims[1];
  lv->sqp = sqp_new(l->dims, l->hier_row, l->always, l->sizes, l->n_sizes, l->screen,
                    cfg->daqp, cfg->constants, l->data, l->data_work, l->merit, l->merit_work,
                    l->hess, l->hess_work);
  AmLevelState* s = &lv->s;
  s->U = zeros(nU), s->lam_u = zeros(nU);
  s->lam_c = zeros(nc), s->memory = zeros(nc), s->lbc = zeros(nc), s->ubc = zeros(nc);
  lv->U0 = zeros(nU), lv->lam_u0 = zeros(nU), lv->lam_c0 = zeros(nc), lv->memory0 = zeros(nc);
  AmTried* t = &s->tried;
  t->U = zeros(nU), t->lam_u = zeros(nU), t->lam_c = zeros(nc), t->memory = zeros(nc);
  int ok = lv->sqp && s->U && s->lam_u && s->lam_c && s->memory && s->lbc && s->ubc &&
           lv->U0 && lv->lam_u0 && lv->lam_c0 && lv->memory0 && t->U && t->lam_u &&
           t->lam_c && t->memory;
  ok = fn_new(&lv->bounds, l->bounds, l->bounds_work) && ok;
  return fn_new(&lv->merit, l->merit, l->merit_work) && ok;
}

static void level_free(Level* lv) {
  if (lv->sqp) sqp_free(lv->sqp);
  fn_free(&lv->bounds);
  fn_free(&lv->merit);
  AmLevelState* s = &lv->s;
  free(s->U), free(s->lam_u), free(s->lam_c), free(s->memory), free(s->lbc), free(s->ubc);
  free(lv->U0), free(lv->lam_u0), free(lv->lam_c0), free(lv->memory0);
  AmTried* t = &s->tried;
  free(t->U), free(t->lam_u), free(t->lam_c), free(t->memory);
}

/* level i's solve in this step kept for the host (the step is left to it) */
static void level_tried(AmController* c, int i) {
  AmLevelState* s = &c->level[i].s;
  AmTried* t = &s->tried;
  size_t nU = sizeof(double) * (size_t)c->cfg->nU;
  size_t nc = sizeof(double) * (size_t)c->cfg->levels[i].dims[1];
  memcpy(t->U, s->U, nU), memcpy(t->lam_u, s->lam_u, nU);
  memcpy(t->lam_c, s->lam_c, nc), memcpy(t->memory, s->memory, nc);
  t->f = s->f, t->seconds = s->seconds, t->qp_excess = s->qp_excess;
  t->status = s->status, t->iterations = s->iterations;
  t->qp_exitflag = s->qp_exitflag, t->qp_finite = s->qp_finite;
  t->valid = 1;
}

/* level i's warm state kept (keep) or put back (!keep) */
static void level_backup(AmController* c, int i, int keep) {
  Level* lv = &c->level[i];
  size_t nU = sizeof(double) * (size_t)c->cfg->nU;
  size_t nc = sizeof(double) * (size_t)c->cfg->levels[i].dims[1];
  AmLevelState* s = &lv->s;
  if (keep) {
    memcpy(lv->U0, s->U, nU), memcpy(lv->lam_u0, s->lam_u, nU);
    memcpy(lv->lam_c0, s->lam_c, nc), memcpy(lv->memory0, s->memory, nc);
    lv->f0 = s->f, lv->warm0 = s->warm;
  } else {
    memcpy(s->U, lv->U0, nU), memcpy(s->lam_u, lv->lam_u0, nU);
    memcpy(s->lam_c, lv->lam_c0, nc), memcpy(s->memory, lv->memory0, nc);
    s->f = lv->f0, s->warm = lv->warm0;
  }
}

static int state_new(AmState* s, const AmConfig* cfg) {
  int nx = cfg->nx, N = cfg->N;
  s->u_prev = zeros(nx), s->p = zeros(cfg->np), s->first = zeros(cfg->nU);
  s->plan_x = zeros((N + 1) * nx), s->plan_u = zeros(N * nx);
  return s->u_prev && s->p && s->first && s->plan_x && s->plan_u;
}

static void state_free(AmState* s) {
  free(s->u_prev), free(s->p), free(s->first), free(s->plan_x), free(s->plan_u);
}

/* the memory between steps copied (the parameters are not: they are the step's) */
static void state_copy(AmState* to, const AmState* from, const AmConfig* cfg) {
  size_t nx = (size_t)cfg->nx, N = (size_t)cfg->N;
  memcpy(to->u_prev, from->u_prev, sizeof(double) * nx);
  memcpy(to->first, from->first, sizeof(double) * (size_t)cfg->nU);
  memcpy(to->plan_x, from->plan_x, sizeof(double) * (N + 1) * nx);
  memcpy(to->plan_u, from->plan_u, sizeof(double) * N * nx);
  to->has_plan = from->has_plan, to->plan_age = from->plan_age, to->has_first = from->has_first;
}

static int largest_rows(const AmConfig* cfg) {
  int nc = 1;
  for (int i = 0; i < cfg->n_levels; ++i)
    if (cfg->levels[i].dims[1] > nc) nc = cfg->levels[i].dims[1];
  return nc;
}

AmController* am_new(const AmConfig* cfg) {
  AmController* c = calloc(1, sizeof *c);
  if (!c) return 0;
  c->cfg = cfg;
  c->level = calloc((size_t)cfg->n_levels, sizeof *c->level);
  int nc = largest_rows(cfg);
  c->guess = zeros(cfg->nU), c->gc = zeros(nc);
  c->scratch = zeros(nc > cfg->nU ? nc : cfg->nU);
  int ok = state_new(&c->s, cfg);
  ok = state_new(&c->before, cfg) && ok;
  ok = c->level && c->guess && c->gc && c->scratch && ok;
  ok = fn_new(&c->parameters, cfg->parameters, cfg->parameters_work) && ok;
  ok = fn_new(&c->plan, cfg->plan, cfg->plan_work) && ok;
  for (int i = 0; ok && i < cfg->n_levels; ++i)
    ok = level_new(&c->level[i], cfg, &cfg->levels[i]);
  if (!ok) {
    am_free(c);
    return 0;
  }
  memcpy(c->opts, cfg->opts, sizeof c->opts);
  am_reset(c, 0);
  return c;
}

void am_free(AmController* c) {
  if (!c) return;
  if (c->level)
    for (int i = 0; i < c->cfg->n_levels; ++i) level_free(&c->level[i]);
  free(c->level);
  fn_free(&c->parameters);
  fn_free(&c->plan);
  state_free(&c->s);
  state_free(&c->before);
  free(c->guess), free(c->gc), free(c->scratch);
  free(c);
}

void am_reset(AmController* c, const double* u_prev) {
  for (int i = 0; i < c->cfg->nx; ++i) c->s.u_prev[i] = u_prev ? u_prev[i] : 0.0;
  c->s.has_plan = 0;
  c->s.plan_age = 0;
  c->s.has_first = 0;
  c->has_before = 0;
  for (int i = 0; i < c->cfg->n_levels; ++i) c->level[i].s.warm = 0;
}

void am_discard(AmController* c) {
  if (!c || !c->has_before) return;
  c->has_before = 0;
  AmState* s = &c->s;
  state_copy(s, &c->before, c->cfg);
  int nx = c->cfg->nx;
  if (s->has_plan && s->plan_age + 1 < c->cfg->N) {
    s->plan_age += 1;
    memcpy(s->u_prev, s->plan_u + s->plan_age * nx, sizeof(double) * (size_t)nx);
  } else { /* no plan flies: none of its answers is a guess either */
    s->has_plan = 0;
    s->has_first = 0;
  }
}

AmState* am_state(AmController* c) { return &c->s; }

AmLevelState* am_level_state(AmController* c, int i) {
  return i >= 0 && i < c->cfg->n_levels ? &c->level[i].s : 0;
}

static void permute(double* v, const int* from, int n, double* scratch) {
  for (int i = 0; i < n; ++i) scratch[i] = v[from[i]];
  memcpy(v, scratch, sizeof(double) * (size_t)n);
}

static double clip(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* the first level's last answer moved on a step, or the last plan moved on to now
   (its last command repeated), or rest */
static void initial_guess(AmController* c) {
  const AmState* s = &c->s;
  int nx = c->cfg->nx, N = c->cfg->N;
  const double* from_u = s->has_first ? s->first : (s->has_plan ? s->plan_u : 0);
  int steps = 1 + s->plan_age; /* the plan's age: steps it flew since it was solved */
  for (int k = 0; k < N; ++k) {
    int from = k + steps < N ? k + steps : N - 1;
    for (int i = 0; i < nx; ++i) c->guess[k * nx + i] = from_u ? from_u[from * nx + i] : 0.0;
  }
}

/* one solve of level i from `start` (clipped to the command bounds): warm with its last
   multipliers moved a stage on, or cold */
static int solve(AmController* c, int i, const double* start, int warm, SqpInfo* info) {
  const AmConfig* cfg = c->cfg;
  Level* lv = &c->level[i];
  AmLevelState* s = &lv->s;
  int nU = cfg->nU, nc = cfg->levels[i].dims[1];
  for (int j = 0; j < nU; ++j) s->U[j] = clip(start[j], cfg->lbU[j], cfg->ubU[j]);
  if (warm) {
    permute(s->lam_c, cfg->levels[i].shift_rows, nc, c->scratch);
    permute(s->lam_u, cfg->shift_vars, nU, c->scratch);
    permute(s->memory, cfg->levels[i].shift_rows, nc, c->scratch);
  } else {
    memset(s->lam_c, 0, sizeof(double) * (size_t)nc);
    memset(s->lam_u, 0, sizeof(double) * (size_t)nU);
    memset(s->memory, 0, sizeof(double) * (size_t)nc);
  }
  c->opts[OPT_WARM] = warm ? 1.0 : 0.0;
  return sqp_solve(lv->sqp, c->opts, c->s.p, s->lbc, s->ubc, cfg->lbU, cfg->ubU, s->U,
                   s->lam_c, s->lam_u, s->memory, info);
}

static int finite_all(const double* v, int n) {
  for (int i = 0; i < n; ++i)
    if (!isfinite(v[i])) return 0;
  return 1;
}

static int succeeded(const AmController* c, int status, const double* U) {
  int ok = status == ST_SOLVED || status == ST_ACCEPTABLE || status == ST_RTI ||
           status == ST_FEASIBLE_AT_MAX_ITER;
  return ok && finite_all(U, c->cfg->nU);
}

/* level i's row bounds: its own, and the rows that hold a higher level's residuals at
   their values at that level's answer (Hierarchical._bounds, strict); 0 if a generated
   function failed */
static int level_bounds(AmController* c, int i) {
  const AmLevel* cfg = &c->cfg->levels[i];
  Level* lv = &c->level[i];
  if (fn_call(&lv->bounds, c->s.p, 0, 0, lv->s.lbc, lv->s.ubc, 0, 0, 0)) return 0;
  double f;
  for (int k = 0, at = -1; k < cfg->n_pins; ++k) {
    int row = cfg->pins[2 * k], higher = cfg->pins[2 * k + 1];
    if (higher != at) { /* the pins come grouped by the level they hold */
      if (fn_call(&lv->merit, c->level[higher].s.U, c->s.p, 0, &f, c->gc, 0, 0, 0)) return 0;
      at = higher;
    }
    lv->s.lbc[row] = lv->s.ubc[row] = c->gc[row];
  }
  return 1;
}

/* whether the level's warm answer costs so much more than its last one that the host
   seeds it again (SqpBackend.solve) */
static int reseed(const AmController* c, double f, double promise) {
  const AmConfig* cfg = c->cfg;
  return cfg->host_seeds && cfg->opts[OPT_RTI] == 0.0 && f > cfg->seed_ratio * promise + cfg->seed_floor;
}

/* level i solved from `start`; a warm solve that fails is retried cold (from where it
   stopped if it only ran out of iterations). The solver's status, or ST_HOST where the
   host seeds: before any solve (a cold one), or after it (a warm solve that failed, a
   costly answer; the solve is then kept in `tried`). */
static int solve_level(AmController* c, int i, const double* start) {
  AmLevelState* s = &c->level[i].s;
  double t0 = seconds();
  s->iterations = 0;
  s->qp_exitflag = 0, s->qp_finite = 1, s->qp_excess = 0.0;
  if (c->cfg->host_seeds && !s->warm) return ST_HOST;
  if (!level_bounds(c, i)) {
    s->warm = 0;
    s->seconds = seconds() - t0;
    return s->status = ST_MODEL_FAILED;
  }
  SqpInfo info;
  int warm = s->warm, host = 0;
  double promise = s->f;
  int status = solve(c, i, start, warm, &info);
  s->iterations += info.iterations;
  /* accept_at_max_iter bounds the step: a solve that ran out of iterations is final */
  int spent = status == ST_MAX_ITER && c->cfg->opts[OPT_ACCEPT_AT_MAX_ITER] != 0.0;
  if (!succeeded(c, status, s->U) && warm && !spent) { /* stale multipliers: retry cold */
    if (c->cfg->host_seeds) {
      host = 1;
    } else {
      int go_on = status == ST_MAX_ITER && finite_all(s->U, c->cfg->nU);
      status = solve(c, i, go_on ? s->U : start, 0, &info);
      s->iterations += info.iterations;
    }
  }
  s->f = info.f;
  s->warm = succeeded(c, status, s->U);
  s->qp_exitflag = info.qp_exitflag, s->qp_finite = info.qp_finite;
  s->qp_excess = info.qp_excess;
  s->seconds = seconds() - t0;
  s->status = status;
  if (host || (s->warm && warm && reseed(c, info.f, promise))) {
    level_tried(c, i);
    return ST_HOST;
  }
  return status;
}

/* on failure: the last plan's next command (clipped to the bounds), or stop (the plan:
   rest at the start, the state the model predicts when the command lands) */
static int fall_back(AmController* c, AmOutput* out) {
  const AmConfig* cfg = c->cfg;
  AmState* s = &c->s;
  size_t nx = (size_t)cfg->nx, N = (size_t)cfg->N;
  out->cost = NAN;
  out->levels = 0;
  if (s->has_plan && s->plan_age + 1 < cfg->N) {
    s->plan_age += 1;
    for (int i = 0; i < cfg->nx; ++i)
      out->u[i] = clip(s->plan_u[s->plan_age * cfg->nx + i], cfg->u_lower[i], cfg->u_upper[i]);
    memcpy(out->plan_x, s->plan_x, sizeof(double) * (N + 1) * nx);
    memcpy(out->plan_u, s->plan_u, sizeof(double) * N * nx);
    return AM_FALLBACK;
  }
  s->has_plan = 0;
  memset(out->u, 0, sizeof(double) * nx);
  memset(out->plan_u, 0, sizeof(double) * N * nx);
  for (size_t k = 0; k <= N; ++k) memcpy(out->plan_x + k * nx, s->p, sizeof(double) * nx);
  return AM_STOPPED;
}

/* the answer of the last level solved flies: its plan, and the first level's answer
   kept as the next guess */
static int fly(AmController* c, int solved, AmOutput* out) {
  const AmConfig* cfg = c->cfg;
  AmState* s = &c->s;
  size_t nx = (size_t)cfg->nx, N = (size_t)cfg->N;
  const Level* lv = &c->level[solved - 1];
  if (fn_call(&c->plan, s->p, lv->s.U, 0, s->plan_x, 0, 0, 0, 0)) return fall_back(c, out);
  memcpy(s->plan_u, lv->s.U, sizeof(double) * N * nx);
  memcpy(s->first, c->level[0].s.U, sizeof(double) * (size_t)cfg->nU);
  s->has_plan = s->has_first = 1;
  s->plan_age = 0;
  memcpy(out->u, s->plan_u, sizeof(double) * nx);
  memcpy(out->plan_x, s->plan_x, sizeof(double) * (N + 1) * nx);
  memcpy(out->plan_u, s->plan_u, sizeof(double) * N * nx);
  out->cost = lv->s.f;
  return solved == cfg->n_levels ? AM_OK : AM_PARTIAL;
}

/* the solve's parameters from x, the command in flight and the actual rates (the
   command in flight where not measured); nonzero if the generated function failed */
static int parameters(AmController* c, const double* x, const double* rates, double t) {
  Fn* fn = &c->parameters;
  fn->arg[0] = x;
  fn->arg[1] = c->s.u_prev;
  fn->arg[2] = rates ? rates : c->s.u_prev;
  fn->arg[3] = &t;
  fn->res[0] = c->s.p;
  return fn->f(fn->arg, fn->res, fn->iw, fn->w, 0);
}

/* the levels solved in turn from the guess, until one fails; the last one's status (or
   ST_HOST); *solved: how many succeeded */
static int solve_levels(AmController* c, int* solved, int* iterations) {
  int status = ST_MODEL_FAILED, n = c->cfg->n_levels;
  initial_guess(c);
  for (*solved = 0; *solved < n; ++*solved) {
    int i = *solved;
    const double* start = i ? c->level[i - 1].s.U : c->guess;
    if (c->cfg->host_seeds) level_backup(c, i, 1);
    status = solve_level(c, i, start);
    if (status == ST_HOST) { /* the levels above: solved, kept for the host too */
      for (int j = 0; j < i; ++j) level_tried(c, j);
      for (int j = 0; j <= i; ++j) level_backup(c, j, 0);
      return ST_HOST;
    }
    *iterations += c->level[i].s.iterations;
    if (!succeeded(c, status, c->level[i].s.U)) break;
  }
  return status;
}

int am_step(AmController* c, const double* x, const double* rates, double t, AmOutput* out) {
  if (!c || !x || !out) return AM_BAD_INPUT;
  const AmConfig* cfg = c->cfg;
  if (!finite_all(x, cfg->nx) || (rates && !finite_all(rates, cfg->nx)) || !isfinite(t))
    return out->status = AM_BAD_INPUT;
  int status = ST_MODEL_FAILED, iterations = 0, solved = 0;
  for (int i = 0; i < cfg->n_levels; ++i) {
    AmLevelState* s = &c->level[i].s;
    s->status = 0, s->seconds = 0.0, s->tried.valid = 0;
  }
  if (!parameters(c, x, rates, t)) status = solve_levels(c, &solved, &iterations);
  if (status == ST_HOST) return out->status = AM_HOST;
  state_copy(&c->before, &c->s, cfg);
  c->has_before = 1;
  out->solver_status = status;
  out->iterations = iterations;
  out->levels = solved;
  if (solved) {
    out->status = fly(c, solved, out);
  } else {
    c->s.has_first = 0;
    out->status = fall_back(c, out);
  }
  if (out->status == AM_FALLBACK || out->status == AM_STOPPED) c->s.has_first = 0;
  memcpy(c->s.u_prev, out->u, sizeof(double) * (size_t)cfg->nx);
  return out->status;
}
