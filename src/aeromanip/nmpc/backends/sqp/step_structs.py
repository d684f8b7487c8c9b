"""The C structs of ``controller_step.h`` as ctypes mirrors: the compiled step's
configuration (``AmConfig``, ``AmLevel``), its memory (``AmState``, ``AmLevelState``,
``AmTried``) and a step's answer (``AmOutput``); their fields in the header's order."""

from __future__ import annotations

import ctypes

POINTER = ctypes.c_void_p  # an opaque pointer
DOUBLES = ctypes.POINTER(ctypes.c_double)
#: the step's outcomes (``controller_step.h``) -> the Python controller's status words
STEP_STATUS = {0: "ok", 1: "fallback", 2: "stopped", 3: "bad input", 4: "partial", 5: "host"}


class AmLevel(ctypes.Structure):
    """``AmLevel`` of ``controller_step.h``."""

    _fields_ = [
        ("dims", POINTER), ("hier_row", POINTER), ("always", POINTER), ("sizes", POINTER),
        ("n_sizes", ctypes.c_int), ("screen", ctypes.c_double), ("shift_rows", POINTER),
        ("pins", POINTER), ("n_pins", ctypes.c_int),
        ("data", POINTER), ("merit", POINTER), ("hess", POINTER), ("bounds", POINTER),
        ("data_work", POINTER), ("merit_work", POINTER), ("hess_work", POINTER),
        ("bounds_work", POINTER),
    ]  # fmt: skip


class AmConfig(ctypes.Structure):
    """``AmConfig`` of ``controller_step.h``."""

    _fields_ = [
        ("nx", ctypes.c_int), ("N", ctypes.c_int), ("nU", ctypes.c_int), ("np", ctypes.c_int),
        ("n_levels", ctypes.c_int), ("levels", ctypes.POINTER(AmLevel)),
        ("daqp", POINTER), ("constants", POINTER), ("opts", POINTER), ("shift_vars", POINTER),
        ("lbU", POINTER), ("ubU", POINTER), ("u_lower", POINTER), ("u_upper", POINTER),
        ("parameters", POINTER), ("plan", POINTER), ("parameters_work", POINTER),
        ("plan_work", POINTER),
        ("host_seeds", ctypes.c_int), ("seed_ratio", ctypes.c_double),
        ("seed_floor", ctypes.c_double),
    ]  # fmt: skip


class AmTried(ctypes.Structure):
    """``AmTried`` of ``controller_step.h``."""

    _fields_ = [
        ("U", DOUBLES), ("lam_c", DOUBLES), ("lam_u", DOUBLES), ("memory", DOUBLES),
        ("f", ctypes.c_double), ("seconds", ctypes.c_double), ("qp_excess", ctypes.c_double),
        ("status", ctypes.c_int), ("iterations", ctypes.c_int),
        ("qp_exitflag", ctypes.c_int), ("qp_finite", ctypes.c_int), ("valid", ctypes.c_int),
    ]  # fmt: skip


class AmLevelState(ctypes.Structure):
    """``AmLevelState`` of ``controller_step.h``."""

    _fields_ = [
        ("U", DOUBLES), ("lam_c", DOUBLES), ("lam_u", DOUBLES), ("memory", DOUBLES),
        ("lbc", DOUBLES), ("ubc", DOUBLES), ("f", ctypes.c_double), ("warm", ctypes.c_int),
        ("status", ctypes.c_int), ("iterations", ctypes.c_int), ("seconds", ctypes.c_double),
        ("qp_exitflag", ctypes.c_int), ("qp_finite", ctypes.c_int),
        ("qp_excess", ctypes.c_double), ("tried", AmTried),
    ]  # fmt: skip


class AmState(ctypes.Structure):
    """``AmState`` of ``controller_step.h``."""

    _fields_ = [
        ("u_prev", DOUBLES), ("p", DOUBLES), ("first", DOUBLES), ("plan_x", DOUBLES),
        ("plan_u", DOUBLES), ("has_plan", ctypes.c_int), ("plan_age", ctypes.c_int),
        ("has_first", ctypes.c_int),
    ]  # fmt: skip


class AmOutput(ctypes.Structure):
    """``AmOutput`` of ``controller_step.h``."""

    _fields_ = [
        ("u", DOUBLES), ("plan_x", DOUBLES), ("plan_u", DOUBLES),
        ("status", ctypes.c_int), ("solver_status", ctypes.c_int),
        ("iterations", ctypes.c_int), ("levels", ctypes.c_int), ("cost", ctypes.c_double),
    ]  # fmt: skip
