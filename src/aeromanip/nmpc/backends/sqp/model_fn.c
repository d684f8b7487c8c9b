/*
 * A CasADi-generated Function called from C through its symbols (model_fn.h).
 */
#include "model_fn.h"

#include <stdlib.h>

int fn_new(Fn* fn, casadi_fn f, casadi_work_fn work) {
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

void fn_free(Fn* fn) {
  free(fn->arg);
  free(fn->res);
  free(fn->iw);
  free(fn->w);
}

int fn_call(Fn* fn, const double* a0, const double* a1, const double* a2, double* r0,
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
