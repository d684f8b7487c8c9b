"""The NMPC: problem, transcription, constraints, strategies, controller, backends.

Data flow: ``Problem`` (tasks, weights, levels, constraints) -> ``Transcription`` (one
NLP per level) -> strategy (``Weighted`` | ``Hierarchical``) -> backend -> ``Controller``.
"""
