/*
 * The SQP's sparse QP by a Riccati-based interior point (ocp_ipm.c).
 */
#ifndef AEROMANIP_OCP_IPM_H
#define AEROMANIP_OCP_IPM_H

/* SOLVED: every residual within its tolerance; MAX_ITER, STALLED (a step or a pivot
 * vanished): the last iterate returned; NAN; NOT_CONVEX: no first factorisation */
enum { OCP_IPM_SOLVED = 0, OCP_IPM_MAX_ITER = 1, OCP_IPM_STALLED = 2, OCP_IPM_NAN = 3,
       OCP_IPM_NOT_CONVEX = 4 };

typedef struct OcpIpm OcpIpm;

typedef struct {
    int iterations, status;
    double res_stat, res_eq, res_ineq, res_comp;
} OcpIpmInfo;

OcpIpm* ocp_ipm_new(int N, int nx, int nu, int nc, int ncT, const double* A, const double* B);
void ocp_ipm_free(OcpIpm* s);
/* settings: tol_stat, tol_eq, tol_ineq, tol_comp, iter_max, thr (slack floor at start) */
int ocp_ipm_solve(OcpIpm* s, const double* H, const double* g, const double* b,
                  const double* C, const double* lg, const double* ug, const double* lb,
                  const double* ub, const double* x0, const double* settings, double* y_out,
                  double* lam_dyn, double* lam_c, double* lam_y, OcpIpmInfo* info);

/* riccati_pivots.c: 1 if every pivot of the Riccati recursion of the blocks H (N of ns x
 * ns, ns = nx + nu) and HT (nx x nx) for AB = [A B] is positive definite (their
 * eigenvalues at least floor_share of the largest magnitude, or of 1e-3), 0 at the first
 * that is not; with reflect, such pivots are made definite by a change of H's u-blocks
 * and 1 is returned. work: nx^2 + nx ns + ns^2 + 2 nu^2 + nu + nx nu doubles. */
int riccati_pivots(int N, int nx, int nu, const double* AB, double* H, const double* HT,
                   int reflect, double floor_share, double* work);

#endif
