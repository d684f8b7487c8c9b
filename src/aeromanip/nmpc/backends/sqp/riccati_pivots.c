/*
 * The Riccati recursion's pivots of per-stage Hessian blocks (convexify.py:
 * riccati_pivots, the same steps): for dynamics x_{k+1} = A x_k + B u_k with x_0
 * pinned, from P = the terminal block and k = N-1 down to 0,
 *
 *   L = H_k + [A B]' P [A B],   pivot R = L_uu,   P = L_xx - L_xu R^-1 L_ux.
 *
 * The condensed Hessian is positive definite exactly when every pivot is. A pivot's
 * eigenvalues below `floor_share` of its largest magnitude (at least 1e-3) make it not
 * definite; with `reflect`, they are replaced by their magnitudes, floored, through a
 * change of H_k's u-block, and the recursion goes on with the changed pivot. A pivot
 * whose Cholesky factorisation holds shifted by floor_share of its Frobenius norm (a
 * bound on the largest eigenvalue) is definite by that rule and is used through its
 * factor; only the others are decomposed (cyclic Jacobi: the pivots are small). The
 * products with [A B] skip its zeros. Matrices row-major; H is changed in place only
 * when reflecting.
 */
#include <math.h>
#include <string.h>

#include "ocp_ipm.h"

#define JACOBI_SWEEPS 60
#define JACOBI_NEGLIGIBLE 1e-18 /* an off-diagonal entry this share of its diagonal's */

/* eigenvalues w and eigenvectors V (columns) of the symmetric n x n matrix a (destroyed) */
static void jacobi_eigen(int n, double* a, double* V, double* w) {
  for (int i = 0; i < n * n; ++i) V[i] = 0.0;
  for (int i = 0; i < n; ++i) V[i * n + i] = 1.0;
  for (int sweep = 0; sweep < JACOBI_SWEEPS; ++sweep) {
    double off = 0.0, all = 0.0;
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) {
        double v = a[i * n + j] * a[i * n + j];
        all += v;
        if (i != j) off += v;
      }
    if (off <= 1e-32 * all || off == 0.0) break;
    for (int p = 0; p < n - 1; ++p)
      for (int q = p + 1; q < n; ++q) {
        double apq = a[p * n + q];
        if (fabs(apq) <= JACOBI_NEGLIGIBLE * (fabs(a[p * n + p]) + fabs(a[q * n + q]))) {
          a[p * n + q] = a[q * n + p] = 0.0; /* below rounding of the diagonal: zero */
          continue;
        }
        double theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
        double t = (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
        double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
        for (int k = 0; k < n; ++k) { /* columns p, q */
          double akp = a[k * n + p], akq = a[k * n + q];
          a[k * n + p] = c * akp - s * akq;
          a[k * n + q] = s * akp + c * akq;
        }
        for (int k = 0; k < n; ++k) { /* rows p, q */
          double apk = a[p * n + k], aqk = a[q * n + k];
          a[p * n + k] = c * apk - s * aqk;
          a[q * n + k] = s * apk + c * aqk;
        }
        for (int k = 0; k < n; ++k) {
          double vkp = V[k * n + p], vkq = V[k * n + q];
          V[k * n + p] = c * vkp - s * vkq;
          V[k * n + q] = s * vkp + c * vkq;
        }
      }
  }
  for (int i = 0; i < n; ++i) w[i] = a[i * n + i];
}

/* the lower Cholesky factor of a - shift I (n x n, into C): 1 if positive definite */
static int cholesky(int n, const double* a, double shift, double* C) {
  for (int j = 0; j < n; ++j) {
    double d = a[j * n + j] - shift;
    for (int k = 0; k < j; ++k) d -= C[j * n + k] * C[j * n + k];
    if (!(d > 0.0)) return 0;
    d = sqrt(d);
    C[j * n + j] = d;
    for (int i = j + 1; i < n; ++i) {
      double v = a[i * n + j];
      for (int k = 0; k < j; ++k) v -= C[i * n + k] * C[j * n + k];
      C[i * n + j] = v / d;
    }
  }
  return 1;
}

/* L = H + AB' P AB (ns x ns), AB = [A B] (nx x ns) given by its nnz nonzeros (row k[e],
   column j[e], value v[e]: the model's dynamics are mostly zeros); T: nx x ns scratch */
static void stage_l(int nx, int ns, int nnz, const int* k, const int* j, const double* v,
                    const double* P, const double* H, double* T, double* L) {
  memset(T, 0, sizeof(double) * nx * ns); /* T = P AB */
  for (int e = 0; e < nnz; ++e)
    for (int i = 0; i < nx; ++i) T[i * ns + j[e]] += P[i * nx + k[e]] * v[e];
  memcpy(L, H, sizeof(double) * ns * ns); /* L = H + AB' T */
  for (int e = 0; e < nnz; ++e)
    for (int c = 0; c < ns; ++c) L[j[e] * ns + c] += v[e] * T[k[e] * ns + c];
}

/* the pivot R (destroyed) by its eigenvalues: 0 if not definite (eigenvalues below
   floor_share of the largest magnitude, or of 1e-3) and not reflect; else w, and
   LV = L_xu V, with H_k's u-block changed where reflected */
static int eigen_pivot(int nx, int nu, int ns, const double* L, double* Hk, double* R,
                       double* V, double* w, double* LV, int reflect, double floor_share) {
  jacobi_eigen(nu, R, V, w);
  double top = 0.0, low = INFINITY;
  for (int i = 0; i < nu; ++i) {
    if (fabs(w[i]) > top) top = fabs(w[i]);
    if (w[i] < low) low = w[i];
  }
  double floor = floor_share * (top > 1e-3 ? top : 1e-3);
  if (low < floor || isnan(low)) {
    if (!reflect || isnan(low)) return 0;
    for (int i = 0; i < nu; ++i) { /* H_k's u-block += V diag(fixed - w) V' */
      double fixed = fabs(w[i]) > floor ? fabs(w[i]) : floor, change = fixed - w[i];
      for (int a = 0; a < nu; ++a)
        for (int b = 0; b < nu; ++b)
          Hk[(nx + a) * ns + nx + b] += change * V[a * nu + i] * V[b * nu + i];
      w[i] = fixed;
    }
  }
  for (int i = 0; i < nx; ++i) /* LV = L_xu V */
    for (int j = 0; j < nu; ++j) {
      double v = 0.0;
      for (int a = 0; a < nu; ++a) v += L[i * ns + nx + a] * V[a * nu + j];
      LV[i * nu + j] = v;
    }
  return 1;
}

int riccati_pivots(int N, int nx, int nu, const double* AB, double* H, const double* HT,
                   int reflect, double floor_share, double* work) {
  int ns = nx + nu;
  double *P = work, *T = P + nx * nx, *L = T + nx * ns, *R = L + ns * ns;
  double *V = R + nu * nu, *w = V + nu * nu, *LV = w + nu;
  int nnz = 0, row[nx * ns], col[nx * ns];
  double val[nx * ns];
  for (int i = 0; i < nx; ++i)
    for (int c = 0; c < ns; ++c)
      if (AB[i * ns + c] != 0.0) row[nnz] = i, col[nnz] = c, val[nnz++] = AB[i * ns + c];
  memcpy(P, HT, sizeof(double) * nx * nx);
  for (int k = N - 1; k >= 0; --k) {
    double* Hk = H + (size_t)k * ns * ns;
    stage_l(nx, ns, nnz, row, col, val, P, Hk, T, L);
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nu; ++j) R[i * nu + j] = L[(nx + i) * ns + nx + j];
    double frob = 0.0;
    for (int i = 0; i < nu * nu; ++i) frob += R[i] * R[i];
    frob = sqrt(frob); /* >= the largest eigenvalue's magnitude */
    double floor = floor_share * (frob > 1e-3 ? frob : 1e-3);
    if (cholesky(nu, R, floor, V) && cholesky(nu, R, 0.0, V)) {
      /* eigenvalues above floor_share of a bound on the largest: definite, no Jacobi;
         LV = L_xu C^-T (C the factor of R), w = 1: P = L_xx - LV LV' */
      for (int i = 0; i < nx; ++i)
        for (int j = 0; j < nu; ++j) {
          double v = L[i * ns + nx + j];
          for (int a = 0; a < j; ++a) v -= LV[i * nu + a] * V[j * nu + a];
          LV[i * nu + j] = v / V[j * nu + j];
        }
      for (int a = 0; a < nu; ++a) w[a] = 1.0;
    } else if (!eigen_pivot(nx, nu, ns, L, Hk, R, V, w, LV, reflect, floor_share)) {
      return 0;
    }
    for (int i = 0; i < nx; ++i)
      for (int j = 0; j <= i; ++j) {
        double v = 0.5 * (L[i * ns + j] + L[j * ns + i]);
        for (int a = 0; a < nu; ++a) v -= LV[i * nu + a] * LV[j * nu + a] / w[a];
        P[i * nx + j] = P[j * nx + i] = v;
      }
  }
  return 1;
}
