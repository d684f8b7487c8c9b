/*
 * Small dense linear algebra and optimality measures for the compiled SQP loop
 * (condensed_loop.c). Matrices are column-major.
 */
#ifndef AEROMANIP_DENSE_LINALG_H
#define AEROMANIP_DENSE_LINALG_H

double la_dot(const double* a, const double* b, int n);
void la_gram(const double* M, int m, int n, double scale, double* H, int add, double* T);
void la_matvec(const double* M, int m, int n, const double* x, double* y);
void la_matvec_t(const double* M, int m, int n, const double* x, double* y);
int la_positive_definite(const double* H, int n, double* L);
void la_packed_vecmat(const double* a, const double* P, int n, double* y);
int la_cholesky_inverse_packed(const double* H, int n, double eps, double* R, double* Rinv);
void sqp_eigen_symmetric(const double* S, int n, double* lam, double* V, double* e);
double la_violation(const double* g, const double* lb, const double* ub, int n);
double la_l1(const double* g, const double* lb, const double* ub, int n);
double la_complementarity(const double* g, const double* lb, const double* ub,
                          const double* lam, int n);

#endif
