/*
 * The compiled SQP loop's QP step on the condensed model: the Hessian (Gauss-Newton, or
 * the exact one convexified: condensed_qp.py, convexify.py) and the dense QP solved by
 * DAQP on the rows that may bind (dense_qp.py).
 */
#include <math.h>
#include <string.h>

#include "daqp/auxiliary.h"
#include "daqp/daqp.h"
#include "daqp/utils.h"
#include "sqp_loop.h"

/* -- the dense QP on the rows that may bind (dense_qp.py) --------------------------- */


/* H has no off-diagonal entry beyond DAQP's 1e-12 (its update_Rinv's test) */
static int diagonal(const double* H, int n) {
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j)
      if (fabs(H[(size_t)i * n + j]) > 1e-12) return 0;
  return 1;
}

/* the LDP's M = A Rinv (A: r x n, rows) and v = Rinv' f, Rinv packed by rows (DAQP's
   update_M and update_v, which run along its packed columns) */
static void ldp_products(const double* Rinv, const double* A, const double* f, int n, int r,
                         double* M, double* v) {
  for (int k = 0; k < r; ++k) la_packed_vecmat(A + (size_t)k * n, Rinv, n, M + (size_t)k * n);
  la_packed_vecmat(f, Rinv, n, v);
}

/* DAQP's setup_daqp (its api.c) in the workspace allocated once by sqp_new: the same
   LDP, nothing allocated */
static int setup_rows(Sqp* s, DAQPProblem* qp) {
  DAQPWorkspace* w = &s->work;
  w->n = qp->n;
  w->m = qp->m;
  w->ms = qp->ms;
  w->qp = qp;
  w->scaling = s->w_scaling;
  w->M = s->w_M;
  w->dupper = s->w_dupper;
  w->dlower = s->w_dlower;
  w->sense = s->w_sense;
  w->Rinv = s->w_Rinv; /* update_Rinv moves it to RinvD where H is diagonal */
  w->RinvD = 0;
  w->v = s->w_v;
  for (int i = 0; i < qp->ms; ++i) w->scaling[i] = 1;
  reset_daqp_workspace(w);
  if (diagonal(qp->H, qp->n)) { /* DAQP's own path: no factor */
    int flag = update_ldp(UPDATE_Rinv + UPDATE_M + UPDATE_v + UPDATE_d + UPDATE_sense, w);
    return flag < 0 ? flag : activate_constraints(w);
  }
  /* update_ldp's steps in its order, the products by rows (contiguous, vectorised) */
  for (int i = 0; i < qp->m; ++i) w->sense[i] = qp->sense[i];
  size_t packed = (size_t)qp->n * (qp->n + 1) / 2;
  if (s->factor_valid) {
    memcpy(w->Rinv, s->factor, sizeof(double) * packed);
  } else {
    if (!la_cholesky_inverse_packed(qp->H, qp->n, w->settings->eps_prox, s->w_R, w->Rinv))
      return EXIT_NONCONVEX;
    memcpy(s->factor, w->Rinv, sizeof(double) * packed);
    s->factor_valid = 1;
  }
  ldp_products(w->Rinv, qp->A, qp->f, qp->n, qp->m - qp->ms, w->M, w->v);
  normalize_M(w);
  normalize_Rinv(w);
  int flag = update_ldp(UPDATE_d, w);
  return flag < 0 ? flag : activate_constraints(w);
}

/* the QP with the rows `rows` (r of them) only: DAQP as CasADi's interface calls it */
static QpOutcome solve_rows(Sqp* s, const double* H, const double* g, const double* A,
                            const double* lba, const double* uba, const double* lbx,
                            const double* ubx, const int* rows, int r, double* d,
                            double* lam_r, double* lam_x) {
  int n = s->nU, m = n + r;
  QpOutcome out = {0, 0, 1, 0.0};
  memcpy(s->dH, H, sizeof(double) * (size_t)n * n);
  for (int i = 0; i < r; ++i)
    for (int j = 0; j < n; ++j) s->dA[(size_t)i * n + j] = A[rows[i] + (size_t)j * s->nc];
  for (int j = 0; j < n; ++j) {
    s->dlo[j] = lbx[j];
    s->dup[j] = ubx[j];
    s->sense[j] = lbx[j] == ubx[j] ? 5 : 0;
  }
  for (int i = 0; i < r; ++i) {
    s->dlo[n + i] = lba[rows[i]];
    s->dup[n + i] = uba[rows[i]];
    s->sense[n + i] = lba[rows[i]] == uba[rows[i]] ? 5 : 0;
  }
  DAQPProblem qp = {n, m, n, s->dH, (c_float*)g, s->dA, s->dup, s->dlo, s->sense};
  DAQPResult res;
  memset(&res, 0, sizeof res);
  res.x = d;
  res.lam = s->dlam;
  int flag = setup_rows(s, &qp);
  if (flag < 0) {
    for (int j = 0; j < n; ++j) d[j] = NAN;
    out.exitflag = flag;
  } else {
    daqp_solve(&res, &s->work);
    out.exitflag = res.exitflag;
  }
  memcpy(lam_x, s->dlam, sizeof(double) * n);
  memcpy(lam_r, s->dlam + n, sizeof(double) * r);
  /* a finite, feasible solution means success (as the Python path decides) */
  double dmax = 0.0;
  for (int j = 0; j < n; ++j) {
    if (!isfinite(d[j])) out.finite = 0;
    if (fabs(d[j]) > dmax) dmax = fabs(d[j]);
  }
  double tol = s->k.cross_tol * (1.0 + dmax), excess = 0.0;
  for (int i = 0; i < r; ++i) {
    double ad = 0.0;
    for (int j = 0; j < n; ++j) ad += s->dA[(size_t)i * n + j] * d[j];
    if (lba[rows[i]] - ad > excess) excess = lba[rows[i]] - ad;
    if (ad - uba[rows[i]] > excess) excess = ad - uba[rows[i]];
  }
  for (int j = 0; j < n; ++j) {
    if (lbx[j] - d[j] > excess) excess = lbx[j] - d[j];
    if (d[j] - ubx[j] > excess) excess = d[j] - ubx[j];
  }
  out.excess = excess;
  out.ok = out.finite && excess <= tol;
  return out;
}

/* the QP, first on the rows near their bounds, active at the last solve (`memory`) or
   always wanted; rows the answer crosses are added (dense_qp.DenseQp._active_set) */
QpOutcome qp_solve(Sqp* s, const double* H, const double* g, const double* A,
                          const double* lba, const double* uba, const double* lbx,
                          const double* ubx, double* memory, double* d, double* lam_a,
                          double* lam_x) {
  int nc = s->nc, n = s->nU;
  QpOutcome out;
  if (H != s->factor_of) { /* the kept factor is of the Hessian last passed here */
    s->factor_valid = 0;
    s->factor_of = H;
  }
  for (int i = 0; i < nc; ++i) {
    double slack = -lba[i] < uba[i] ? -lba[i] : uba[i];
    s->near[i] = s->always[i] || memory[i] != 0.0 || slack < s->screen;
  }
  int full = 1;
  for (int round = 0; round < s->k.screen_rounds; ++round) {
    int r = 0;
    for (int i = 0; i < nc; ++i)
      if (s->near[i]) s->rows[r++] = i;
    int k = nc;
    for (int t = 0; t < s->n_sizes; ++t)
      if (s->sizes[t] >= r) {
        k = s->sizes[t];
        break;
      }
    if (k == nc) break;
    out = solve_rows(s, H, g, A, lba, uba, lbx, ubx, s->rows, r, d, s->rlam, lam_x);
    if (!out.ok) {
      memset(lam_a, 0, sizeof(double) * nc);
      return out;
    }
    double dmax = 0.0;
    for (int j = 0; j < n; ++j)
      if (fabs(d[j]) > dmax) dmax = fabs(d[j]);
    double tol = s->k.cross_tol * (1.0 + dmax);
    la_matvec(A, nc, n, d, s->Ad);
    int crossed = 0;
    for (int i = 0; i < nc; ++i)
      if (!s->near[i] && (s->Ad[i] < lba[i] - tol || s->Ad[i] > uba[i] + tol)) {
        s->near[i] = 2;  /* added after this round */
        crossed = 1;
      }
    if (!crossed) {
      memset(lam_a, 0, sizeof(double) * nc);
      for (int i = 0; i < r; ++i) lam_a[s->rows[i]] = s->rlam[i];
      full = 0;
      break;
    }
  }
  if (full) {
    for (int i = 0; i < nc; ++i) s->rows[i] = i;
    out = solve_rows(s, H, g, A, lba, uba, lbx, ubx, s->rows, nc, d, lam_a, lam_x);
    if (!out.ok) memset(lam_a, 0, sizeof(double) * nc);
  }
  if (out.ok) memcpy(memory, lam_a, sizeof(double) * nc);
  return out;
}

/* -- Hessians (condensed_qp.py: _hessian; convexify.py) ----------------------------- */

/* into s->Hc: H + amount V (V = C'C of the active rows, plus the fixed variables' unit
   diagonal), or H + amount I (V null) */
static void modified(Sqp* s, const double* H, const double* V, double amount) {
  int n = s->nU;
  if (V)
    for (size_t i = 0; i < (size_t)n * n; ++i) s->Hc[i] = H[i] + amount * V[i];
  else {
    memcpy(s->Hc, H, sizeof(double) * (size_t)n * n);
    for (int j = 0; j < n; ++j) s->Hc[j + (size_t)j * n] += amount;
  }
}

/* the least i < count whose amount base * 10^(first + step i) makes H + amount V (or
   + amount I) positive definite, or -1. As convexify.least_passing: the last first, then
   bisection (a larger amount makes it so too) */
static int least_definite(Sqp* s, const double* H, const double* V, double base, double first,
                          double step, int count) {
  if (count <= 0) return -1;
  modified(s, H, V, base * pow(10.0, first + step * (count - 1)));
  if (!la_positive_definite(s->Hc, s->nU, s->L)) return -1;
  int lo = -1, hi = count - 1; /* definite at hi; not at lo (or lo = -1) */
  while (hi - lo > 1) {
    int mid = (lo + hi) / 2;
    modified(s, H, V, base * pow(10.0, first + step * mid));
    if (la_positive_definite(s->Hc, s->nU, s->L)) hi = mid;
    else lo = mid;
  }
  return hi;
}

/* H <- H + amount V (or + amount I) */
static void take_modified(Sqp* s, double* H, const double* V, double amount) {
  modified(s, H, V, amount);
  memcpy(H, s->Hc, sizeof(double) * (size_t)s->nU * s->nU);
}

/* H positive definite as it is, or H + rho C'C for the active rows C (and the variables
   at a bound), or (if shift) H + delta I, or H with its eigenvalues reflected
   (convexify.py: convexified) */
static void convexify(Sqp* s, double* H, const double* lam_c, const double* lam_u,
                      int shift) {
  int n = s->nU, nc = s->nc;
  if (la_positive_definite(H, n, s->L)) return;
  double scale = 0.0;
  for (int j = 0; j < n; ++j)
    if (fabs(H[j + (size_t)j * n]) > scale) scale = fabs(H[j + (size_t)j * n]);
  if (scale < 1e-8) scale = 1e-8;
  int nC = 0, nfixed = 0;
  for (int i = 0; i < nc; ++i) nC += lam_c[i] != 0.0;
  for (int j = 0; j < n; ++j) nfixed += lam_u[j] != 0.0;
  if (nC || nfixed) {
    double norms = 0.0;
    int r = 0;
    for (int i = 0; i < nc; ++i) {
      if (lam_c[i] == 0.0) continue;
      for (int j = 0; j < n; ++j) s->C[r + (size_t)j * nC] = s->A[i + (size_t)j * nc];
      ++r;
    }
    for (int i = 0; i < nC; ++i) {
      double rn = 0.0;
      for (int j = 0; j < n; ++j) rn += s->C[i + (size_t)j * nC] * s->C[i + (size_t)j * nC];
      norms += rn;
    }
    norms = (norms + nfixed) / (double)(nC + nfixed);
    double base = scale / (norms > 1e-12 ? norms : 1e-12);
    la_gram(s->C, nC, n, 1.0, s->V, 0, s->T); /* C'C, then the fixed variables' diagonal */
    for (int j = 0; j < n; ++j)
      if (lam_u[j] != 0.0) s->V[j + (size_t)j * n] += 1.0;
    int i = least_definite(s, H, s->V, base, 0.0, 1.0, (int)s->k.convexify_decades);
    if (i >= 0) {
      take_modified(s, H, s->V, base * pow(10.0, i));
      return;
    }
  }
  int count = shift ? (int)s->k.shift_count : 0;
  int i = least_definite(s, H, 0, scale, s->k.shift_first, s->k.shift_step, count);
  if (i >= 0) { /* one step above the least (convexify.above_least) */
    if (i + 1 < count) ++i;
    take_modified(s, H, 0, scale * pow(10.0, s->k.shift_first + s->k.shift_step * i));
    return;
  }
  double* lam = s->tmp;
  sqp_eigen_symmetric(H, n, lam, s->V, s->Hc);
  double top = 0.0;
  for (int i = 0; i < n; ++i)
    if (fabs(lam[i]) > top) top = fabs(lam[i]);
  double floor = s->k.eigen_floor * (top > 1e-3 ? top : 1e-3);
  for (int i = 0; i < n; ++i) lam[i] = fabs(lam[i]) > floor ? fabs(lam[i]) : floor;
  /* H = V diag(lam) V', column by column of V: the inner loops run down columns */
  memset(H, 0, sizeof(double) * (size_t)n * n);
  for (int k = 0; k < n; ++k) {
    const double* v = s->V + (size_t)k * n;
    for (int j = 0; j < n; ++j) {
      double w = lam[k] * v[j];
      double* Hj = H + (size_t)j * n;
      for (int i = j; i < n; ++i) Hj[i] += w * v[i];
    }
  }
  for (int j = 0; j < n; ++j)
    for (int i = j + 1; i < n; ++i) H[j + (size_t)i * n] = H[i + (size_t)j * n];
}

/* the QP's Hessian at the iterate: Gauss-Newton (plus the hierarchy rows' curvature) or
   the exact one convexified; regularised and damped on the diagonal */
int hessian(Sqp* s, const double* U, const double* p, const double* lam_c,
                   const double* lam_u, int exact, double regularization, double damping,
                   int shift) {
  int n = s->nU;
  s->factor_valid = 0;
  if (exact && s->has_hess) {
    if (fn_call(&s->hess, U, p, lam_c, s->H, 0, 0, 0, 0)) return 1;
    convexify(s, s->H, lam_c, lam_u, shift);
  } else {
    la_gram(s->J, s->nr, n, 2.0, s->H, 0, s->T);
    if (s->nh) {
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < s->nh; ++i) {
          double l = lam_c[s->hier_row[i]];
          s->C[i + (size_t)j * s->nh] = s->Jh[i + (size_t)j * s->nh] * sqrt(l > 0 ? l : 0.0);
        }
      la_gram(s->C, s->nh, n, 2.0, s->H, 1, s->T);
    }
  }
  double top = -INFINITY;
  for (int j = 0; j < n; ++j)
    if (s->H[j + (size_t)j * n] > top) top = s->H[j + (size_t)j * n];
  for (int j = 0; j < n; ++j) s->H[j + (size_t)j * n] += regularization + damping * top;
  return 0;
}

