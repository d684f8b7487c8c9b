/*
 * The SQP loop of the condensed QP model in C: one call per solve.
 *
 * The same algorithm, step for step, as the Python loop of aeromanip's SQP
 * (nmpc/backends/sqp/solver.py with condensed_qp.py, dense_qp.py, convexify.py and
 * optimality.py): Gauss-Newton or exact (convexified) Hessians, DAQP on the rows that
 * may bind (screened, as dense_qp.py does), an l1 merit with Armijo backtracking and
 * second-order corrections, Levenberg-Marquardt damping, KKT and acceptable-level stops,
 * real-time iterations. The model's Functions (residuals, rows and their Jacobians; the
 * merit; the exact Hessian of the Lagrangian) are CasADi-generated C, called through the
 * pointers given to sqp_new. Every buffer is allocated once by sqp_new; DAQP allocates
 * its own workspace per QP.
 *
 * Matrices are column-major (CasADi's layout) unless said otherwise.
 */

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sqp_loop.h"

/* -- the model's Functions ------------------------------------------------------------ */

/* -- the loop (solver.py: _sqp, _verdict, _line_search) ---------------------------- */

/* the merit's parts at U + step: cost and l1 violation */
static int merit(Sqp* s, const double* U, const double* step, const double* p,
                 const double* lbc, const double* ubc, double* f, double* viol) {
  double* Ut = s->tmp;
  for (int j = 0; j < s->nU; ++j) Ut[j] = U[j] + step[j];
  if (fn_call(&s->merit, Ut, p, 0, f, s->trial_c, 0, 0, 0)) return 1;
  *viol = la_l1(s->trial_c, lbc, ubc, s->nc);
  return 0;
}

static double kkt_error(Sqp* s, const double* U, const double* lbc, const double* ubc,
                        const double* lbU, const double* ubU, const double* lam_c,
                        const double* lam_u) {
  int n = s->nU;
  double k1 = la_complementarity(s->c, lbc, ubc, lam_c, s->nc);
  double k2 = la_complementarity(U, lbU, ubU, lam_u, n);
  la_matvec_t(s->A, s->nc, n, lam_c, s->tmp);
  double st = 0.0;
  for (int j = 0; j < n; ++j) {
    double v = fabs(s->grad[j] + s->tmp[j] + lam_u[j]);
    if (v > st || isnan(v)) st = v;
  }
  double k = k1 > k2 ? k1 : k2;
  return st > k || isnan(st) ? st : k;
}

/* opts: max_iter, tol, acceptable_tol, constr_viol_tol, acceptable_iter, rti, hessian
   (HESS_*), regularization, warm (multipliers given), accept_at_max_iter */
/* the bounds of one solve and its options */
typedef struct {
  const double *p, *lbc, *ubc, *lbU, *ubU;
  int max_iter, acceptable_iter, rti, hess_mode, warm, accept_at_max_iter;
  double tol, acceptable_tol, constr_viol_tol, regularization;
} Problem;

/* the stopping test at an iterate (solver.py: _verdict): the status to stop with (0: go
   on); `acceptable` counts the iterations in a row at the acceptable level */
static int verdict(Sqp* s, const Problem* pb, const double* U, const double* lam_c,
                   const double* lam_u, int it, int* acceptable) {
  double viol = pb->rti ? 0.0 : la_violation(s->c, pb->lbc, pb->ubc, s->nc);
  double kkt = INFINITY;
  if (!pb->rti && (it > 0 || pb->warm) && viol <= pb->constr_viol_tol) {
    kkt = kkt_error(s, U, pb->lbc, pb->ubc, pb->lbU, pb->ubU, lam_c, lam_u);
    if (kkt <= pb->tol && viol <= pb->tol) return ST_SOLVED;
  }
  *acceptable = kkt <= pb->acceptable_tol ? *acceptable + 1 : 0;
  if (*acceptable >= pb->acceptable_iter || (it >= pb->max_iter && *acceptable))
    return ST_ACCEPTABLE;
  if (it < pb->max_iter) return 0;
  return pb->accept_at_max_iter && viol <= pb->constr_viol_tol ? ST_FEASIBLE_AT_MAX_ITER
                                                                : ST_MAX_ITER;
}

/* second-order corrections of the step s->qd (condensed_qp.py: correction; solver.py:
   _line_search): the last QP with its rows taken at the end of the last step tried (their
   values there in s->trial_c, viol1 their violation), up to max_soc in a row while each
   cuts the violation by kappa_soc; accepted (1) if a step passes the merit test, and
   then it is in s->sd with its multipliers in lam_c, lam_u; *solved counts the QPs */
static int corrected(Sqp* s, const Problem* pb, const double* U, double* memory,
                     double mu, double phi0, double descent, double viol1, double* lam_c,
                     double* lam_u, int max_soc, int* solved, int* failed) {
  int n = s->nU, nc = s->nc;
  const double* step = s->qd;
  while (*solved < max_soc) {
    la_matvec(s->A, nc, n, step, s->Ad); /* before the QP writes s->sd */
    for (int i = 0; i < nc; ++i) {
      double cc = s->trial_c[i] - s->Ad[i];
      s->lba[i] = pb->lbc[i] - cc;
      s->uba[i] = pb->ubc[i] - cc;
    }
    QpOutcome soc = qp_solve(s, s->H, s->grad, s->A, s->lba, s->uba, s->lbx, s->ubx, memory,
                             s->sd, s->slam_a, s->slam_x);
    ++*solved;
    double fs, vs;
    if (!soc.ok) return 0;
    if (merit(s, U, s->sd, pb->p, pb->lbc, pb->ubc, &fs, &vs)) {
      *failed = 1;
      return 0;
    }
    if (fs + mu * vs <= phi0 + s->k.armijo * descent) {
      memcpy(lam_c, s->slam_a, sizeof(double) * nc);
      memcpy(lam_u, s->slam_x, sizeof(double) * n);
      return 1;
    }
    if (vs > s->k.kappa_soc * viol1) return 0;
    viol1 = vs;
    step = s->sd;
  }
  return 0;
}

/* Armijo backtracking on the l1 merit f + mu * violations (solver.py: _line_search):
   the step length (0 if the model failed); *d becomes the corrected step if the full
   step was accepted only with second-order corrections (at most max_soc; *solved counts
   them) */
static double line_search(Sqp* s, const Problem* pb, const double* U, double f, double mu,
                          double* memory, double* lam_c, double* lam_u, const double** d,
                          int max_soc, int* solved) {
  int n = s->nU, failed = 0;
  double viol0 = la_l1(s->c, pb->lbc, pb->ubc, s->nc), phi0 = f + mu * viol0;
  double slope = la_dot(s->grad, s->qd, n) - mu * viol0;
  double descent = slope < 0.0 ? slope : 0.0, f1, viol1, alpha = s->k.backtrack;
  *d = s->qd;
  if (merit(s, U, s->qd, pb->p, pb->lbc, pb->ubc, &f1, &viol1)) return 0.0;
  if (f1 + mu * viol1 <= phi0 + s->k.armijo * descent) return 1.0;
  /* a bounded solve's corrections count: rounding must not decide them */
  if (viol1 > viol0 + (pb->accept_at_max_iter ? s->k.soc_min_rise : 0.0)) {
    if (corrected(s, pb, U, memory, mu, phi0, descent, viol1, lam_c, lam_u, max_soc, solved,
                  &failed)) {
      *d = s->sd;
      return 1.0;
    }
    if (failed) return 0.0;
  }
  for (;;) {
    for (int j = 0; j < n; ++j) s->Ad[j] = alpha * s->qd[j];
    if (merit(s, U, s->Ad, pb->p, pb->lbc, pb->ubc, &f1, &viol1)) return 0.0;
    if (f1 + mu * viol1 <= phi0 + s->k.armijo * alpha * descent || alpha < s->k.min_step)
      return alpha;
    alpha *= s->k.backtrack;
  }
}

/* the model at U (s->R, J, c, A, Jh), the cost and its gradient; 0, or a status */
static int linearize(Sqp* s, const double* U, const double* p, double* f) {
  if (fn_call(&s->data, U, p, 0, s->R, s->J, s->c, s->A, s->Jh)) return ST_MODEL_FAILED;
  *f = la_dot(s->R, s->R, s->nr);
  la_matvec_t(s->J, s->nr, s->nU, s->R, s->grad);
  for (int j = 0; j < s->nU; ++j) s->grad[j] *= 2.0;
  return isfinite(*f) ? 0 : ST_INVALID;
}

/* the QP step from U into s->qd (its multipliers into lam_c, lam_u); 0, or a status */
static int qp_step(Sqp* s, const Problem* pb, const double* U, double* lam_c, double* lam_u,
                   double* memory, int exact, double damping, SqpInfo* info) {
  int n = s->nU, nc = s->nc;
  if (hessian(s, U, pb->p, lam_c, lam_u, exact, pb->regularization, damping,
              pb->accept_at_max_iter))
    return ST_MODEL_FAILED;
  for (int i = 0; i < nc; ++i) {
    s->lba[i] = pb->lbc[i] - s->c[i];
    s->uba[i] = pb->ubc[i] - s->c[i];
  }
  for (int j = 0; j < n; ++j) {
    s->lbx[j] = pb->lbU[j] - U[j];
    s->ubx[j] = pb->ubU[j] - U[j];
  }
  QpOutcome qp = qp_solve(s, s->H, s->grad, s->A, s->lba, s->uba, s->lbx, s->ubx, memory,
                          s->qd, s->qlam_a, s->qlam_x);
  if (!qp.ok) {
    info->qp_exitflag = qp.exitflag;
    info->qp_finite = qp.finite;
    info->qp_excess = qp.excess;
    return ST_QP_FAILED;
  }
  memcpy(lam_c, s->qlam_a, sizeof(double) * nc);
  memcpy(lam_u, s->qlam_x, sizeof(double) * n);
  return 0;
}

/* opts: OPT_COUNT values, in the order of OPT_* (sqp_loop.h) */
int sqp_solve(Sqp* s, const double* opts, const double* p, const double* lbc,
              const double* ubc, const double* lbU, const double* ubU, double* U,
              double* lam_c, double* lam_u, double* memory, SqpInfo* info) {
  Problem pb = {p, lbc, ubc, lbU, ubU, (int)opts[OPT_MAX_ITER], (int)opts[OPT_ACCEPTABLE_ITER],
                opts[OPT_RTI] != 0.0, (int)opts[OPT_HESSIAN], opts[OPT_WARM] != 0.0,
                opts[OPT_ACCEPT_AT_MAX_ITER] != 0.0, opts[OPT_TOL], opts[OPT_ACCEPTABLE_TOL],
                opts[OPT_CONSTR_VIOL_TOL], opts[OPT_REGULARIZATION]};
  if (pb.rti) pb.max_iter = 1;
  double mu = 0.0, damping = 0.0, f;
  int it = 0, acceptable = 0, status, exact = pb.hess_mode == HESS_EXACT;
  memset(info, 0, sizeof *info);
  info->f = NAN;
  for (;;) {
    status = linearize(s, U, p, &f);
    if (status != ST_MODEL_FAILED) info->f = f;
    if (status || (status = verdict(s, &pb, U, lam_c, lam_u, it, &acceptable))) break;
    status = qp_step(s, &pb, U, lam_c, lam_u, memory, exact, damping, info);
    ++it;
    if (status) break;
    if (pb.rti) {
      for (int j = 0; j < s->nU; ++j) U[j] += s->qd[j];
      status = ST_RTI;
      break;
    }
    double lam_top = 0.0;
    for (int i = 0; i < s->nc; ++i)
      if (fabs(lam_c[i]) > lam_top) lam_top = fabs(lam_c[i]);
    double penalty = s->k.penalty_margin * lam_top + s->k.penalty_floor;
    if (penalty > mu) mu = penalty;
    const double* d;
    /* a bounded solve counts its corrections as QPs */
    int max_soc = (int)s->k.max_soc, corrections = 0;
    if (pb.accept_at_max_iter && pb.max_iter - it < max_soc) max_soc = pb.max_iter - it;
    double alpha =
        line_search(s, &pb, U, f, mu, memory, lam_c, lam_u, &d, max_soc, &corrections);
    if (pb.accept_at_max_iter) it += corrections;
    if (alpha == 0.0) {
      status = ST_MODEL_FAILED;
      break;
    }
    for (int j = 0; j < s->nU; ++j) U[j] += alpha * d[j];
    if (alpha < 1.0)
      damping = fmax(s->k.damping_growth * damping, s->k.damping_start);
    else if ((damping /= s->k.damping_growth) < s->k.damping_start)
      damping = 0.0;
    if (pb.hess_mode == HESS_AUTO) exact = exact || alpha < 1.0 || it >= s->k.exact_from_iteration;
  }
  info->iterations = it;
  return status;
}

/* -- setup ------------------------------------------------------------------------- */

void sqp_free(Sqp* s) {
  if (!s) return;
  fn_free(&s->data);
  fn_free(&s->merit);
  if (s->has_hess) fn_free(&s->hess);
  double** bufs[] = {&s->R, &s->J, &s->c, &s->A, &s->Jh, &s->grad, &s->H, &s->trial_c,
                     &s->qd, &s->qlam_a, &s->qlam_x, &s->lba, &s->uba, &s->lbx, &s->ubx,
                     &s->Ad, &s->soc_c, &s->sd, &s->slam_a, &s->slam_x, &s->dH, &s->dA,
                     &s->dlo, &s->dup, &s->dlam, &s->rlam, &s->tmp, &s->L, &s->C, &s->V,
                     &s->Hc, &s->w_scaling, &s->w_M, &s->w_dupper, &s->w_dlower,
                     &s->w_Rinv, &s->w_v, &s->w_R, &s->T, &s->factor};
  for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; ++i) free(*bufs[i]);
  s->work.settings = 0; /* s's own: not DAQP's to free */
  free_daqp_workspace(&s->work);
  free(s->w_sense);
  free(s->sense);
  free(s->rows);
  free(s->near);
  free(s->hier_row);
  free(s->always);
  free(s);
}

/* dims: nU, nc, nr, nh, np; sizes: the screened QP's row counts (ascending, the last
   nc); consts: the Python loop's constants in Constants' order; daqp: primal_tol,
   dual_tol, zero_tol, pivot_tol, progress_tol, cycle_tol, iter_limit, eps_prox, eta_prox
   (NaN: DAQP's default) */
Sqp* sqp_new(const int* dims, const int* hier_row, const unsigned char* always,
             const int* sizes, int n_sizes, double screen, const double* daqp,
             const double* consts, casadi_fn data, casadi_work_fn data_work, casadi_fn merit_fn,
             casadi_work_fn merit_work, casadi_fn hess, casadi_work_fn hess_work) {
  if (n_sizes > MAX_SIZES) return 0;
  Sqp* s = calloc(1, sizeof(Sqp));
  if (!s) return 0;
  s->nU = dims[0], s->nc = dims[1], s->nr = dims[2], s->nh = dims[3], s->np = dims[4];
  s->has_hess = hess != 0;
  s->k = (Constants){consts[0],  consts[1],  consts[2],  consts[3],  consts[4],  consts[5],
                     consts[6],  consts[7],  consts[8],  consts[9],  consts[10], consts[11],
                     consts[12], consts[13], consts[14], consts[15], consts[16],
                     consts[17]};
  int ok = fn_new(&s->data, data, data_work) && fn_new(&s->merit, merit_fn, merit_work);
  if (s->has_hess) ok = ok && fn_new(&s->hess, hess, hess_work);
  size_t n = (size_t)s->nU, nc = (size_t)s->nc, nr = (size_t)s->nr, nh = (size_t)s->nh;
  size_t nm = n > nc ? n : nc, big = n * (n > nc ? n : nc), wide = nh > nc ? nh : nc;
  struct { double** p; size_t size; } plan[] = {
      {&s->R, nr}, {&s->J, nr * n}, {&s->c, nc}, {&s->A, nc * n}, {&s->Jh, nh * n},
      {&s->grad, n}, {&s->H, n * n}, {&s->trial_c, nc}, {&s->qd, n}, {&s->qlam_a, nc},
      {&s->qlam_x, n}, {&s->lba, nc}, {&s->uba, nc}, {&s->lbx, n}, {&s->ubx, n},
      {&s->Ad, nm}, {&s->soc_c, nc}, {&s->sd, n}, {&s->slam_a, nc}, {&s->slam_x, n},
      {&s->dH, n * n}, {&s->dA, big}, {&s->dlo, n + nc}, {&s->dup, n + nc},
      {&s->dlam, n + nc}, {&s->rlam, nc}, {&s->tmp, nm}, {&s->L, n * n},
      {&s->C, wide * n}, {&s->V, n * n}, {&s->Hc, n * n}, {&s->w_scaling, n + nc},
      {&s->w_M, n * nc}, {&s->w_dupper, n + nc}, {&s->w_dlower, n + nc},
      {&s->w_Rinv, n * (n + 1) / 2}, {&s->w_v, n}, {&s->w_R, n * n},
      {&s->T, (nr > wide ? nr : wide) * n}, {&s->factor, n * (n + 1) / 2}};
  for (size_t i = 0; i < sizeof plan / sizeof plan[0]; ++i) {
    *plan[i].p = calloc(plan[i].size + 1, sizeof(double));
    ok = ok && *plan[i].p;
  }
  s->sense = calloc(n + nc + 1, sizeof(int));
  s->rows = calloc(nc + 1, sizeof(int));
  s->near = calloc(nc + 1, 1);
  s->hier_row = calloc(nh + 1, sizeof(int));
  s->always = calloc(nc + 1, 1);
  s->w_sense = calloc(n + nc + 1, sizeof(int));
  allocate_daqp_workspace(&s->work, (int)n, 0);
  ok = ok && s->sense && s->rows && s->near && s->hier_row && s->always;
  ok = ok && s->w_sense && s->work.lam && s->work.lam_star && s->work.WS && s->work.D &&
       s->work.xldl && s->work.zldl && s->work.L && s->work.u && s->work.xold;
  if (!ok) {
    sqp_free(s);
    return 0;
  }
  if (nh) memcpy(s->hier_row, hier_row, sizeof(int) * nh);
  memcpy(s->always, always, nc);
  memcpy(s->sizes, sizes, sizeof(int) * (size_t)n_sizes);
  s->n_sizes = n_sizes;
  s->screen = screen;
  daqp_default_settings(&s->settings); /* then those given (NaN: DAQP's default) */
  s->work.settings = &s->settings;
  if (!isnan(daqp[0])) s->settings.primal_tol = daqp[0];
  if (!isnan(daqp[1])) s->settings.dual_tol = daqp[1];
  if (!isnan(daqp[2])) s->settings.zero_tol = daqp[2];
  if (!isnan(daqp[3])) s->settings.pivot_tol = daqp[3];
  if (!isnan(daqp[4])) s->settings.progress_tol = daqp[4];
  if (!isnan(daqp[5])) s->settings.cycle_tol = (int)daqp[5];
  if (!isnan(daqp[6])) s->settings.iter_limit = (int)daqp[6];
  if (!isnan(daqp[7])) s->settings.eps_prox = daqp[7];
  if (!isnan(daqp[8])) s->settings.eta_prox = daqp[8];
  return s;
}
