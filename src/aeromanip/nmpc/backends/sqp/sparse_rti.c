/*
 * One real-time iteration on the sparse model in compiled C (sparse_rti.py): what
 * SparseQpModel.linearize, .step and the Riccati interior point do for an RTI, in one
 * call. The model's generated stage Functions (mapped over the horizon) and terminal
 * Functions give the weighted residuals and rows with their Jacobians; the Gauss-Newton
 * blocks 2 J'J + reg I, the gradient 2 J'r, the gaps and the rows' bounds make the QP
 * that ocp_ipm.c solves. Jacobians are CasADi's (column-major); the QP's blocks row-major.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_fn.h"
#include "ocp_ipm.h"

typedef struct {
  int N, nx, nu, nr, nc, nrT, ncT, npk, nw, ng, n_rows;
  double reg;
  Fn stage, terminal;
  OcpIpm* qp;
  const double *A, *B;  /* the dynamics (row-major) */
  int *gap_rows, *row_slot, *row_src;
  /* the model at the iterate, and the QP's data */
  double *Z, *U, *r, *Jr, *c, *Jc, *rT, *JrT, *cT, *JcT;
  double *H, *g, *b, *C, *lg, *ug, *lb, *ub, *y, *lam_dyn, *lam_c, *lam_y, *vc, *cflat;
} Rti;

typedef struct {
  double f;
  int qp_status, qp_iterations;
} RtiInfo;

void rti_free(Rti* s);

static double* alloc(size_t n) { return calloc(n > 0 ? n : 1, sizeof(double)); }

/* dims: N, nx (states), nu (inputs), nr, nc, nrT, ncT, npk (parameters per stage), nw,
 * ng; gap_rows (N nx), row_slot and row_src (n_slots each: where each stage row of g
 * sits among the QP's N nc + ncT rows) */
Rti* rti_new(const int* dims, double reg, const double* A, const double* B,
             const int* gap_rows, const int* row_slot, const int* row_src, int n_slots,
             casadi_fn stage, casadi_work_fn stage_work, casadi_fn terminal,
             casadi_work_fn terminal_work) {
  Rti* s = calloc(1, sizeof(Rti));
  if (!s) return NULL;
  s->N = dims[0], s->nx = dims[1], s->nu = dims[2], s->nr = dims[3], s->nc = dims[4];
  s->nrT = dims[5], s->ncT = dims[6], s->npk = dims[7], s->nw = dims[8], s->ng = dims[9];
  s->n_rows = n_slots, s->reg = reg;
  int N = s->N, nx = s->nx, nv = s->nx + s->nu, nq = N * s->nc + s->ncT;
  s->qp = ocp_ipm_new(N, nx, s->nu, s->nc, s->ncT, A, B);
  s->A = A, s->B = B;
  s->gap_rows = malloc(sizeof(int) * N * nx);
  s->row_slot = malloc(sizeof(int) * (n_slots + 1));
  s->row_src = malloc(sizeof(int) * (n_slots + 1));
  if (!s->qp || !s->gap_rows || !s->row_slot || !s->row_src ||
      !fn_new(&s->stage, stage, stage_work) || !fn_new(&s->terminal, terminal, terminal_work)) {
    rti_free(s);
    return NULL;
  }
  memcpy(s->gap_rows, gap_rows, sizeof(int) * N * nx);
  memcpy(s->row_slot, row_slot, sizeof(int) * n_slots);
  memcpy(s->row_src, row_src, sizeof(int) * n_slots);
  double** bufs[] = {&s->Z, &s->U, &s->r, &s->Jr, &s->c, &s->Jc, &s->rT, &s->JrT, &s->cT,
                     &s->JcT, &s->H, &s->g, &s->b, &s->C, &s->lg, &s->ug, &s->lb, &s->ub,
                     &s->y, &s->lam_dyn, &s->lam_c, &s->lam_y, &s->vc, &s->cflat};
  size_t sizes[] = {(size_t)N * nx, (size_t)N * s->nu, (size_t)N * s->nr,
                    (size_t)N * s->nr * nv, (size_t)N * s->nc, (size_t)N * s->nc * nv,
                    (size_t)s->nrT, (size_t)s->nrT * nx, (size_t)s->ncT, (size_t)s->ncT * nx,
                    (size_t)N * nv * nv + nx * nx, (size_t)s->nw, (size_t)N * nx,
                    (size_t)N * s->nc * nv + s->ncT * nx, nq, nq, s->nw, s->nw, s->nw,
                    (size_t)N * nx, nq, s->nw, s->nw, nq};
  for (size_t i = 0; i < sizeof(sizes) / sizeof(sizes[0]); i++)
    if (!(*bufs[i] = alloc(sizes[i]))) {
      rti_free(s);
      return NULL;
    }
  return s;
}

void rti_free(Rti* s) {
  if (!s) return;
  if (s->qp) ocp_ipm_free(s->qp);
  if (s->stage.arg) fn_free(&s->stage);
  if (s->terminal.arg) fn_free(&s->terminal);
  void* all[] = {s->gap_rows, s->row_slot, s->row_src, s->Z, s->U, s->r, s->Jr, s->c,
                 s->Jc, s->rT, s->JrT, s->cT, s->JcT, s->H, s->g, s->b, s->C, s->lg, s->ug,
                 s->lb, s->ub, s->y, s->lam_dyn, s->lam_c, s->lam_y, s->vc, s->cflat};
  for (size_t i = 0; i < sizeof(all) / sizeof(all[0]); i++) free(all[i]);
  free(s);
}

/* H (n x n, row-major) = 2 J'J + reg I and g = 2 J'r of residuals r (m) whose Jacobian
 * J (m x n) is column-major; the zeros of J skipped (a residual touches few variables) */
static double gauss_newton(const double* J, const double* r, int m, int n, double reg,
                           double* H, double* g) {
  memset(H, 0, sizeof(double) * n * n);
  memset(g, 0, sizeof(double) * n);
  int cols[n > 0 ? n : 1];
  double f = 0.0;
  for (int i = 0; i < m; i++) {
    int k = 0;
    for (int j = 0; j < n; j++)
      if (J[j * m + i] != 0.0) cols[k++] = j;
    for (int a = 0; a < k; a++) {
      double ja = 2.0 * J[cols[a] * m + i];
      g[cols[a]] += ja * r[i];
      for (int b = 0; b < k; b++) H[cols[a] * n + cols[b]] += ja * J[cols[b] * m + i];
    }
    f += r[i] * r[i];
  }
  for (int j = 0; j < n; j++) H[j * n + j] += reg;
  return f;
}

/* a column-major block (m x n) into a row-major one */
static void transpose(const double* in, int m, int n, double* out) {
  for (int i = 0; i < m; i++)
    for (int j = 0; j < n; j++) out[i * n + j] = in[j * m + i];
}

/* one RTI from v (nw; clipped into [lbw, ubw] first) at parameters p: v_out = the
 * clipped v + the QP's step, the multipliers (lam_g: ng, lam_x: nw, CasADi's signs);
 * returns the QP's status (ocp_ipm.h; -1: the model failed), info: the cost at the
 * linearisation point, the QP's iterations */
int rti_step(Rti* s, const double* v, const double* p, const double* lbw, const double* ubw,
             const double* lbg, const double* ubg, const double* settings, double* v_out,
             double* lam_g, double* lam_x, RtiInfo* info) {
  int N = s->N, nx = s->nx, nu = s->nu, nv = nx + nu, nc = s->nc, nq = N * nc + s->ncT;
  for (int i = 0; i < s->nw; i++) s->vc[i] = fmin(fmax(v[i], lbw[i]), ubw[i]);
  for (int k = 0; k < N; k++) {
    memcpy(s->Z + k * nx, s->vc + k * nv, sizeof(double) * nx);
    memcpy(s->U + k * nu, s->vc + k * nv + nx, sizeof(double) * nu);
  }
  const double *zN = s->vc + N * nv, *P = p + nx, *pN = p + nx + (size_t)N * s->npk;
  if (fn_call(&s->stage, s->Z, s->U, P, s->r, s->Jr, s->c, s->Jc, 0) ||
      fn_call(&s->terminal, zN, pN, 0, s->rT, s->JrT, s->cT, s->JcT, 0))
    return -1;
  double f = 0.0;
  for (int k = 0; k < N; k++) {
    f += gauss_newton(s->Jr + (size_t)k * s->nr * nv, s->r + k * s->nr, s->nr, nv, s->reg,
                      s->H + (size_t)k * nv * nv, s->g + k * nv);
    transpose(s->Jc + (size_t)k * nc * nv, nc, nv, s->C + (size_t)k * nc * nv);
  }
  f += gauss_newton(s->JrT, s->rT, s->nrT, nx, s->reg, s->H + (size_t)N * nv * nv,
                    s->g + N * nv);
  transpose(s->JcT, s->ncT, nx, s->C + (size_t)N * nc * nv);
  /* the gaps z[k+1] - A z[k] - B u[k] and the dynamics' offsets b = lbg - gap */
  for (int k = 0; k < N; k++) {
    const double *z = s->vc + k * nv, *u = z + nx, *zn = s->vc + (k + 1) * nv;
    for (int i = 0; i < nx; i++) {
      double gap = zn[i];
      for (int j = 0; j < nx; j++) gap -= s->A[i * nx + j] * z[j];
      for (int j = 0; j < nu; j++) gap -= s->B[i * nu + j] * u[j];
      s->b[k * nx + i] = lbg[s->gap_rows[k * nx + i]] - gap;
    }
  }
  /* the stage rows' bounds, less their values (rows a stage lacks: none) */
  memcpy(s->cflat, s->c, sizeof(double) * N * nc);
  memcpy(s->cflat + N * nc, s->cT, sizeof(double) * s->ncT);
  for (int i = 0; i < nq; i++) s->lg[i] = -INFINITY, s->ug[i] = INFINITY;
  for (int i = 0; i < s->n_rows; i++) {
    int slot = s->row_slot[i], src = s->row_src[i];
    s->lg[slot] = lbg[src] - s->cflat[slot];
    s->ug[slot] = ubg[src] - s->cflat[slot];
  }
  for (int i = 0; i < s->nw; i++) s->lb[i] = lbw[i] - s->vc[i], s->ub[i] = ubw[i] - s->vc[i];
  OcpIpmInfo qi;
  int status = ocp_ipm_solve(s->qp, s->H, s->g, s->b, s->C, s->lg, s->ug, s->lb, s->ub,
                             s->lb /* x0: stage 0's state, pinned */, settings, s->y,
                             s->lam_dyn, s->lam_c, s->lam_y, &qi);
  for (int i = 0; i < s->nw; i++) v_out[i] = s->vc[i] + s->y[i];
  memset(lam_g, 0, sizeof(double) * s->ng);
  for (int i = 0; i < N * nx; i++) lam_g[s->gap_rows[i]] = s->lam_dyn[i];
  for (int i = 0; i < s->n_rows; i++) lam_g[s->row_src[i]] = s->lam_c[s->row_slot[i]];
  memcpy(lam_x, s->lam_y, sizeof(double) * s->nw);
  info->f = f, info->qp_status = status, info->qp_iterations = qi.iterations;
  return status;
}
