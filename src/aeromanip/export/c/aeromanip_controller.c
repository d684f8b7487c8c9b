/*
 * The exported controller (aeromanip_controller.h): the step of controller_step.c with
 * the scenario's configuration, am_config, generated in aeromanip_config.h.
 */
#include "aeromanip_controller.h"

#include "aeromanip_config.h"
#include "controller_step.h"

aeromanip_controller* aeromanip_init(void) {
  return (aeromanip_controller*)am_new(&am_config);
}

void aeromanip_free(aeromanip_controller* c) { am_free((AmController*)c); }

void aeromanip_reset(aeromanip_controller* c, const double* u_prev) {
  am_reset((AmController*)c, u_prev);
}

void aeromanip_discard(aeromanip_controller* c) { am_discard((AmController*)c); }

aeromanip_status aeromanip_step_rates(aeromanip_controller* c, const double* x,
                                      const double* rates, double t, aeromanip_output* out) {
  if (!c || !x || !out) return AEROMANIP_BAD_INPUT;
  AmOutput o = {out->u, out->plan_x, out->plan_u, 0, 0, 0, 0, 0.0};
  int status = am_step((AmController*)c, x, rates, t, &o);
  out->status = status;
  if (status == AM_BAD_INPUT) return AEROMANIP_BAD_INPUT; /* nothing else written */
  out->solver_status = o.solver_status;
  out->iterations = o.iterations;
  out->levels = o.levels;
  out->cost = o.cost;
  return (aeromanip_status)status;
}

aeromanip_status aeromanip_step(aeromanip_controller* c, const double* x, double t,
                                aeromanip_output* out) {
  return aeromanip_step_rates(c, x, 0, t, out);
}
