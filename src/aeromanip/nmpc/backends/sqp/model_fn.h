/*
 * A CasADi-generated Function called from C through its symbols (the compiled loops).
 */
#ifndef AEROMANIP_MODEL_FN_H
#define AEROMANIP_MODEL_FN_H

typedef long long casadi_int;
typedef int (*casadi_fn)(const double** arg, double** res, casadi_int* iw, double* w, int mem);
typedef int (*casadi_work_fn)(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw,
                              casadi_int* sz_w);

typedef struct {
  casadi_fn f;
  const double** arg;
  double** res;
  casadi_int* iw;
  double* w;
} Fn;

/* the work buffers of f (from its work function); 0 if they could not be allocated */
int fn_new(Fn* fn, casadi_fn f, casadi_work_fn work);
void fn_free(Fn* fn);
/* f at three arguments into five results (unused ones NULL); nonzero if f failed */
int fn_call(Fn* fn, const double* a0, const double* a1, const double* a2, double* r0,
            double* r1, double* r2, double* r3, double* r4);

#endif
