"""The Riccati interior point (``ocp_ipm``): random OCP-structured QPs against an
active-set solver (qpOASES through CasADi) on the same QP assembled whole, its
multipliers against an independent KKT check, and the SQP's steps and closed loop
against HPIPM's.
"""

from __future__ import annotations

import logging
import os

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.c_library import entry_of
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.sqp import ocp_ipm
from aeromanip.nmpc.backends.sqp.ocp_ipm import RiccatiQp
from aeromanip.nmpc.backends.sqp.solver import SqpBackend
from aeromanip.nmpc.strategies import Weighted
from nmpc_helpers import X0, rest

pytestmark = pytest.mark.codegen  # the solver is compiled C

TOL = 1e-9  # residual tolerance asked of the solver here (rounding floors it near 1e-10)


def random_ocp(N, nx, nu, nc, ncT, seed, equalities=0.1):
    """A random convex OCP QP, feasible by construction: a double-integrator-like ``A``,
    ``B`` (sparse, as the model's), dense positive definite Hessian blocks; the bounds
    placed around a trajectory of the dynamics (some active at the optimum, some
    equalities, some infinite)."""
    rng = np.random.default_rng(seed)
    nv, h = nx + nu, nx // 2
    A, B = np.eye(nx), np.zeros((nx, nu))
    for i in range(min(h, nu)):
        A[i, h + i], B[i, i], B[h + i, i] = 0.1, 0.005, 0.1
    blocks = []
    for w in [nv] * N + [nx]:
        G = rng.normal(size=(w + 2, w))
        blocks.append(G.T @ G / w + 1e-3 * np.eye(w))
    b, x0 = 0.01 * rng.normal(size=N * nx), 0.1 * rng.normal(size=nx)
    y = np.zeros(N * nv + nx)  # a trajectory of the dynamics
    y[:nx] = x0
    for k in range(N):
        y[k * nv + nx : (k + 1) * nv] = 0.3 * rng.normal(size=nu)
        nxt = (
            A @ y[k * nv : k * nv + nx]
            + B @ y[k * nv + nx : (k + 1) * nv]
            + b[k * nx : (k + 1) * nx]
        )
        y[(k + 1) * nv : (k + 1) * nv + nx] = nxt
    C = rng.normal(size=N * nc * nv + ncT * nx)
    q = {"dims": (N, nx, nu, nc, ncT), "A": A, "B": B, "blocks": blocks,
         "H": np.concatenate([blk.ravel() for blk in blocks]), "g": 3.0 * rng.normal(size=y.size),
         "b": b, "C": C, "x0": x0}  # fmt: skip
    Cy = np.concatenate([stage_rows(q, k)[1] @ y[stage_rows(q, k)[0]] for k in range(N + 1)])
    lg, ug = Cy - rng.uniform(0.0, 0.5, Cy.size), Cy + rng.uniform(0.0, 0.5, Cy.size)
    eq = rng.random(Cy.size) < equalities
    lg[eq] = ug[eq] = Cy[eq]
    lg[(rng.random(Cy.size) < 0.3) & ~eq] = -np.inf
    lb, ub = y - rng.uniform(0.0, 1.0, y.size), y + rng.uniform(0.0, 1.0, y.size)
    ub[rng.random(y.size) < 0.3] = np.inf
    q.update(lg=lg, ug=ug, lb=lb, ub=ub)
    return q


def stage_rows(q, k):
    """Stage ``k``'s slice of the variables, its row block and its rows' bounds."""
    N, nx, nu, nc, ncT = q["dims"]
    nv, w, m = nx + nu, nx + nu if k < N else nx, nc if k < N else ncT
    C = q["C"][k * nc * nv : k * nc * nv + m * w].reshape(m, w)
    rows = slice(k * nc, k * nc + m)
    lg, ug = (q[key][rows] if key in q else None for key in ("lg", "ug"))
    return slice(k * nv, k * nv + w), C, lg, ug


def assembled(q):
    """The QP assembled whole: Hessian, gradient, rows and their bounds, variable bounds."""
    N, nx, nu, _, _ = q["dims"]
    nv = nx + nu
    n = N * nv + nx
    H, rows, lo, hi = np.zeros((n, n)), [], [], []
    for k, block in enumerate(q["blocks"]):
        s = slice(k * nv, k * nv + block.shape[0])
        H[s, s] = block
    for k in range(N):
        row = np.zeros((nx, n))
        row[:, k * nv : k * nv + nx], row[:, k * nv + nx : (k + 1) * nv] = -q["A"], -q["B"]
        row[:, (k + 1) * nv : (k + 1) * nv + nx] = np.eye(nx)
        rows.append(row), lo.append(q["b"][k * nx : (k + 1) * nx]), hi.append(lo[-1])
    for k in range(N + 1):
        s, C, lg, ug = stage_rows(q, k)
        block = np.zeros((C.shape[0], n))
        block[:, s] = C
        rows.append(block), lo.append(lg), hi.append(ug)
    lb, ub = q["lb"].copy(), q["ub"].copy()
    lb[:nx] = ub[:nx] = q["x0"]
    return H, q["g"], np.vstack(rows), np.concatenate(lo), np.concatenate(hi), lb, ub


def reference(q):
    """qpOASES (an active-set method) on the assembled QP: the answer to compare with."""
    H, g, A, lba, uba, lbx, ubx = assembled(q)
    qp = {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()}
    solver = ca.conic("reference", "qpoases", qp, {"printLevel": "none", "error_on_fail": True})
    sol = solver(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
    return np.asarray(sol["x"]).ravel()


def kkt_errors(q, sol):
    """Stationarity, feasibility and complementarity of ``sol`` (CasADi's convention:
    ``H y + g + A' lam_a + lam_x = 0``), from the assembled QP."""
    H, g, A, lba, uba, lbx, ubx = assembled(q)
    N, nx, _, nc, ncT = q["dims"]
    lam_a = np.concatenate([sol.lam_dyn, *[sol.lam_c[k * nc : k * nc + (nc if k < N else ncT)]
                                           for k in range(N + 1)]])  # fmt: skip
    y, Ay = sol.y, A @ sol.y
    stationarity = np.abs(H @ y + g + A.T @ lam_a + sol.lam_y).max()
    feasibility = max(np.max(lba - Ay), np.max(Ay - uba), np.max(lbx - y), np.max(y - ubx))

    def slack(value, lo, hi, lam):  # a multiplier pushes only on the bound its sign names
        at = np.where(lam > 0, hi - value, value - lo)
        return np.max(np.abs(lam) * np.where(np.isfinite(at), at, np.inf), initial=0.0)

    free = np.ones(y.size, dtype=bool)
    free[:nx] = False  # x0 is pinned: any multiplier
    complementarity = max(slack(Ay, lba, uba, lam_a), slack(y[free], lbx[free], ubx[free],
                                                              sol.lam_y[free]))  # fmt: skip
    return stationarity, feasibility, complementarity


def solve(q, tol=TOL, iter_max=50):
    qp = RiccatiQp.create(q["dims"], q["A"], q["B"], tol, iter_max)
    assert qp is not None, "the solver's C library did not build"
    return qp.solve(q["H"], q["g"], q["b"], q["C"], (q["lg"], q["ug"]), (q["lb"], q["ub"]),
                    q["x0"])  # fmt: skip


@pytest.mark.parametrize(
    "dims, seed",
    [((1, 2, 1, 1, 0), 0), ((4, 4, 2, 2, 1), 1), ((10, 6, 3, 4, 2), 2), ((25, 8, 3, 5, 3), 3),
     ((12, 18, 7, 10, 3), 4)],
)  # fmt: skip
def test_random_ocp_qps_match_an_active_set_solver(dims, seed):
    q = random_ocp(*dims, seed)
    sol = solve(q)
    assert sol.status == "solved" and sol.usable
    y_ref = reference(q)
    np.testing.assert_allclose(sol.y, y_ref, atol=1e-6 * (1 + np.abs(y_ref).max()))
    stationarity, feasibility, complementarity = kkt_errors(q, sol)
    assert stationarity < 1e-7 and feasibility < 1e-8 and complementarity < 1e-7


def test_without_inequalities_one_newton_step_solves_it():
    """An equality-constrained QP (dynamics only) is one Riccati solve."""
    q = random_ocp(8, 4, 2, 2, 1, 5)
    for key in ("lg", "lb"):
        q[key][:] = -np.inf
    for key in ("ug", "ub"):
        q[key][:] = np.inf
    sol = solve(q)
    assert sol.status == "solved" and sol.iterations == 1
    np.testing.assert_allclose(sol.y, reference(q), atol=1e-9)


def test_a_qp_not_convex_on_the_inputs_is_not_usable():
    q = random_ocp(5, 4, 2, 2, 1, 6)
    N, nx, nu, _, _ = q["dims"]
    nv = nx + nu
    H = q["H"][: N * nv * nv].reshape(N, nv, nv)
    H[2, nx:, nx:] -= 50.0 * np.eye(nu)  # the inputs' curvature negative at stage 2
    sol = solve(q)
    assert sol.status == "not convex" and not sol.usable


def test_iterations_are_capped():
    sol = solve(random_ocp(10, 6, 3, 4, 2, 2), iter_max=2)
    assert sol.status == "maximum iterations" and sol.iterations == 2


# --- in the SQP: the sparse model's steps and a closed loop, against HPIPM ----------------


def _strategy(problem, qpsol):
    return Weighted(problem, "sqp", {"codegen": False, "qpsol": qpsol, "seed": "none"})


def test_the_sparse_models_qp_step_equals_hpipms(small_problem):
    """One SQP step of the flight problem from rest: the same step and multipliers."""
    steps = {}
    for qpsol in ("riccati", "hpipm"):
        strat = _strategy(small_problem, qpsol)
        tr, model = strat.transcription, strat.solvers[0].backend.model
        assert isinstance(model.qp, RiccatiQp) == (qpsol == "riccati")
        p = tr.parameters(X0, np.zeros(7), small_problem.stage_params(0.0))
        v, lam_c, lam_v = model.start(
            SolveRequest(tr.pack(*rest(small_problem), np.zeros(7)), p, tr.lbg, tr.ubg)
        )
        lin = model.linearize(v, p)
        steps[qpsol] = model.step(v, lin, lam_c, lam_v, p, exact=False)
    ours, hpipm = steps["riccati"], steps["hpipm"]
    assert ours.ok and hpipm.ok
    scale = 1 + np.abs(hpipm.d).max()
    np.testing.assert_allclose(ours.d, hpipm.d, atol=1e-6 * scale)
    np.testing.assert_allclose(ours.lam_a, hpipm.lam_a, atol=1e-5 * (1 + np.abs(hpipm.lam_a).max()))


def test_auto_beyond_the_condensing_limit_takes_the_riccati_solver(small_problem):
    opts = {"codegen": False, "seed": "none", "condense_max_horizon": 1}
    model = Weighted(small_problem, "sqp", opts).solvers[0].backend.model
    assert isinstance(model.qp, RiccatiQp)


def test_riccati_takes_no_qp_options():
    with pytest.raises(
        ConfigError,
        match=r"^solver_options.qpsol_options: hpipm: qpsol 'riccati' takes no options",
    ):
        SqpBackend.checked_options({"qpsol": "riccati", "qpsol_options": {"hpipm": {}}})


def test_without_a_compiler_the_sparse_model_uses_hpipm(monkeypatch, small_problem):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    model = _strategy(small_problem, "riccati").solvers[0].backend.model
    assert not isinstance(model.qp, RiccatiQp)


def test_a_damaged_library_is_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    assert ocp_ipm.riccati_library() is not None
    import shutil

    path = entry_of(ocp_ipm.SPEC, shutil.which("gcc")).lib
    cut = path.with_suffix(".cut")
    cut.write_bytes(path.read_bytes()[:100])
    os.replace(cut, path)  # truncated (a new file: the loaded one stays mapped)
    assert not CacheEntry(path).valid()
    assert ocp_ipm.riccati_library() is not None and CacheEntry(path).valid()


def test_a_build_failure_is_one_warning(monkeypatch, tmp_path, caplog):
    from dataclasses import replace

    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    for name in ocp_ipm.SPEC.sources:
        (tmp_path / name).write_text("this is not C\n")
    (tmp_path / "ocp_ipm.h").write_text("\n")
    monkeypatch.setattr(ocp_ipm, "SPEC", replace(ocp_ipm.SPEC, directory=tmp_path))
    with caplog.at_level(logging.WARNING):
        assert ocp_ipm.riccati_library() is None
    assert "building the Riccati QP solver failed" in caplog.text


@pytest.mark.parametrize(
    ("strategy", "backend"), [("weighted", "sqp"), ("hierarchical", "sqp-rti")]
)
def test_a_closed_loop_commands_as_with_hpipm(strategy, backend, monkeypatch):
    """The flight at N = 20 (kinematic), eight steps from rest: each command within 2e-6
    of the same loop's with HPIPM (both interior points stop at residuals of 1e-8, the
    RTI's too; the loops drift apart by ~6e-8 a step)."""
    from aeromanip.experiment.scenario import load_scenarios
    from aeromanip.nmpc.backends.sqp.hpipm import HPIPM_LIMITS
    from aeromanip.nmpc.controller import Controller

    monkeypatch.setitem(HPIPM_LIMITS, "rti", (1e-8, HPIPM_LIMITS["rti"][1]))

    sets = ["sim='kinematic'", "controller.horizon=20", "controller.dt=0.25",
            "controller.weights_dt=0.5", f"controller.strategy='{strategy}'",
            "duration=3"]  # fmt: skip
    sc = load_scenarios("flight", sets)[""]
    hierarchy = sc.hierarchy if strategy == "hierarchical" else None
    commands = {}
    for qpsol in ("riccati", "hpipm"):
        ctrl = Controller(sc.problem, strategy, backend, {"qpsol": qpsol}, hierarchy=hierarchy)
        x, U = sc.x0.copy(), []
        for k in range(8):
            cmd = ctrl.step(x, k * sc.problem.dt)
            assert cmd.status == "ok", cmd.message
            U.append(cmd.u)
            x = x + sc.problem.dt * cmd.u
        commands[qpsol] = np.array(U)
    assert np.abs(commands["riccati"]).max() > 0.05  # it flies
    np.testing.assert_allclose(commands["riccati"], commands["hpipm"], atol=2e-6)
