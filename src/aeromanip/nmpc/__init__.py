"""The NMPC: problem, transcription, constraints, strategies, controller, backends.

Data flow: ``Problem`` (tasks, weights, levels, constraints) -> ``Transcription`` (one
NLP per level) -> strategy (``Weighted`` | ``Hierarchical``) -> backend -> ``Controller``.

Exports:

* ``Problem`` (tasks by weight and level, constraints, horizon), ``Bounds``,
  ``Clearance``, ``PathConstraint``, ``UserConstraint``;
* ``Controller`` (``step(state, t) -> Command``), ``Command``;
* ``Transcription`` (the NLP of a level), the strategies ``Weighted`` and
  ``Hierarchical``, their results ``StrategyResult`` and ``LevelReport``;
* ``RateModel`` (the first-order rate response in the prediction model);
* backends: the base ``Backend``, its result ``NlpResult``, the registry ``BACKENDS`` and
  ``make_backend``; the built-ins ``IpoptBackend`` (``"ipopt"``), ``FatropBackend``
  (``"fatrop"``), ``SqpBackend`` (``"sqp"``) and ``SqpRtiBackend`` (``"sqp-rti"``),
  imported on first use.
"""

from __future__ import annotations

from aeromanip.nmpc.backends import BACKENDS, Backend, NlpResult, make_backend
from aeromanip.nmpc.constraints import Bounds, Clearance, PathConstraint, UserConstraint
from aeromanip.nmpc.controller import Command, Controller
from aeromanip.nmpc.model import RateModel
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, LevelReport, StrategyResult, Weighted
from aeromanip.nmpc.transcription import Transcription
from aeromanip.registry import lazy_exports

# the built-in backends' modules build solvers: imported when first named
_LAZY = {
    "IpoptBackend": "aeromanip.nmpc.backends.nlpsol",
    "FatropBackend": "aeromanip.nmpc.backends.nlpsol",
    "SqpBackend": "aeromanip.nmpc.backends.sqp.solver",
    "SqpRtiBackend": "aeromanip.nmpc.backends.sqp.solver",
}

__all__ = [
    "BACKENDS",
    "Backend",
    "Bounds",
    "Clearance",
    "Command",
    "Controller",
    "FatropBackend",
    "Hierarchical",
    "IpoptBackend",
    "LevelReport",
    "NlpResult",
    "PathConstraint",
    "Problem",
    "RateModel",
    "SqpBackend",
    "SqpRtiBackend",
    "StrategyResult",
    "Transcription",
    "UserConstraint",
    "Weighted",
    "make_backend",
]


__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
