/*
 * Small dense linear algebra and optimality measures for the compiled SQP loop: the
 * products it needs, a Cholesky test, a symmetric eigensolver, and optimality.py's
 * measures. Matrices are column-major.
 */
#include "dense_linalg.h"

#include <math.h>
#include <string.h>

double la_dot(const double* a, const double* b, int n) {
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

/* H = scale * M' M, or H += it (`add`) (M: m x n column-major; T: m x n scratch): the
   sum of the rows' outer products, each over its span of nonzeros, along rows of M
   (copied into T) so the inner loop is contiguous and vectorises (a condensed
   Jacobian's rows depend on a few commands: a stage's residuals on none after it, a
   rate's on two) */
void la_gram(const double* M, int m, int n, double scale, double* H, int add, double* T) {
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < n; ++j) T[(size_t)i * n + j] = M[i + (size_t)j * m];
  if (!add) memset(H, 0, sizeof(double) * (size_t)n * n);
  for (int r = 0; r < m; ++r) { /* the lower triangle, by columns of H */
    const double* t = T + (size_t)r * n;
    int lo = 0, hi = n;
    while (lo < n && t[lo] == 0.0) ++lo;
    while (hi > lo && t[hi - 1] == 0.0) --hi;
    for (int i = lo; i < hi; ++i) {
      double a = scale * t[i];
      if (a == 0.0) continue;
      double* column = H + (size_t)i * n;
      for (int j = i; j < hi; ++j) column[j] += a * t[j];
    }
  }
  for (int i = 0; i < n; ++i) /* the upper triangle mirrors the lower */
    for (int j = i + 1; j < n; ++j) H[i + (size_t)j * n] = H[j + (size_t)i * n];
}

/* y = M x (M: m x n) */
void la_matvec(const double* M, int m, int n, const double* x, double* y) {
  for (int i = 0; i < m; ++i) y[i] = 0.0;
  for (int j = 0; j < n; ++j) {
    double xj = x[j];
    if (xj == 0.0) continue;
    const double* col = M + (size_t)j * m;
    for (int i = 0; i < m; ++i) y[i] += col[i] * xj;
  }
}

/* y = M' x (M: m x n) */
void la_matvec_t(const double* M, int m, int n, const double* x, double* y) {
  for (int j = 0; j < n; ++j) y[j] = la_dot(M + (size_t)j * m, x, m);
}

/* R's rows k >= from, columns j >= k, less the outer products of the b (<= 4) pivot rows
   i0.. (already scaled): the trailing update of a right-looking Cholesky, four rows at a
   time so that each row below is read and written once per block */
static void cholesky_trailing(double* R, int n, int i0, int b, int from) {
  const double* r0 = R + (size_t)i0 * n;
  const double* r1 = b > 1 ? r0 + n : r0;
  const double* r2 = b > 2 ? r1 + n : r0;
  const double* r3 = b > 3 ? r2 + n : r0;
  for (int k = from; k < n; ++k) {
    double f0 = r0[k], f1 = b > 1 ? r1[k] : 0.0, f2 = b > 2 ? r2[k] : 0.0;
    double f3 = b > 3 ? r3[k] : 0.0;
    double* rk = R + (size_t)k * n;
    for (int j = k; j < n; ++j) rk[j] -= f0 * r0[j] + f1 * r1[j] + f2 * r2[j] + f3 * r3[j];
  }
}

/* y = a' P (P: n x n upper triangular, its rows packed: row j holds columns j..n-1):
   y[c] = sum_{j <= c} a[j] P[j][c]; four rows of P at a time (y read and written once
   per four), the blocks where a is zero skipped */
void la_packed_vecmat(const double* a, const double* P, int n, double* y) {
  memset(y, 0, sizeof(double) * (size_t)n);
  const double* r0 = P; /* row j */
  int j = 0;
  for (; j + 3 < n; j += 4) {
    const double* r1 = r0 + (n - j);
    const double* r2 = r1 + (n - j - 1);
    const double* r3 = r2 + (n - j - 2);
    double a0 = a[j], a1 = a[j + 1], a2 = a[j + 2], a3 = a[j + 3];
    if (a0 != 0.0 || a1 != 0.0 || a2 != 0.0 || a3 != 0.0) {
      double* o = y + j; /* column j */
      o[0] += a0 * r0[0];
      o[1] += a0 * r0[1] + a1 * r1[0];
      o[2] += a0 * r0[2] + a1 * r1[1] + a2 * r2[0];
      for (int i = 0; i < n - j - 3; ++i)
        o[3 + i] += a0 * r0[3 + i] + a1 * r1[2 + i] + a2 * r2[1 + i] + a3 * r3[i];
    }
    r0 = r3 + (n - j - 3);
  }
  for (; j < n; r0 += n - j, ++j)
    for (int i = 0; i < n - j; ++i) y[j + i] += a[j] * r0[i];
}

/* DAQP's Rinv (its utils.c, update_Rinv): the inverse of the upper triangular R with
   H + eps I = R'R (H: n x n symmetric, one triangle read), its rows packed (row i holds
   columns i..n-1). Both halves run along rows, so their inner loops are contiguous and
   vectorise (DAQP's Cholesky runs down columns of its packed rows); both work by
   blocks of four rows. R: n x n scratch.
   0 where H + eps I is not positive definite. */
int la_cholesky_inverse_packed(const double* H, int n, double eps, double* R, double* Rinv) {
  for (int i = 0; i < n; ++i) {
    memcpy(R + (size_t)i * n + i, H + (size_t)i * n + i, sizeof(double) * (size_t)(n - i));
    R[(size_t)i * n + i] += eps;
  }
  for (int i0 = 0; i0 < n; i0 += 4) { /* right-looking, by blocks of four pivot rows */
    int b = n - i0 < 4 ? n - i0 : 4;
    for (int i = i0; i < i0 + b; ++i) { /* the block's rows */
      double* ri = R + (size_t)i * n;
      if (!(ri[i] > 0.0)) return 0;
      ri[i] = sqrt(ri[i]);
      double inv = 1.0 / ri[i];
      for (int j = i + 1; j < n; ++j) ri[j] *= inv;
      for (int k = i + 1; k < i0 + b; ++k) {
        double f = ri[k];
        double* rk = R + (size_t)k * n;
        for (int j = k; j < n; ++j) rk[j] -= f * ri[j];
      }
    }
    cholesky_trailing(R, n, i0, b, i0 + b); /* then the rows below it */
  }
  /* row i of R^-1 (packed, from column i) = (e_i - sum_{k>i} R[i][k] (row k of R^-1)) /
     R[i][i]: the rows k > i are R^-1's trailing block, packed; from the last row */
  size_t packed = (size_t)n * (n + 1) / 2;
  for (int i = n - 1; i >= 0; --i) {
    const double* ri = R + (size_t)i * n;
    double* out = Rinv + packed - (size_t)(n - i) * (n - i + 1) / 2;
    double inv = 1.0 / ri[i];
    la_packed_vecmat(ri + i + 1, out + (n - i), n - i - 1, out + 1);
    out[0] = inv;
    for (int j = 1; j < n - i; ++j) out[j] *= -inv;
  }
  return 1;
}

/* Cholesky of a symmetric matrix (lower triangle read): positive definite? */
int la_positive_definite(const double* H, int n, double* L) {
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

#define AT(i, j) V[(i) + (size_t)(j) * n]

/* Householder reduction of V (symmetric, overwritten by the transformation) to
   tridiagonal form: diagonal in d, subdiagonal in e (EISPACK's tred2) */
static void tred2(double* V, int n, double* d, double* e) {
  double* lam = d;
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
}

/* the eigenvalues d and vectors V of the tridiagonal matrix (d, e) that tred2 left,
   by the implicit QL method (EISPACK's tql2) */
static void tql2(double* V, int n, double* d, double* e) {
  double* lam = d;
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
        double g = lam[l], p = (lam[l + 1] - g) / (2.0 * e[l]), r = sqrt(p * p + 1.0);
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
          r = sqrt(p * p + e[i] * e[i]); /* no overflow at a Hessian's magnitudes */
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
}
#undef AT

/* eigenvalues (into lam, ascending) and eigenvectors (columns of V) of a symmetric
   matrix S (n x n, read): Householder tridiagonalisation and the implicit QL method
   (EISPACK's tred2 and tql2, as in the public-domain JAMA); e: n scratch */
void sqp_eigen_symmetric(const double* S, int n, double* lam, double* V, double* e) {
  memcpy(V, S, sizeof(double) * (size_t)n * n);
  tred2(V, n, lam, e);
  tql2(V, n, lam, e);
}

/* -- optimality measures (optimality.py) -------------------------------------------- */

double la_violation(const double* g, const double* lb, const double* ub, int n) {
  double v = 0.0;
  for (int i = 0; i < n; ++i) {
    if (lb[i] - g[i] > v) v = lb[i] - g[i];
    if (g[i] - ub[i] > v) v = g[i] - ub[i];
  }
  return v;
}

double la_l1(const double* g, const double* lb, const double* ub, int n) {
  double lo = 0.0, hi = 0.0;
  for (int i = 0; i < n; ++i) {
    if (lb[i] - g[i] > 0) lo += lb[i] - g[i];
    if (g[i] - ub[i] > 0) hi += g[i] - ub[i];
  }
  return lo + hi;
}

double la_complementarity(const double* g, const double* lb, const double* ub,
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

