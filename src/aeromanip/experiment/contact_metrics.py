"""Force regulation metrics of a contact run, from its log columns alone.

With a set normal force (``f_ref``, logged by a force task) and the true normal force
(``f_n``) and contact flag (``contact``) of the physics simulator:

- the **set phase**: the rows where the set force is at its largest (within
  ``PLATEAU_TOLERANCE``), e.g. pressing and sliding at 2 N, less the first ``SETTLE_S``
  after it is reached (the press building up to it); ``force_set_s`` its first and last
  row's times [s];
- ``force_rmse_n``: the RMS of ``f_n - f_ref`` over the set phase [N];
- ``force_contact_share``: the share of the set phase's rows in contact;
- ``f_n_first_touch_peak_n``: the largest ``f_n`` within ``FIRST_TOUCH_S`` of the first
  row in contact [N] (NaN: never in contact), and ``first_touch_s`` that row's time;
- ``f_ref_max_n``: the largest set force [N];
- with the surface's outward normal (the run's ``meta.json``: ``surface_normals``, the
  first surface), ``ee_tangential_rmse_m``: the RMS of the EE's error to its reference
  in the surface's plane over the set phase [m] (along the normal the force rules).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

PLATEAU_TOLERANCE = 1e-3  # relative: a set force within this of its largest is "set"
FIRST_TOUCH_S = 2.0  # [s] the window after the first contact where its peak is taken
SETTLE_S = 1.0  # [s] the start of the set force's plateau left out of the set phase


def force_metrics(
    columns: Mapping[str, np.ndarray], normal: Sequence[float] | None = None
) -> dict[str, Any]:
    """The metrics of the module docstring (``normal``: the surface's, for the tangential
    error); empty without ``f_ref``, ``f_n``, ``contact`` and ``t`` columns or without a
    positive set force."""
    if not all(k in columns for k in ("t", "f_ref", "f_n", "contact")):
        return {}
    t, f_ref = np.asarray(columns["t"], float), np.asarray(columns["f_ref"], float)
    f_n, contact = np.asarray(columns["f_n"], float), np.asarray(columns["contact"], float)
    if len(t) == 0 or not np.nanmax(f_ref) > 0:
        return {}
    top = float(np.nanmax(f_ref))
    held = f_ref >= top * (1.0 - PLATEAU_TOLERANCE)
    held &= t >= t[held][0] + SETTLE_S - 1e-9
    if not held.any():
        return {"f_ref_max_n": top}
    out: dict[str, Any] = {
        "f_ref_max_n": top,
        "force_rmse_n": float(np.sqrt(np.nanmean((f_n[held] - f_ref[held]) ** 2))),
        "force_contact_share": float(np.nanmean(contact[held] > 0.5)),
        "force_set_s": [float(t[held][0]), float(t[held][-1])],
    }
    names = ("ee_x", "ee_y", "ee_z", "ref_x", "ref_y", "ref_z")
    if normal is not None and all(k in columns for k in names):
        n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
        err = np.column_stack([np.asarray(columns[k], float) for k in names[:3]])
        err -= np.column_stack([np.asarray(columns[k], float) for k in names[3:]])
        err -= np.outer(err @ n, n)  # in the surface's plane
        out["ee_tangential_rmse_m"] = float(np.sqrt(np.nanmean(np.sum(err[held] ** 2, axis=1))))
    touching = np.nonzero(contact > 0.5)[0]
    if touching.size == 0:
        out.update(first_touch_s=float("nan"), f_n_first_touch_peak_n=float("nan"))
        return out
    t0 = float(t[touching[0]])
    window = (t >= t0) & (t <= t0 + FIRST_TOUCH_S)
    out.update(first_touch_s=t0, f_n_first_touch_peak_n=float(np.nanmax(f_n[window])))
    return out
