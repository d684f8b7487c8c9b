"""What the controller computes in Python before each solve, as CasADi Functions for C.

``Controller.step`` builds the solve's parameters (the start state, the tasks' references
over the horizon) and the condensed model's row bounds (``Transcription.variable_bounds``:
the state box, braking into the margin, widened to hold a recovery plan) with NumPy. An
exported controller computes the same in generated C: ``parameters_function`` states
the parameters as expressions of ``(x, u_prev, rates, t)``, ``bounds_function`` a level's row
bounds as expressions of the parameters, ``plan_function`` rolls a plan out, and
``ee_function`` gives the end effector's position (the example's error), and
``costs_function`` every task's cost at a plan (the compiled step's reports). The tests
check each against its NumPy twin.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel, condensed_variables
from aeromanip.nmpc.model import RateModel, _response_terms
from aeromanip.nmpc.transcription import Transcription


def _rates_of(model: RateModel, z: ca.SX) -> ca.SX:
    """``RateModel.rates_of`` as an expression."""
    nx = model.nx
    parts = [z[nx + i] for i in range(nx)]
    for j, i in enumerate(model.lagged):
        parts[int(i)] = z[2 * nx + j]
    return ca.vertcat(*parts)


def _reach(model: RateModel, z0: ca.SX, max_change: np.ndarray) -> ca.SX:
    """``RateModel.reach`` as an expression."""
    nx = model.nx
    u = ca.fabs(z0[nx : 2 * nx])
    m = ca.fmax(u, ca.fabs(_rates_of(model, z0)))
    n = ca.if_else(u > 0, ca.ceil(u / ca.DM(max_change)), 0.0)
    return m * (model.dt * (n + 1.0) + ca.DM(model.tau))


def _recovery(
    model: RateModel, z0: ca.SX, steps: int, max_change: np.ndarray, tr: Transcription
) -> list[ca.SX]:
    """``RateModel.recovery`` as expressions: the states ``x[1..steps]``."""
    b, nx = tr.problem.bounds, model.nx
    lo, hi, u_lo, u_hi = (ca.DM(v) for v in (b.x_lower, b.x_upper, b.u_lower, b.u_upper))
    a, c = (ca.DM(v) for v in _response_terms(model.tau, model.dt))
    gain = model.dt - c
    x, u, r = z0[:nx], z0[nx : 2 * nx], _rates_of(model, z0)
    change = ca.DM(max_change)
    out = []
    for _ in range(steps):
        base = x + c * r
        f_lo, f_hi = ca.fmax(u - change, u_lo), ca.fmin(u + change, u_hi)
        d_lo, d_hi = (lo - base) / gain, (hi - base) / gain
        lo_k, hi_k = ca.fmax(d_lo, f_lo), ca.fmin(d_hi, f_hi)
        inside = ca.fmin(ca.fmax(0.0, lo_k), hi_k)
        u = ca.if_else(lo_k <= hi_k, inside, ca.if_else(d_hi < f_lo, f_lo, f_hi))
        x = base + gain * u
        r = u + a * (r - u)
        out.append(x)
    return out


def _coast_bounds(tr: Transcription, z0: ca.SX) -> tuple[list[ca.SX], list[ca.SX]]:
    """The state bounds of stages ``1..N`` before any widening: the box, and near now
    where the vehicle would coast into the margin (``Bounds.return_bounds``)."""
    b, dt, N = tr.problem.bounds, tr.problem.dt, tr.N
    lows = [ca.SX(ca.DM(b.x_lower)) for _ in range(N)]
    highs = [ca.SX(ca.DM(b.x_upper)) for _ in range(N)]
    soft = min(N, math.ceil(b.margin_ramp / dt))
    if soft <= 0 or b.margin is None or b.margin_ramp <= 0:
        return lows, highs
    z, zero = z0, ca.DM.zeros(tr.nx)
    for k in range(1, soft + 1):
        z = tr.model.next_sx(z, zero)
        room = ca.DM(max(1.0 - dt * k / b.margin_ramp, 0.0) * np.asarray(b.margin))
        coast = z[: tr.nx]
        above = ca.fmin(ca.fmax(coast - ca.DM(b.x_upper), 0.0), room)
        below = ca.fmin(ca.fmax(ca.DM(b.x_lower) - coast, 0.0), room)
        lows[k - 1], highs[k - 1] = ca.DM(b.x_lower) - below, ca.DM(b.x_upper) + above
    return lows, highs


def state_bounds(tr: Transcription, z0: ca.SX) -> tuple[list[ca.SX], list[ca.SX]]:
    """``Transcription.variable_bounds`` of the states of stages ``1..N`` (each (nx,)),
    as expressions of the start ``z0``."""
    b, model = tr.problem.bounds, tr.model
    lows, highs = _coast_bounds(tr, z0)
    x0 = z0[: tr.nx]
    reach = _reach(model, z0, tr.max_change)
    out_low = ca.sum1(x0 - reach < ca.DM(b.x_lower))
    out_high = ca.sum1(x0 + reach > ca.DM(b.x_upper))
    near = out_low + out_high > 0
    brake = _recovery(model, z0, tr.N, tr.max_change, tr)
    lows = [ca.if_else(near, ca.fmin(lo, xb), lo) for lo, xb in zip(lows, brake, strict=True)]
    highs = [ca.if_else(near, ca.fmax(hi, xb), hi) for hi, xb in zip(highs, brake, strict=True)]
    return lows, highs


def start_state(
    tr: Transcription, x: ca.SX, u_prev: ca.SX, rates: ca.SX, latency_s: float
) -> ca.SX:
    """``Controller._start``'s ``z0``: the augmented state (the lagged DoFs' actual rates
    ``rates``), moved on by ``latency_s`` [s] under the last command."""
    model = tr.model
    z0 = ca.vertcat(x, u_prev, rates[model.lagged.tolist()])
    if latency_s <= 0:
        return z0
    A, B = model.matrices(latency_s)
    return ca.mtimes(ca.DM(A), z0) + ca.mtimes(ca.DM(B), u_prev)


def parameters_function(tr: Transcription, latency_s: float, name: str) -> ca.Function:
    """``name(x, u_prev, rates, t) -> p``: a solve's parameters at the time ``t`` [s] from
    the measured state ``x``, the command in flight ``u_prev`` and the actual rates
    ``rates`` (``Controller.step`` with ``latency_s`` [s]; only the lagged DoFs' rates
    count): the start state, then every task's references over the horizon."""
    nx, N, dt = tr.nx, tr.N, tr.problem.dt
    x, u_prev, t = ca.SX.sym("x", nx), ca.SX.sym("u_prev", nx), ca.SX.sym("t")
    rates = ca.SX.sym("rates", nx)
    z0 = start_state(tr, x, u_prev, rates, latency_s)
    t_plan = t + latency_s
    stage_params = []
    for k in range(N + 1):
        stage_params += [e.task.param_expression(t_plan + dt * k) for e in tr.problem.entries]
    p = ca.vertcat(z0, *stage_params)
    return ca.Function(name, [x, u_prev, rates, t], [p], ["x", "u_prev", "rates", "t"], ["p"])


def bounds_function(
    model: CondensedQpModel, lbg: np.ndarray, ubg: np.ndarray, name: str
) -> ca.Function:
    """``name(p) -> (lbc, ubc)``: the condensed model's row bounds of a solve with the
    parameters ``p`` (``CondensedQpModel.start`` with the NLP's row bounds ``lbg``,
    ``ubg``): its rows', then the states' (the box, braking, widened for a recovery)."""
    tr = model.tr
    p = ca.SX.sym("p", tr.p.numel())
    lows, highs = state_bounds(tr, p[: tr.nz])
    s = tr.stride
    lb_states = [lows[i // s - 1][i % s] for i in model.state_idx]
    ub_states = [highs[i // s - 1][i % s] for i in model.state_idx]
    lbc = ca.vertcat(ca.DM(lbg[model.keep]), *lb_states)
    ubc = ca.vertcat(ca.DM(ubg[model.keep]), *ub_states)
    return ca.Function(name, [p], [lbc, ubc], ["p"], ["lbc", "ubc"])


def plan_function(tr: Transcription, name: str) -> ca.Function:
    """``name(p, U) -> X``: the states (N+1 stages x nx, stage-major) of the commands
    ``U`` (N x nx, stage-major) from the start in ``p`` (``RateModel.rollout``)."""
    p, U = ca.SX.sym("p", tr.p.numel()), ca.SX.sym("U", tr.N * tr.nx)
    z, X = p[: tr.nz], []
    for k in range(tr.N + 1):
        X.append(z[: tr.nx])
        if k < tr.N:
            z = tr.model.next_sx(z, U[k * tr.nx : (k + 1) * tr.nx])
    return ca.Function(name, [p, U], [ca.vertcat(*X)], ["p", "U"], ["X"])


def ee_function(tr: Transcription, name: str) -> ca.Function:
    """``name(x) -> ee``: the end effector's position [m, world]."""
    x = ca.SX.sym("x", tr.nx)
    return ca.Function(name, [x], [tr.problem.kin.ee_position(x)], ["x"], ["ee"])


def reference_function(tr: Transcription, name: str) -> ca.Function:
    """``name(t) -> r``: the tracking task's reference [m] at ``t`` [s]."""
    t = ca.SX.sym("t")
    refs = [e.task.param_expression(t) for e in tr.problem.entries if e.name == "tracking"]
    return ca.Function(name, [t], [refs[0] if refs else ca.SX.zeros(3)], ["t"], ["r"])


def costs_function(model: CondensedQpModel, name: str) -> ca.Function:
    """``name(U, p) -> C``: every task's weighted cost over the horizon (``stage_costs``
    summed over the stages: ``Transcription.costs``) at the commands ``U`` from the start
    in ``p``."""
    tr = model.tr
    U, p = ca.SX.sym("U", model.nU), ca.SX.sym("p", tr.p.numel())
    C = model.sources[2](condensed_variables(tr, U, p), p)  # stage_costs, as generated
    return ca.Function(name, [U, p], [ca.sum2(C)], ["U", "p"], ["C"])
