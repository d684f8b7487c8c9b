/*
 * A primal-dual interior-point method for the SQP's sparse QP, structured as an optimal
 * control problem and solved by a Riccati recursion (the method of HPIPM, Frison and
 * Diehl 2020, and of Rao, Wright and Rawlings 1998), written for constant dynamics:
 *
 *   min  sum_k 1/2 y_k' H_k y_k + g_k' y_k  (k = 0..N; y_k = [x_k; u_k], y_N = x_N)
 *   s.t. x_{k+1} = A x_k + B u_k + b_k      (k = 0..N-1; A, B the same at every stage)
 *        x_0 = x0                           (pinned)
 *        lb_k <= y_k <= ub_k,  lg_k <= C_k y_k <= ug_k   (infinite bounds: absent)
 *
 * Mehrotra's predictor-corrector: one factorisation per iteration (the Riccati
 * recursion on H_k plus the barrier's curvature), two solves. Rows and bounds whose
 * lower and upper values are equal are equalities (a regularised Newton step on them). A and B are the model's
 * (sparse, constant): their products skip the zeros, so an iteration costs about
 * N (nu^3 / 3 + nx^2 nu + nc nv^2) flops. Matrices are row-major; H_k symmetric.
 *
 * Multipliers come back in CasADi's convention (conic): H y + g + A_g' lam_g + lam_x = 0,
 * positive where an upper bound is active: pi_k (the dynamics' rows x_{k+1} - A x_k -
 * B u_k = b_k) as lam_g, lam_c = lambda_upper - lambda_lower of the rows C_k y_k, lam_y
 * of the bounds (on x_0: what holds it pinned).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ocp_ipm.h"

#define PIVOT_FLOOR 1e-13      /* relative to the pivot's diagonal entry */
#define PIVOT_INDEFINITE 1e-7  /* a pivot below minus this (relative) is not rounding */
/* an equality row C y = e is kept by a regularised Newton step (C dy - reg dlam = -r):
 * a bounded weight 1/reg in the factorisation where two opposite bounds would have
 * their barrier's grow without bound; its fixed point is exact */
#define EQUALITY_REG 1e-8
#define MIN_STEP 1e-12
#define LAMBDA_FLOOR 1e-6 /* the bounds' multipliers start at least here */         /* a shorter step: stalled */
#define STEP_TO_BOUNDARY 0.995 /* the fraction of the longest feasible step taken */

struct OcpIpm {
    int N, nx, nu, nc, ncT, nv;
    double *A, *B;           /* nx x nx, nx x nu */
    int *col_start, *col_row, *col_of; /* the nonzeros of [A B] by column: rows, columns */
    double* col_val;          /* ... and values */
    /* per stage (N + 1, sized for nv): the iterate, slacks, multipliers, masks */
    double *y, *pi, *tl, *tu, *ll, *lu;      /* y: (N+1) nv; pi: N nx; t, l: per bound */
    double *itl, *itu;                       /* 1 / t (no division in the inner loops) */
    double *dy, *dpi, *dtl, *dtu, *dll, *dlu; /* the step */
    double *atl, *atu, *all, *alu;           /* the affine step's slack and multipliers */
    unsigned char *ml, *mu, *me;             /* finite lower / upper / equal, per bound */
    /* Riccati: per stage */
    double *P, *p, *L, *K, *kff, *Pc; /* Pc: P_{k+1} rdyn_k, per iteration */
    double *M, *m, *PAB, *w, *qt, *rhat, *rdyn;
    int nb_stage; /* bounds per stage: nv box + nc rows */
    /* per solve, the nonzeros of H_k's rows and C_k's rows: column indices by row */
    int *h_ptr, *h_col, *c_ptr, *c_col;
};

static int stage_nv(const OcpIpm* s, int k) { return k < s->N ? s->nv : s->nx; }
static int stage_nc(const OcpIpm* s, int k) { return k < s->N ? s->nc : s->ncT; }

OcpIpm* ocp_ipm_new(int N, int nx, int nu, int nc, int ncT, const double* A, const double* B) {
    OcpIpm* s = calloc(1, sizeof(OcpIpm));
    if (!s) return NULL;
    int nv = nx + nu, nb = nv + (nc > ncT ? nc : ncT);
    s->N = N, s->nx = nx, s->nu = nu, s->nc = nc, s->ncT = ncT, s->nv = nv, s->nb_stage = nb;
    size_t S = (size_t)(N + 1);
    s->A = malloc(sizeof(double) * nx * nx);
    s->B = malloc(sizeof(double) * nx * (nu > 0 ? nu : 1));
    s->col_start = malloc(sizeof(int) * (nv + 1));
    s->col_row = malloc(sizeof(int) * nx * nv);
    s->col_of = malloc(sizeof(int) * nx * nv);
    s->col_val = malloc(sizeof(double) * nx * nv);
    double** vecs[] = {&s->y, &s->dy, &s->qt, &s->rhat};
    for (int i = 0; i < 4; i++) *vecs[i] = calloc(S * nv, sizeof(double));
    double** pis[] = {&s->pi, &s->dpi, &s->rdyn, &s->p, &s->w, &s->Pc};
    for (int i = 0; i < 6; i++) *pis[i] = calloc(S * nx, sizeof(double));
    double** bnds[] = {&s->tl, &s->tu, &s->ll, &s->lu, &s->dtl, &s->dtu, &s->dll,
                       &s->dlu, &s->atl, &s->atu, &s->all, &s->alu, &s->itl, &s->itu};
    for (int i = 0; i < 14; i++) *bnds[i] = calloc(S * nb, sizeof(double));
    s->ml = calloc(S * nb, 1), s->mu = calloc(S * nb, 1), s->me = calloc(S * nb, 1);
    s->P = calloc(S * nx * nx, sizeof(double));
    s->L = calloc(S * nu * nu + 1, sizeof(double));
    s->K = calloc(S * nu * nx + 1, sizeof(double));
    s->kff = calloc(S * nu + 1, sizeof(double));
    s->M = calloc((size_t)nv * nv, sizeof(double));
    s->m = calloc(nv, sizeof(double));
    s->PAB = calloc((size_t)nx * nv, sizeof(double));
    int ncm = nc > ncT ? nc : ncT;
    s->h_ptr = malloc(sizeof(int) * S * (nv + 1));
    s->h_col = malloc(sizeof(int) * S * nv * nv);
    s->c_ptr = malloc(sizeof(int) * S * (ncm + 1));
    s->c_col = malloc(sizeof(int) * (S * ncm * nv + 1));
    if (!s->h_ptr || !s->h_col || !s->c_ptr || !s->c_col ||!s->A || !s->B || !s->col_start || !s->col_row || !s->col_of || !s->col_val || !s->y || !s->dy ||
        !s->qt || !s->rhat || !s->pi || !s->dpi || !s->rdyn || !s->p || !s->w || !s->Pc || !s->tl ||
        !s->tu || !s->ll || !s->lu || !s->dtl || !s->dtu || !s->dll || !s->dlu || !s->atl ||
        !s->atu || !s->all || !s->alu || !s->itl || !s->itu || !s->ml || !s->mu || !s->me || !s->P || !s->L || !s->K ||
        !s->kff || !s->M || !s->m || !s->PAB) {
        ocp_ipm_free(s);
        return NULL;
    }
    memcpy(s->A, A, sizeof(double) * nx * nx);
    if (nu) memcpy(s->B, B, sizeof(double) * nx * nu);
    int n = 0;
    for (int j = 0; j < nv; j++) {
        s->col_start[j] = n;
        for (int i = 0; i < nx; i++) {
            double v = j < nx ? A[i * nx + j] : B[i * nu + (j - nx)];
            if (v != 0.0) s->col_row[n] = i, s->col_of[n] = j, s->col_val[n++] = v;
        }
    }
    s->col_start[nv] = n;
    return s;
}

void ocp_ipm_free(OcpIpm* s) {
    if (!s) return;
    void* all[] = {s->A, s->B, s->col_start, s->col_row, s->col_of, s->col_val, s->y, s->dy, s->qt,
                   s->rhat, s->pi, s->dpi, s->rdyn, s->p, s->w, s->Pc, s->tl, s->tu, s->ll, s->lu,
                   s->dtl, s->dtu, s->dll, s->dlu, s->atl, s->atu, s->all, s->alu, s->itl, s->itu, s->ml,
                   s->mu, s->me, s->P, s->L, s->K, s->kff, s->M, s->m, s->PAB, s->h_ptr,
                   s->h_col, s->c_ptr, s->c_col};
    for (size_t i = 0; i < sizeof(all) / sizeof(all[0]); i++) free(all[i]);
    free(s);
}

/* the nonzeros of row r of C_k: c_col[c_ptr[.. r] .. c_ptr[.. r + 1]] */
static const int* row_cols(const OcpIpm* s, int k, int r, int* n) {
    int ncm = s->nb_stage - s->nv;
    const int* ptr = s->c_ptr + (size_t)k * (ncm + 1);
    *n = ptr[r + 1] - ptr[r];
    return s->c_col + (size_t)k * ncm * s->nv + ptr[r];
}

/* the value of bound i of stage k at y_k: a variable (i < nvk) or a row of C_k */
static double bound_value(const OcpIpm* s, const double* Ck, int k, const double* yk, int i) {
    int nvk = stage_nv(s, k);
    if (i < nvk) return yk[i];
    int n;
    const int* col = row_cols(s, k, i - nvk, &n);
    const double* row = Ck + (size_t)(i - nvk) * nvk;
    double v = 0.0;
    for (int t = 0; t < n; t++) v += row[col[t]] * yk[col[t]];
    return v;
}

/* y_k-space vector out += sum_i D_i' a_i over stage k's bounds (D_i a unit row or C_k's) */
static void add_bounds_t(const OcpIpm* s, const double* Ck, int k, const double* a, double* out) {
    int nvk = stage_nv(s, k), nck = stage_nc(s, k);
    for (int i = 0; i < nvk; i++) out[i] += a[i];
    for (int r = 0; r < nck; r++) {
        double ar = a[nvk + r];
        if (ar == 0.0) continue;
        int n;
        const int* col = row_cols(s, k, r, &n);
        const double* row = Ck + (size_t)r * nvk;
        for (int t = 0; t < n; t++) out[col[t]] += ar * row[col[t]];
    }
}

/* out = [A B] y (nx) + add, the zeros of [A B] skipped */
static void dynamics(const OcpIpm* s, const double* y, const double* add, double* out) {
    memcpy(out, add, sizeof(double) * s->nx);
    for (int j = 0; j < s->nv; j++) {
        double yj = y[j];
        if (yj == 0.0) continue;
        for (int q = s->col_start[j]; q < s->col_start[j + 1]; q++)
            out[s->col_row[q]] += s->col_val[q] * yj;
    }
}

typedef struct {
    const double *H, *g, *b, *C, *lg, *ug, *lb, *ub, *x0;
} Data;

static const double* stage_H(const OcpIpm* s, const Data* d, int k) {
    return d->H + (size_t)k * s->nv * s->nv;
}
static const double* stage_C(const OcpIpm* s, const Data* d, int k) {
    return d->C + (size_t)k * s->nc * s->nv;
}
static double stage_lo(const OcpIpm* s, const Data* d, int k, int i) {
    int nvk = stage_nv(s, k);
    return i < nvk ? d->lb[k * s->nv + i] : d->lg[k * s->nc + (i - nvk)];
}
static double stage_hi(const OcpIpm* s, const Data* d, int k, int i) {
    int nvk = stage_nv(s, k);
    return i < nvk ? d->ub[k * s->nv + i] : d->ug[k * s->nc + (i - nvk)];
}

/* this QP's nonzeros of H_k's and C_k's rows (the data stay fixed during a solve) */
static void scan(OcpIpm* s, const Data* d) {
    int ncm = s->nb_stage - s->nv, nv = s->nv;
    for (int k = 0; k <= s->N; k++) {
        int nvk = stage_nv(s, k), nck = stage_nc(s, k), n = 0;
        const double *H = stage_H(s, d, k), *Ck = stage_C(s, d, k);
        int *hp = s->h_ptr + (size_t)k * (nv + 1), *hc = s->h_col + (size_t)k * nv * nv;
        for (int i = 0; i < nvk; i++) {
            hp[i] = n;
            for (int j = 0; j < nvk; j++)
                if (H[i * nvk + j] != 0.0) hc[n++] = j;
        }
        hp[nvk] = n;
        int *cp = s->c_ptr + (size_t)k * (ncm + 1), *cc = s->c_col + (size_t)k * ncm * nv;
        n = 0;
        for (int r = 0; r < nck; r++) {
            cp[r] = n;
            for (int j = 0; j < nvk; j++)
                if (Ck[r * nvk + j] != 0.0) cc[n++] = j;
        }
        cp[nck] = n;
    }
}

/* masks (x_0's bounds are not constraints: x_0 is pinned), start: y on x0, slacks and
 * multipliers at least `thr` */
static void init(OcpIpm* s, const Data* d, double thr, double lam0) {
    int nb = s->nb_stage;
    memset(s->y, 0, sizeof(double) * (s->N + 1) * s->nv);
    memset(s->pi, 0, sizeof(double) * s->N * s->nx);
    memcpy(s->y, d->x0, sizeof(double) * s->nx);
    for (int k = 0; k <= s->N; k++) {
        int nvk = stage_nv(s, k), n = nvk + stage_nc(s, k);
        const double *Ck = stage_C(s, d, k), *yk = s->y + k * s->nv;
        for (int i = 0; i < nb; i++) {
            int j = k * nb + i;
            double lo = i < n ? stage_lo(s, d, k, i) : -INFINITY;
            double hi = i < n ? stage_hi(s, d, k, i) : INFINITY;
            int pinned = k == 0 && i < s->nx;
            s->me[j] = !pinned && isfinite(lo) && lo == hi;
            s->ml[j] = !pinned && !s->me[j] && isfinite(lo);
            s->mu[j] = !pinned && !s->me[j] && isfinite(hi);
            double v = (s->ml[j] || s->mu[j]) ? bound_value(s, Ck, k, yk, i) : 0.0;
            s->tl[j] = s->ml[j] ? fmax(v - lo, thr) : 1.0;
            s->tu[j] = s->mu[j] ? fmax(hi - v, thr) : 1.0;
            s->ll[j] = s->ml[j] ? lam0 : 0.0;
            s->lu[j] = s->mu[j] ? lam0 : 0.0;
        }
    }
}

typedef struct {
    double stat, eq, ineq, mu, comp; /* mu: the mean of t lambda (centring), comp: its max */
} Residuals;

/* the residuals at the iterate: rhat (stationarity without the dynamics' multipliers),
 * rdyn, the bounds' (into dtl/dtu as scratch: r_l = D y - lo - t_l, r_u = hi - D y - t_u) */
static Residuals residuals(OcpIpm* s, const Data* d) {
    int N = s->N, nx = s->nx, nv = s->nv, nb = s->nb_stage;
    Residuals r = {0, 0, 0, 0, 0};
    double comp = 0.0;
    int count = 0;
    for (int k = 0; k <= N; k++) {
        int nvk = stage_nv(s, k), n = nvk + stage_nc(s, k);
        const double *H = stage_H(s, d, k), *Ck = stage_C(s, d, k), *yk = s->y + k * nv;
        double *rh = s->rhat + k * nv, a[nb];
        const int *hp = s->h_ptr + (size_t)k * (nv + 1), *hc = s->h_col + (size_t)k * nv * nv;
        for (int i = 0; i < nvk; i++) {
            double v = d->g[k * nv + i];
            for (int t = hp[i]; t < hp[i + 1]; t++) v += H[i * nvk + hc[t]] * yk[hc[t]];
            rh[i] = v;
        }
        for (int i = 0; i < n; i++) {
            int j = k * nb + i;
            a[i] = s->lu[j] - s->ll[j];
            if (s->me[j]) { /* an equality: its residual in dtl, its multiplier in lu */
                s->dtl[j] = bound_value(s, Ck, k, yk, i) - stage_lo(s, d, k, i);
                r.eq = fmax(r.eq, fabs(s->dtl[j]));
                continue;
            }
            if (!(s->ml[j] || s->mu[j])) continue;
            double v = bound_value(s, Ck, k, yk, i);
            s->dtl[j] = s->ml[j] ? v - stage_lo(s, d, k, i) - s->tl[j] : 0.0;
            s->dtu[j] = s->mu[j] ? stage_hi(s, d, k, i) - v - s->tu[j] : 0.0;
            r.ineq = fmax(r.ineq, fmax(fabs(s->dtl[j]), fabs(s->dtu[j])));
            if (s->ml[j]) {
                double c = s->tl[j] * s->ll[j];
                comp += c, count++, r.comp = fmax(r.comp, c), s->itl[j] = 1.0 / s->tl[j];
            }
            if (s->mu[j]) {
                double c = s->tu[j] * s->lu[j];
                comp += c, count++, r.comp = fmax(r.comp, c), s->itu[j] = 1.0 / s->tu[j];
            }
        }
        add_bounds_t(s, Ck, k, a, rh);
        /* the full stationarity: + [A B]' pi_k - [pi_{k-1}; 0] (x_0 is pinned) */
        double st[nv];
        memcpy(st, rh, sizeof(double) * nvk);
        if (k < N) {
            const double* pk = s->pi + k * nx;
            for (int j = 0; j < nv; j++)
                for (int q = s->col_start[j]; q < s->col_start[j + 1]; q++)
                    st[j] += s->col_val[q] * pk[s->col_row[q]];
        }
        if (k > 0)
            for (int i = 0; i < nx; i++) st[i] -= s->pi[(k - 1) * nx + i];
        for (int i = k == 0 ? nx : 0; i < nvk; i++) r.stat = fmax(r.stat, fabs(st[i]));
        if (k < N) {
            const double* xn = s->y + (k + 1) * nv;
            double* rd = s->rdyn + k * nx;
            dynamics(s, yk, d->b + k * nx, rd);
            for (int i = 0; i < nx; i++) rd[i] -= xn[i], r.eq = fmax(r.eq, fabs(rd[i]));
        }
    }
    r.mu = count ? comp / count : 0.0;
    return r;
}

/* out = P x + add for a symmetric P (n x n): along P's rows, independent sums */
static void symv(const double* P, const double* x, const double* add, int n, double* out) {
    memcpy(out, add, sizeof(double) * n);
    for (int j = 0; j < n; j++) {
        double xj = x[j];
        const double* row = P + j * n; /* P[j][i] = P[i][j] */
        for (int i = 0; i < n; i++) out[i] += row[i] * xj;
    }
}

/* Riccati factorisation of the Newton system's matrix: H_k + D' Sigma D per stage */
static int factorize(OcpIpm* s, const Data* d) {
    int N = s->N, nx = s->nx, nu = s->nu, nv = s->nv, nb = s->nb_stage;
    double* M = s->M;
    for (int k = N; k >= 0; k--) {
        int nvk = stage_nv(s, k), nck = stage_nc(s, k);
        const double *H = stage_H(s, d, k), *Ck = stage_C(s, d, k);
        memcpy(M, H, sizeof(double) * nvk * nvk);
        for (int i = 0; i < nvk + nck; i++) {
            int j = k * nb + i;
            double sig = s->me[j] ? 1.0 / EQUALITY_REG
                                  : (s->ml[j] ? s->ll[j] * s->itl[j] : 0) +
                                        (s->mu[j] ? s->lu[j] * s->itu[j] : 0);
            if (sig == 0.0) continue;
            if (i < nvk) {
                M[i * nvk + i] += sig;
                continue;
            }
            const double* row = Ck + (size_t)(i - nvk) * nvk;
            int n;
            const int* col = row_cols(s, k, i - nvk, &n);
            for (int t = 0; t < n; t++) { /* the lower triangle: columns are ascending */
                int a = col[t];
                double ra = sig * row[a];
                for (int q = 0; q <= t; q++) M[a * nvk + col[q]] += ra * row[col[q]];
            }
        }
        double* Pk = s->P + (size_t)k * nx * nx;
        if (k == N) {
            for (int a = 0; a < nx; a++)
                for (int c = 0; c <= a; c++) Pk[a * nx + c] = Pk[c * nx + a] = M[a * nx + c];
            continue;
        }
        /* M += [A B]' P_{k+1} [A B] (lower triangle), the zeros of [A B] skipped */
        const double* Pn = s->P + (size_t)(k + 1) * nx * nx;
        const double* ck = s->rdyn + k * nx;
        double* Pck = s->Pc + k * nx;
        int gap = 0;
        for (int i = 0; i < nx; i++) gap |= ck[i] != 0.0;
        memset(Pck, 0, sizeof(double) * nx);
        if (gap) /* the dynamics' residual: zero once a full step is taken */
            for (int j = 0; j < nx; j++) {
                double cj = ck[j];
                const double* row = Pn + j * nx; /* P symmetric: its rows are columns */
                for (int i = 0; i < nx; i++) Pck[i] += row[i] * cj;
            }
        /* PABt = (P [A B])' by the nonzeros of [A B]: each a whole row of P (= its
         * column) scaled, then M[a][c] += [A B]'[a] . PABt[c] over c's nonzeros */
        double* PABt = s->PAB;
        int nnz = s->col_start[nv];
        memset(PABt, 0, sizeof(double) * nv * nx);
        for (int q = 0; q < nnz; q++) {
            double v = s->col_val[q];
            const double* Pr = Pn + s->col_row[q] * nx;
            double* out = PABt + s->col_of[q] * nx;
            for (int i = 0; i < nx; i++) out[i] += v * Pr[i];
        }
        for (int a = 0; a < nv; a++) {
            const double* Pa = PABt + a * nx;
            double* Ma = M + a * nv;
            for (int q = 0; q < nnz && s->col_of[q] <= a; q++)
                Ma[s->col_of[q]] += s->col_val[q] * Pa[s->col_row[q]];
        }
        /* Cholesky of M_uu (lower), K = L^-1 M_ux, P_k = M_xx - K'K */
        double *Lk = s->L + (size_t)k * nu * nu, *Kk = s->K + (size_t)k * nu * nx;
        for (int i = 0; i < nu; i++)
            for (int j = 0; j <= i; j++) {
                double v = M[(nx + i) * nv + nx + j];
                for (int q = 0; q < j; q++) v -= Lk[i * nu + q] * Lk[j * nu + q];
                if (i == j) {
                    /* a pivot lost to rounding (huge barrier terms) is floored; one
                     * clearly negative means a QP not convex on the inputs */
                    double scale = 1.0 + fabs(M[(nx + i) * nv + nx + i]);
                    if (!(v > -PIVOT_INDEFINITE * scale)) return 1;
                    Lk[i * nu + i] = sqrt(fmax(v, PIVOT_FLOOR * scale));
                } else {
                    Lk[i * nu + j] = v / Lk[j * nu + j];
                }
            }
        for (int i = 0; i < nu; i++) { /* row by row: the inner loops run along rows */
            double* Ki = Kk + i * nx;
            memcpy(Ki, M + (nx + i) * nv, sizeof(double) * nx);
            for (int q = 0; q < i; q++) {
                double l = Lk[i * nu + q];
                const double* Kq = Kk + q * nx;
                for (int c = 0; c < nx; c++) Ki[c] -= l * Kq[c];
            }
            double inv = 1.0 / Lk[i * nu + i];
            for (int c = 0; c < nx; c++) Ki[c] *= inv;
        }
        if (k == 0) continue; /* x_0 is pinned: P_0 is not needed */
        for (int a = 0; a < nx; a++) memcpy(Pk + a * nx, M + a * nv, sizeof(double) * (a + 1));
        for (int q = 0; q < nu; q++) {
            const double* Kq = Kk + q * nx;
            for (int a = 0; a < nx; a++) {
                double ka = Kq[a];
                double* Pa = Pk + a * nx;
                for (int c = 0; c <= a; c++) Pa[c] -= ka * Kq[c];
            }
        }
        for (int a = 0; a < nx; a++)
            for (int c = 0; c < a; c++) Pk[c * nx + a] = Pk[a * nx + c];
    }
    return 0;
}

/* the step for the complementarity targets (rcl, rcu: t*lambda wanted - now, per
 * bound): backward recursion on the vectors, forward sweep, then slacks and multipliers */
static void solve(OcpIpm* s, const Data* d, const double* rcl, const double* rcu) {
    int N = s->N, nx = s->nx, nu = s->nu, nv = s->nv, nb = s->nb_stage;
    for (int k = N; k >= 0; k--) {
        int nvk = stage_nv(s, k), n = nvk + stage_nc(s, k);
        const double* Ck = stage_C(s, d, k);
        double *q = s->qt + k * nv, a[nb];
        memcpy(q, s->rhat + k * nv, sizeof(double) * nvk);
        for (int i = 0; i < n; i++) {
            int j = k * nb + i;
            double v = 0.0;
            if (s->me[j]) v = s->dtl[j] / EQUALITY_REG;
            if (s->ml[j]) v -= (rcl[j] - s->ll[j] * s->dtl[j]) * s->itl[j];
            if (s->mu[j]) v += (rcu[j] - s->lu[j] * s->dtu[j]) * s->itu[j];
            a[i] = v;
        }
        add_bounds_t(s, Ck, k, a, q);
        double* pk = s->p + k * nx;
        if (k == N) {
            memcpy(pk, q, sizeof(double) * nx);
            continue;
        }
        /* m = q + [A B]' (P_{k+1} c_k + p_{k+1}), c_k = rdyn_k */
        const double *pn = s->p + (k + 1) * nx;
        double* w = s->w;
        const double* Pck = s->Pc + k * nx;
        for (int i = 0; i < nx; i++) w[i] = Pck[i] + pn[i];
        double* m = s->m;
        for (int c = 0; c < nv; c++) {
            double v = q[c];
            for (int t = s->col_start[c]; t < s->col_start[c + 1]; t++)
                v += s->col_val[t] * w[s->col_row[t]];
            m[c] = v;
        }
        double *Lk = s->L + (size_t)k * nu * nu, *Kk = s->K + (size_t)k * nu * nx;
        double* kf = s->kff + k * nu;
        for (int i = 0; i < nu; i++) {
            double v = m[nx + i];
            for (int t = 0; t < i; t++) v -= Lk[i * nu + t] * kf[t];
            kf[i] = v / Lk[i * nu + i];
        }
        memcpy(pk, m, sizeof(double) * nx);
        for (int t = 0; t < nu; t++) {
            double f = kf[t];
            const double* Kt = Kk + t * nx;
            for (int i = 0; i < nx; i++) pk[i] -= Kt[i] * f;
        }
    }
    /* forward: du_k = -L^-T (K dx_k + kff), dx_{k+1} = A dx_k + B du_k + rdyn_k */
    memset(s->dy, 0, sizeof(double) * nx); /* y_0's x is on x0 already */
    for (int k = 0; k < N; k++) {
        double *dyk = s->dy + k * nv, *dx = dyk, *du = dyk + nx, *dxn = s->dy + (k + 1) * nv;
        double *Lk = s->L + (size_t)k * nu * nu, *Kk = s->K + (size_t)k * nu * nx;
        double v[nu > 0 ? nu : 1];
        for (int i = 0; i < nu; i++) {
            double a = s->kff[k * nu + i];
            for (int j = 0; j < nx; j++) a += Kk[i * nx + j] * dx[j];
            v[i] = a;
        }
        for (int i = nu - 1; i >= 0; i--) {
            double a = v[i];
            for (int t = i + 1; t < nu; t++) a += Lk[t * nu + i] * du[t]; /* du = -z */
            du[i] = -a / Lk[i * nu + i];
        }
        dynamics(s, dyk, s->rdyn + k * nx, dxn);
        /* pi_k (new) = P_{k+1} dx_{k+1} + p_{k+1}: the step of pi is the difference */
        const double *Pn = s->P + (size_t)(k + 1) * nx * nx, *pn = s->p + (k + 1) * nx;
        double* dpk = s->dpi + k * nx;
        symv(Pn, dxn, pn, nx, dpk);
        for (int i = 0; i < nx; i++) dpk[i] -= s->pi[k * nx + i];
    }
    /* slacks and multipliers: dt_l = r_l + D dy, dt_u = r_u - D dy, dlam = (rc - lam dt)/t */
    for (int k = 0; k <= N; k++) {
        int nvk = stage_nv(s, k), n = nvk + stage_nc(s, k);
        const double *Ck = stage_C(s, d, k), *dyk = s->dy + k * nv;
        for (int i = 0; i < n; i++) {
            int j = k * nb + i;
            if (!(s->ml[j] || s->mu[j] || s->me[j])) continue;
            double Ddy = bound_value(s, Ck, k, dyk, i);
            if (s->me[j]) s->atu[j] = (Ddy + s->dtl[j]) / EQUALITY_REG;
            if (s->ml[j]) {
                double dt = s->dtl[j] + Ddy;
                s->all[j] = dt, s->atl[j] = (rcl[j] - s->ll[j] * dt) * s->itl[j];
            }
            if (s->mu[j]) {
                double dt = s->dtu[j] - Ddy;
                s->alu[j] = dt, s->atu[j] = (rcu[j] - s->lu[j] * dt) * s->itu[j];
            }
        }
    }
}

/* the longest step (possibly infinite) keeping slacks and multipliers nonnegative */
static double max_step(const OcpIpm* s) {
    int n = (s->N + 1) * s->nb_stage;
    double a = INFINITY;
    for (int j = 0; j < n; j++) {
        if (s->ml[j]) {
            if (s->all[j] < 0) a = fmin(a, -s->tl[j] / s->all[j]);
            if (s->atl[j] < 0) a = fmin(a, -s->ll[j] / s->atl[j]);
        }
        if (s->mu[j]) {
            if (s->alu[j] < 0) a = fmin(a, -s->tu[j] / s->alu[j]);
            if (s->atu[j] < 0) a = fmin(a, -s->lu[j] / s->atu[j]);
        }
    }
    return a;
}

/* In `solve`, all/alu hold the slacks' steps and atl/atu the multipliers' (named for
 * the affine step that uses them first). */
int ocp_ipm_solve(OcpIpm* s, const double* H, const double* g, const double* b,
                  const double* C, const double* lg, const double* ug, const double* lb,
                  const double* ub, const double* x0, const double* settings, double* y_out,
                  double* lam_dyn, double* lam_c, double* lam_y, OcpIpmInfo* info) {
    Data d = {H, g, b, C, lg, ug, lb, ub, x0};
    double tol_stat = settings[0], tol_eq = settings[1], tol_ineq = settings[2];
    double tol_comp = settings[3], thr = settings[5];
    int iter_max = (int)settings[4];
    int N = s->N, nx = s->nx, nv = s->nv, nb = s->nb_stage, nbt = (N + 1) * nb;
    scan(s, &d);
    /* the bounds' multipliers start at the gradient's scale (they balance it at the
     * optimum): an SQP's QPs near convergence start near their small multipliers */
    double gmax = 0.0;
    for (int i = 0; i < N * nv + nx; i++) gmax = fmax(gmax, fabs(g[i]));
    init(s, &d, thr, fmin(thr, fmax(gmax, LAMBDA_FLOOR)));
    double *rcl = malloc(sizeof(double) * nbt * 2), *rcu = rcl + nbt;
    int status = OCP_IPM_MAX_ITER, it = 0;
    Residuals r = residuals(s, &d);
    for (it = 0; it <= iter_max; it++) {
        if (!(isfinite(r.stat) && isfinite(r.eq) && isfinite(r.ineq) && isfinite(r.comp))) {
            status = OCP_IPM_NAN;
            break;
        }
        if (r.stat <= tol_stat && r.eq <= tol_eq && r.ineq <= tol_ineq && r.comp <= tol_comp) {
            status = OCP_IPM_SOLVED;
            break;
        }
        if (it == iter_max) break;
        if (factorize(s, &d)) { /* late: rounding at tiny slacks, the iterate stands */
            status = it == 0 ? OCP_IPM_NOT_CONVEX : OCP_IPM_STALLED;
            break;
        }
        /* predictor (affine): complementarity to zero */
        for (int j = 0; j < nbt; j++) rcl[j] = -s->tl[j] * s->ll[j], rcu[j] = -s->tu[j] * s->lu[j];
        solve(s, &d, rcl, rcu);
        double alpha = fmin(1.0, max_step(s)), comp = 0.0;
        int count = 0;
        for (int j = 0; j < nbt; j++) {
            if (s->ml[j]) comp += (s->tl[j] + alpha * s->all[j]) * (s->ll[j] + alpha * s->atl[j]), count++;
            if (s->mu[j]) comp += (s->tu[j] + alpha * s->alu[j]) * (s->lu[j] + alpha * s->atu[j]), count++;
        }
        double sigma = 0.0;
        if (count && r.mu > 0) {
            double ratio = comp / count / r.mu;
            sigma = ratio * ratio * ratio;
        }
        /* corrector: centring sigma mu and Mehrotra's second-order term */
        for (int j = 0; j < nbt; j++) {
            rcl[j] = s->ml[j] ? sigma * r.mu - s->tl[j] * s->ll[j] - s->all[j] * s->atl[j] : 0.0;
            rcu[j] = s->mu[j] ? sigma * r.mu - s->tu[j] * s->lu[j] - s->alu[j] * s->atu[j] : 0.0;
        }
        solve(s, &d, rcl, rcu);
        alpha = fmin(1.0, STEP_TO_BOUNDARY * max_step(s));
        if (alpha < MIN_STEP) {
            status = OCP_IPM_STALLED;
            break;
        }
        for (int i = 0; i < (N + 1) * nv; i++) s->y[i] += alpha * s->dy[i];
        for (int i = 0; i < N * nx; i++) s->pi[i] += alpha * s->dpi[i];
        for (int j = 0; j < nbt; j++) {
            if (s->ml[j]) s->tl[j] += alpha * s->all[j], s->ll[j] += alpha * s->atl[j];
            if (s->mu[j]) s->tu[j] += alpha * s->alu[j], s->lu[j] += alpha * s->atu[j];
            if (s->me[j]) s->lu[j] += alpha * s->atu[j];
        }
        r = residuals(s, &d);
    }
    free(rcl);
    info->iterations = it;
    info->status = status;
    info->res_stat = r.stat, info->res_eq = r.eq, info->res_ineq = r.ineq, info->res_comp = r.comp;
    /* the answers in CasADi's convention (module comment) */
    for (int k = 0; k <= N; k++) {
        int nvk = stage_nv(s, k), nck = stage_nc(s, k);
        memcpy(y_out + k * nv, s->y + k * nv, sizeof(double) * nvk);
        for (int i = 0; i < nvk; i++) lam_y[k * nv + i] = s->lu[k * nb + i] - s->ll[k * nb + i];
        for (int r2 = 0; r2 < nck; r2++)
            lam_c[k * s->nc + r2] = s->lu[k * nb + nvk + r2] - s->ll[k * nb + nvk + r2];
    }
    for (int i = 0; i < N * nx; i++) lam_dyn[i] = -s->pi[i];
    /* x_0 pinned: its multiplier closes stage 0's stationarity */
    if (N > 0) {
        double st[nv];
        memcpy(st, s->rhat, sizeof(double) * nv);
        for (int j = 0; j < nx; j++)
            for (int q = s->col_start[j]; q < s->col_start[j + 1]; q++)
                st[j] += s->col_val[q] * s->pi[s->col_row[q]];
        for (int i = 0; i < nx; i++) lam_y[i] -= st[i];
    }
    return status;
}
