"""NLP solver backends, registered by name: ``ipopt``, ``fatrop``, ``sqp``, ``sqp-rti``."""

from aeromanip.nmpc.backends.base import (
    BACKENDS,
    Backend,
    NlpResult,
    SolveRequest,
    make_backend,
)

__all__ = ["BACKENDS", "Backend", "NlpResult", "SolveRequest", "make_backend"]
