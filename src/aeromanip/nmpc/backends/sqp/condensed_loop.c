/*
 * The SQP loop of the condensed QP model in C: one call per solve.
 *
 * The same algorithm, step for step, as the Python loop of aeromanip's SQP
 * (nmpc/backends/sqp/solver.py with condensed_qp.py, dense_qp.py, convexify.py and
 * optimality.py): Gauss-Newton or exact (convexified) Hessians, DAQP on the rows that
 * may bind (screened, as dense_qp.py does), an l1 merit with Armijo backtracking and a
 * second-order correction, Levenberg-Marquardt damping, KKT and acceptable-level stops,
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

#include "daqp/api.h"

typedef long long casadi_int;
typedef int (*casadi_fn)(const double** arg, double** res, casadi_int* iw, double* w, int mem);
typedef int (*casadi_work_fn)(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw,
                              casadi_int* sz_w);

/* the outcome of a solve (Python maps them to IPOPT-like status words) */
enum { ST_SOLVED = 1, ST_ACCEPTABLE = 2, ST_MAX_ITER = 3, ST_INVALID = 4, ST_QP_FAILED = 5,
       ST_RTI = 6, ST_MODEL_FAILED = 7 };
enum { HESS_AUTO = 0, HESS_EXACT = 1, HESS_GN = 2 };

#define SCREEN_ROUNDS 4
#define CROSS_TOL 1e-6
#define EXACT_FROM_ITERATION 6
#define ARMIJO 1e-4
#define BACKTRACK 0.5
#define MIN_STEP 1e-3
#define DAMPING_START 1e-3
#define DAMPING_GROWTH 10.0
#define PENALTY_MARGIN 1.1
#define PENALTY_FLOOR 1e-8
#define CONVEXIFY_DECADES 5
#define EIGEN_FLOOR 1e-6
#define MAX_SIZES 16

typedef struct {
  casadi_fn f;
  const double** arg;
  double** res;
  casadi_int* iw;
  double* w;
} Fn;

typedef struct {
  int nU, nc, nr, nh, np, has_hess;
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
  double *dH, *dA, *dlo, *dup, *dlam, *rlam, *tmp, *L, *C, *V, *Hc;
  int *sense, *rows, *range;
  unsigned char* near;
} Sqp;

typedef struct {
  double f;
  int iterations;
  int qp_exitflag;     /* DAQP's, of the QP that failed */
  int qp_finite;       /* its answer finite? */
  double qp_excess;    /* how far it crossed its bounds */
} SqpInfo;

/* -- small dense linear algebra ------------------------------------------------------- */

static double dot(const double* a, const double* b, int n) {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    s0 += a[i] * b[i];
    s1 += a[i + 1] * b[i + 1];
    s2 += a[i + 2] * b[i + 2];
    s3 += a[i + 3] * b[i + 3];
  }
  for (; i < n; ++i) s0 += a[i] * b[i];
  return (s0 + s1) + (s2 + s3);
}

/* H = scale * M' M (M: m x n column-major; `range`: 2n ints of scratch): each column's
   products only over the rows where both columns have nonzeros (a condensed Jacobian is
   block-triangular: a stage's residuals do not depend on later commands) */
static void gram(const double* M, int m, int n, double scale, double* H, int add, int* range) {
  for (int j = 0; j < n; ++j) {
    const double* col = M + (size_t)j * m;
    int lo = 0, hi = m;
    while (lo < m && col[lo] == 0.0) ++lo;
    while (hi > lo && col[hi - 1] == 0.0) --hi;
    range[2 * j] = lo;
    range[2 * j + 1] = hi;
  }
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i <= j; ++i) {
      int lo = range[2 * i] > range[2 * j] ? range[2 * i] : range[2 * j];
      int hi = range[2 * i + 1] < range[2 * j + 1] ? range[2 * i + 1] : range[2 * j + 1];
      double v = hi > lo ? scale * dot(M + (size_t)i * m + lo, M + (size_t)j * m + lo, hi - lo)
                         : 0.0;
      if (add) {
        H[i + (size_t)j * n] += v;
        if (i != j) H[j + (size_t)i * n] += v;
      } else {
        H[i + (size_t)j * n] = v;
        H[j + (size_t)i * n] = v;
      }
    }
  }
}

/* y = M x (M: m x n) */
static void matvec(const double* M, int m, int n, const double* x, double* y) {
  for (int i = 0; i < m; ++i) y[i] = 0.0;
  for (int j = 0; j < n; ++j) {
    double xj = x[j];
    if (xj == 0.0) continue;
    const double* col = M + (size_t)j * m;
    for (int i = 0; i < m; ++i) y[i] += col[i] * xj;
  }
}

/* y = M' x (M: m x n) */
static void matvec_t(const double* M, int m, int n, const double* x, double* y) {
  for (int j = 0; j < n; ++j) y[j] = dot(M + (size_t)j * m, x, m);
}

/* Cholesky of a symmetric matrix (lower triangle read): positive definite? */
static int positive_definite(const double* H, int n, double* L) {
  memcpy(L, H, sizeof(double) * (size_t)n * n);
  for (int j = 0; j < n; ++j) {
    double* Lj = L + (size_t)j * n;
    double s = Lj[j];
    for (int k = 0; k < j; ++k) s -= L[j + (size_t)k * n] * L[j + (size_t)k * n];
    if (!(s > 0.0)) return 0;
    s = sqrt(s);
    Lj[j] = s;
    for (int i = j + 1; i < n; ++i) {
      double t = Lj[i];
      for (int k = 0; k < j; ++k) t -= L[i + (size_t)k * n] * L[j + (size_t)k * n];
      Lj[i] = t / s;
    }
  }
  return 1;
}

/* eigenvalues (into lam, ascending) and eigenvectors (columns of V) of a symmetric
   matrix S (n x n, read): Householder tridiagonalisation and the implicit QL method
   (EISPACK's tred2 and tql2, as in the public-domain JAMA); e: n scratch */
void sqp_eigen_symmetric(const double* S, int n, double* lam, double* V, double* e) {
#define AT(i, j) V[(i) + (size_t)(j) * n]
  memcpy(V, S, sizeof(double) * (size_t)n * n);
  for (int j = 0; j < n; ++j) lam[j] = AT(n - 1, j);
  for (int i = n - 1; i > 0; --i) { /* tred2 */
    double scale = 0.0, h = 0.0;
    for (int k = 0; k < i; ++k) scale += fabs(lam[k]);
    if (scale == 0.0) {
      e[i] = lam[i - 1];
      for (int j = 0; j < i; ++j) {
        lam[j] = AT(i - 1, j);
        AT(i, j) = 0.0;
        AT(j, i) = 0.0;
      }
    } else {
      for (int k = 0; k < i; ++k) {
        lam[k] /= scale;
        h += lam[k] * lam[k];
      }
      double f = lam[i - 1], g = sqrt(h);
      if (f > 0) g = -g;
      e[i] = scale * g;
      h -= f * g;
      lam[i - 1] = f - g;
      for (int j = 0; j < i; ++j) e[j] = 0.0;
      for (int j = 0; j < i; ++j) {
        f = lam[j];
        AT(j, i) = f;
        g = e[j] + AT(j, j) * f;
        for (int k = j + 1; k <= i - 1; ++k) {
          g += AT(k, j) * lam[k];
          e[k] += AT(k, j) * f;
        }
        e[j] = g;
      }
      f = 0.0;
      for (int j = 0; j < i; ++j) {
        e[j] /= h;
        f += e[j] * lam[j];
      }
      double hh = f / (h + h);
      for (int j = 0; j < i; ++j) e[j] -= hh * lam[j];
      for (int j = 0; j < i; ++j) {
        f = lam[j];
        g = e[j];
        for (int k = j; k <= i - 1; ++k) AT(k, j) -= (f * e[k] + g * lam[k]);
        lam[j] = AT(i - 1, j);
        AT(i, j) = 0.0;
      }
    }
    lam[i] = h;
  }
  for (int i = 0; i < n - 1; ++i) { /* accumulate the transformations */
    AT(n - 1, i) = AT(i, i);
    AT(i, i) = 1.0;
    double h = lam[i + 1];
    if (h != 0.0) {
      for (int k = 0; k <= i; ++k) lam[k] = AT(k, i + 1) / h;
      for (int j = 0; j <= i; ++j) {
        double g = 0.0;
        for (int k = 0; k <= i; ++k) g += AT(k, i + 1) * AT(k, j);
        for (int k = 0; k <= i; ++k) AT(k, j) -= g * lam[k];
      }
    }
    for (int k = 0; k <= i; ++k) AT(k, i + 1) = 0.0;
  }
  for (int j = 0; j < n; ++j) {
    lam[j] = AT(n - 1, j);
    AT(n - 1, j) = 0.0;
  }
  AT(n - 1, n - 1) = 1.0;
  e[0] = 0.0;
  for (int i = 1; i < n; ++i) e[i - 1] = e[i]; /* tql2 */
  e[n - 1] = 0.0;
  double f = 0.0, tst1 = 0.0, eps = 2.220446049250313e-16;
  for (int l = 0; l < n; ++l) {
    if (fabs(lam[l]) + fabs(e[l]) > tst1) tst1 = fabs(lam[l]) + fabs(e[l]);
    int m = l;
    while (m < n && fabs(e[m]) > eps * tst1) ++m;
    if (m == n) m = n - 1;
    if (m > l) {
      for (int iter = 0; iter < 60; ++iter) {
        double g = lam[l], p = (lam[l + 1] - g) / (2.0 * e[l]), r = hypot(p, 1.0);
        if (p < 0) r = -r;
        lam[l] = e[l] / (p + r);
        lam[l + 1] = e[l] * (p + r);
        double dl1 = lam[l + 1], h = g - lam[l];
        for (int i = l + 2; i < n; ++i) lam[i] -= h;
        f += h;
        p = lam[m];
        double c = 1.0, c2 = 1.0, c3 = 1.0, el1 = e[l + 1], s = 0.0, s2 = 0.0;
        for (int i = m - 1; i >= l; --i) {
          c3 = c2;
          c2 = c;
          s2 = s;
          g = c * e[i];
          h = c * p;
          r = hypot(p, e[i]);
          e[i + 1] = s * r;
          s = e[i] / r;
          c = p / r;
          p = c * lam[i] - s * g;
          lam[i + 1] = h + s * (c * g + s * lam[i]);
          for (int k = 0; k < n; ++k) {
            h = AT(k, i + 1);
            AT(k, i + 1) = s * AT(k, i) + c * h;
            AT(k, i) = c * AT(k, i) - s * h;
          }
        }
        p = -s * s2 * c3 * el1 * e[l] / dl1;
        e[l] = s * p;
        lam[l] = c * p;
        if (!(fabs(e[l]) > eps * tst1)) break;
      }
    }
    lam[l] += f;
    e[l] = 0.0;
  }
#undef AT
}

/* -- optimality measures (optimality.py) -------------------------------------------- */

static double violation(const double* g, const double* lb, const double* ub, int n) {
  double v = 0.0;
  for (int i = 0; i < n; ++i) {
    if (lb[i] - g[i] > v) v = lb[i] - g[i];
    if (g[i] - ub[i] > v) v = g[i] - ub[i];
  }
  return v;
}

static double l1(const double* g, const double* lb, const double* ub, int n) {
  double lo = 0.0, hi = 0.0;
  for (int i = 0; i < n; ++i) {
    if (lb[i] - g[i] > 0) lo += lb[i] - g[i];
    if (g[i] - ub[i] > 0) hi += g[i] - ub[i];
  }
  return lo + hi;
}

static double complementarity(const double* g, const double* lb, const double* ub,
                              const double* lam, int n) {
  double c = 0.0;
  for (int i = 0; i < n; ++i) {
    double dist = lam[i] > 0 ? ub[i] - g[i] : (lam[i] < 0 ? lb[i] - g[i] : 0.0);
    double v = fabs(lam[i] * dist);
    if (!isfinite(v)) return INFINITY;
    if (v > c) c = v;
  }
  return c;
}

/* -- the model's Functions ------------------------------------------------------------ */

static int fn_new(Fn* fn, casadi_fn f, casadi_work_fn work) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  fn->f = f;
  work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  /* fn_call sets 3 arguments and 5 results (unused ones NULL) */
  fn->arg = calloc((size_t)(sz_arg > 3 ? sz_arg : 3), sizeof(double*));
  fn->res = calloc((size_t)(sz_res > 5 ? sz_res : 5), sizeof(double*));
  fn->iw = calloc((size_t)sz_iw + 1, sizeof(casadi_int));
  fn->w = calloc((size_t)sz_w + 1, sizeof(double));
  return fn->arg && fn->res && fn->iw && fn->w;
}

static void fn_free(Fn* fn) {
  free(fn->arg);
  free(fn->res);
  free(fn->iw);
  free(fn->w);
}

static int fn_call(Fn* fn, const double* a0, const double* a1, const double* a2, double* r0,
                   double* r1, double* r2, double* r3, double* r4) {
  fn->arg[0] = a0;
  fn->arg[1] = a1;
  fn->arg[2] = a2;
  fn->res[0] = r0;
  fn->res[1] = r1;
  fn->res[2] = r2;
  fn->res[3] = r3;
  fn->res[4] = r4;
  return fn->f(fn->arg, fn->res, fn->iw, fn->w, 0);
}

/* -- the dense QP on the rows that may bind (dense_qp.py) --------------------------- */

typedef struct {
  int ok, exitflag, finite;
  double excess;
} QpOutcome;

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
  DAQPWorkspace work;
  DAQPResult res;
  memset(&work, 0, sizeof work);
  memset(&res, 0, sizeof res);
  work.settings = &s->settings;
  res.x = d;
  res.lam = s->dlam;
  int flag = setup_daqp(&qp, &work, &res.setup_time);
  if (flag < 0) {
    for (int j = 0; j < n; ++j) d[j] = NAN;
    out.exitflag = flag;
  } else {
    daqp_solve(&res, &work);
    out.exitflag = res.exitflag;
  }
  work.settings = 0;
  free_daqp_workspace(&work);
  free_daqp_ldp(&work);
  memcpy(lam_x, s->dlam, sizeof(double) * n);
  memcpy(lam_r, s->dlam + n, sizeof(double) * r);
  /* a finite, feasible solution means success (as the Python path decides) */
  double dmax = 0.0;
  for (int j = 0; j < n; ++j) {
    if (!isfinite(d[j])) out.finite = 0;
    if (fabs(d[j]) > dmax) dmax = fabs(d[j]);
  }
  double tol = CROSS_TOL * (1.0 + dmax), excess = 0.0;
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
static QpOutcome qp_solve(Sqp* s, const double* H, const double* g, const double* A,
                          const double* lba, const double* uba, const double* lbx,
                          const double* ubx, double* memory, double* d, double* lam_a,
                          double* lam_x) {
  int nc = s->nc, n = s->nU;
  QpOutcome out;
  for (int i = 0; i < nc; ++i) {
    double slack = -lba[i] < uba[i] ? -lba[i] : uba[i];
    s->near[i] = s->always[i] || memory[i] != 0.0 || slack < s->screen;
  }
  int full = 1;
  for (int round = 0; round < SCREEN_ROUNDS; ++round) {
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
    double tol = CROSS_TOL * (1.0 + dmax);
    matvec(A, nc, n, d, s->Ad);
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

/* H positive definite as it is, or H + rho C'C for the active rows C (and the variables
   at a bound), or H with its eigenvalues reflected */
static void convexify(Sqp* s, double* H, const double* lam_c, const double* lam_u) {
  int n = s->nU, nc = s->nc;
  if (positive_definite(H, n, s->L)) return;
  int nC = 0, nfixed = 0;
  for (int i = 0; i < nc; ++i) nC += lam_c[i] != 0.0;
  for (int j = 0; j < n; ++j) nfixed += lam_u[j] != 0.0;
  if (nC || nfixed) {
    double scale = 0.0, norms = 0.0;
    for (int j = 0; j < n; ++j)
      if (fabs(H[j + (size_t)j * n]) > scale) scale = fabs(H[j + (size_t)j * n]);
    if (scale < 1e-8) scale = 1e-8;
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
    gram(s->C, nC, n, 1.0, s->V, 0, s->range); /* C'C, then the fixed variables' diagonal */
    for (int j = 0; j < n; ++j)
      if (lam_u[j] != 0.0) s->V[j + (size_t)j * n] += 1.0;
    double rho = base;
    for (int t = 0; t < CONVEXIFY_DECADES; ++t, rho *= 10.0) {
      for (size_t i = 0; i < (size_t)n * n; ++i) s->Hc[i] = H[i] + rho * s->V[i];
      if (positive_definite(s->Hc, n, s->L)) {
        memcpy(H, s->Hc, sizeof(double) * (size_t)n * n);
        return;
      }
    }
  }
  double* lam = s->tmp;
  sqp_eigen_symmetric(H, n, lam, s->V, s->Hc);
  double top = 0.0;
  for (int i = 0; i < n; ++i)
    if (fabs(lam[i]) > top) top = fabs(lam[i]);
  double floor = EIGEN_FLOOR * (top > 1e-3 ? top : 1e-3);
  for (int i = 0; i < n; ++i) lam[i] = fabs(lam[i]) > floor ? fabs(lam[i]) : floor;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      double v = 0.0;
      for (int k = 0; k < n; ++k) v += s->V[i + (size_t)k * n] * lam[k] * s->V[j + (size_t)k * n];
      H[i + (size_t)j * n] = v;
    }
}

/* the QP's Hessian at the iterate: Gauss-Newton (plus the hierarchy rows' curvature) or
   the exact one convexified; regularised and damped on the diagonal */
static int hessian(Sqp* s, const double* U, const double* p, const double* lam_c,
                   const double* lam_u, int exact, double regularization, double damping) {
  int n = s->nU;
  if (exact && s->has_hess) {
    if (fn_call(&s->hess, U, p, lam_c, s->H, 0, 0, 0, 0)) return 1;
    convexify(s, s->H, lam_c, lam_u);
  } else {
    gram(s->J, s->nr, n, 2.0, s->H, 0, s->range);
    if (s->nh) {
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < s->nh; ++i) {
          double l = lam_c[s->hier_row[i]];
          s->C[i + (size_t)j * s->nh] = s->Jh[i + (size_t)j * s->nh] * sqrt(l > 0 ? l : 0.0);
        }
      gram(s->C, s->nh, n, 2.0, s->H, 1, s->range);
    }
  }
  double top = -INFINITY;
  for (int j = 0; j < n; ++j)
    if (s->H[j + (size_t)j * n] > top) top = s->H[j + (size_t)j * n];
  for (int j = 0; j < n; ++j) s->H[j + (size_t)j * n] += regularization + damping * top;
  return 0;
}

/* -- the loop (solver.py: _sqp, _verdict, _line_search) ---------------------------- */

/* the merit's parts at U + step: cost and l1 violation */
static int merit(Sqp* s, const double* U, const double* step, const double* p,
                 const double* lbc, const double* ubc, double* f, double* viol) {
  double* Ut = s->tmp;
  for (int j = 0; j < s->nU; ++j) Ut[j] = U[j] + step[j];
  if (fn_call(&s->merit, Ut, p, 0, f, s->trial_c, 0, 0, 0)) return 1;
  *viol = l1(s->trial_c, lbc, ubc, s->nc);
  return 0;
}

static double kkt_error(Sqp* s, const double* U, const double* lbc, const double* ubc,
                        const double* lbU, const double* ubU, const double* lam_c,
                        const double* lam_u) {
  int n = s->nU;
  double k1 = complementarity(s->c, lbc, ubc, lam_c, s->nc);
  double k2 = complementarity(U, lbU, ubU, lam_u, n);
  matvec_t(s->A, s->nc, n, lam_c, s->tmp);
  double st = 0.0;
  for (int j = 0; j < n; ++j) {
    double v = fabs(s->grad[j] + s->tmp[j] + lam_u[j]);
    if (v > st || isnan(v)) st = v;
  }
  double k = k1 > k2 ? k1 : k2;
  return st > k || isnan(st) ? st : k;
}

/* opts: max_iter, tol, acceptable_tol, constr_viol_tol, acceptable_iter, rti, hessian
   (HESS_*), regularization, warm (multipliers given) */
int sqp_solve(Sqp* s, const double* opts, const double* p, const double* lbc,
              const double* ubc, const double* lbU, const double* ubU, double* U,
              double* lam_c, double* lam_u, double* memory, SqpInfo* info) {
  int n = s->nU, nc = s->nc;
  int max_iter = (int)opts[0], acceptable_iter = (int)opts[4], rti = opts[5] != 0.0;
  int hess_mode = (int)opts[6], warm = opts[8] != 0.0;
  double tol = opts[1], acceptable_tol = opts[2], cvt = opts[3], reg = opts[7];
  double mu = 0.0, damping = 0.0;
  int it = 0, acceptable = 0, status = 0, exact = hess_mode == HESS_EXACT;
  if (rti) max_iter = 1;
  memset(info, 0, sizeof *info);
  info->f = NAN;
  for (;;) {
    if (fn_call(&s->data, U, p, 0, s->R, s->J, s->c, s->A, s->Jh)) {
      status = ST_MODEL_FAILED;
      break;
    }
    double f = dot(s->R, s->R, s->nr);
    info->f = f;
    matvec_t(s->J, s->nr, n, s->R, s->grad);
    for (int j = 0; j < n; ++j) s->grad[j] *= 2.0;
    if (!isfinite(f)) {
      status = ST_INVALID;
      break;
    }
    /* the stopping test (solver.py: _verdict) */
    double viol = rti ? 0.0 : violation(s->c, lbc, ubc, nc);
    double kkt = INFINITY;
    if (!rti && (it > 0 || warm) && viol <= cvt) {
      kkt = kkt_error(s, U, lbc, ubc, lbU, ubU, lam_c, lam_u);
      if (kkt <= tol && viol <= tol) {
        status = ST_SOLVED;
        break;
      }
    }
    acceptable = kkt <= acceptable_tol ? acceptable + 1 : 0;
    if (acceptable >= acceptable_iter || (it >= max_iter && acceptable)) {
      status = ST_ACCEPTABLE;
      break;
    }
    if (it >= max_iter) {
      status = ST_MAX_ITER;
      break;
    }
    /* the QP step */
    if (hessian(s, U, p, lam_c, lam_u, exact, reg, damping)) {
      status = ST_MODEL_FAILED;
      break;
    }
    for (int i = 0; i < nc; ++i) {
      s->lba[i] = lbc[i] - s->c[i];
      s->uba[i] = ubc[i] - s->c[i];
    }
    for (int j = 0; j < n; ++j) {
      s->lbx[j] = lbU[j] - U[j];
      s->ubx[j] = ubU[j] - U[j];
    }
    QpOutcome qp = qp_solve(s, s->H, s->grad, s->A, s->lba, s->uba, s->lbx, s->ubx, memory,
                            s->qd, s->qlam_a, s->qlam_x);
    ++it;
    if (!qp.ok) {
      status = ST_QP_FAILED;
      info->qp_exitflag = qp.exitflag;
      info->qp_finite = qp.finite;
      info->qp_excess = qp.excess;
      break;
    }
    memcpy(lam_c, s->qlam_a, sizeof(double) * nc);
    memcpy(lam_u, s->qlam_x, sizeof(double) * n);
    if (rti) {
      for (int j = 0; j < n; ++j) U[j] += s->qd[j];
      status = ST_RTI;
      break;
    }
    double lam_top = 0.0;
    for (int i = 0; i < nc; ++i)
      if (fabs(lam_c[i]) > lam_top) lam_top = fabs(lam_c[i]);
    double mu_new = PENALTY_MARGIN * lam_top + PENALTY_FLOOR;
    if (mu_new > mu) mu = mu_new;
    /* the line search (solver.py: _line_search) */
    double viol0 = l1(s->c, lbc, ubc, nc), phi0 = f + mu * viol0;
    double slope = dot(s->grad, s->qd, n) - mu * viol0;
    double descent = slope < 0.0 ? slope : 0.0, f1, viol1, alpha = 1.0;
    const double* d = s->qd;
    if (merit(s, U, d, p, lbc, ubc, &f1, &viol1)) {
      status = ST_MODEL_FAILED;
      break;
    }
    int accepted = f1 + mu * viol1 <= phi0 + ARMIJO * descent;
    if (!accepted && viol1 > viol0) { /* the second-order correction */
      matvec(s->A, nc, n, d, s->Ad);
      for (int i = 0; i < nc; ++i) {
        double cc = s->trial_c[i] - s->Ad[i];
        s->lba[i] = lbc[i] - cc;
        s->uba[i] = ubc[i] - cc;
      }
      QpOutcome soc = qp_solve(s, s->H, s->grad, s->A, s->lba, s->uba, s->lbx, s->ubx, memory,
                               s->sd, s->slam_a, s->slam_x);
      double fs, vs;
      if (soc.ok) {
        if (merit(s, U, s->sd, p, lbc, ubc, &fs, &vs)) {
          status = ST_MODEL_FAILED;
          break;
        }
        if (fs + mu * vs <= phi0 + ARMIJO * descent) {
          accepted = 1;
          d = s->sd;
          memcpy(lam_c, s->slam_a, sizeof(double) * nc);
          memcpy(lam_u, s->slam_x, sizeof(double) * n);
        }
      }
    }
    if (!accepted) {
      alpha = BACKTRACK;
      for (;;) {
        for (int j = 0; j < n; ++j) s->Ad[j] = alpha * s->qd[j];
        if (merit(s, U, s->Ad, p, lbc, ubc, &f1, &viol1)) {
          status = ST_MODEL_FAILED;
          break;
        }
        if (f1 + mu * viol1 <= phi0 + ARMIJO * alpha * descent || alpha < MIN_STEP) break;
        alpha *= BACKTRACK;
      }
      if (status) break;
    }
    for (int j = 0; j < n; ++j) U[j] += alpha * d[j];
    if (alpha < 1.0) {
      damping = DAMPING_GROWTH * damping > DAMPING_START ? DAMPING_GROWTH * damping : DAMPING_START;
    } else {
      damping /= DAMPING_GROWTH;
      if (damping < DAMPING_START) damping = 0.0;
    }
    if (hess_mode == HESS_AUTO) exact = exact || alpha < 1.0 || it >= EXACT_FROM_ITERATION;
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
                     &s->Hc};
  for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; ++i) free(*bufs[i]);
  free(s->sense);
  free(s->rows);
  free(s->range);
  free(s->near);
  free(s->hier_row);
  free(s->always);
  free(s);
}

/* dims: nU, nc, nr, nh, np; sizes: the screened QP's row counts (ascending, the last nc);
   daqp: primal_tol, dual_tol, zero_tol, pivot_tol, progress_tol, cycle_tol, iter_limit,
   eps_prox, eta_prox */
Sqp* sqp_new(const int* dims, const int* hier_row, const unsigned char* always,
             const int* sizes, int n_sizes, double screen, const double* daqp,
             casadi_fn data, casadi_work_fn data_work, casadi_fn merit_fn,
             casadi_work_fn merit_work, casadi_fn hess, casadi_work_fn hess_work) {
  if (n_sizes > MAX_SIZES) return 0;
  Sqp* s = calloc(1, sizeof(Sqp));
  if (!s) return 0;
  s->nU = dims[0], s->nc = dims[1], s->nr = dims[2], s->nh = dims[3], s->np = dims[4];
  s->has_hess = hess != 0;
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
      {&s->C, wide * n}, {&s->V, n * n}, {&s->Hc, n * n}};
  for (size_t i = 0; i < sizeof plan / sizeof plan[0]; ++i) {
    *plan[i].p = calloc(plan[i].size + 1, sizeof(double));
    ok = ok && *plan[i].p;
  }
  s->sense = calloc(n + nc + 1, sizeof(int));
  s->rows = calloc(nc + 1, sizeof(int));
  s->range = calloc(2 * n + 1, sizeof(int));
  s->near = calloc(nc + 1, 1);
  s->hier_row = calloc(nh + 1, sizeof(int));
  s->always = calloc(nc + 1, 1);
  ok = ok && s->sense && s->rows && s->range && s->near && s->hier_row && s->always;
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
