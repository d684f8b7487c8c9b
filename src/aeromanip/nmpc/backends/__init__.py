"""NLP solver backends, registered by name: ``ipopt``, ``fatrop``, ``sqp``, ``sqp-rti``."""

from aeromanip.nmpc.backends.base import BACKENDS, Backend, NlpResult, make_backend

__all__ = ["BACKENDS", "Backend", "NlpResult", "make_backend"]
