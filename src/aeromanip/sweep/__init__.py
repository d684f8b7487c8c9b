"""Parameter sweeps and Monte-Carlo campaigns of scenarios on Ray (``aeromanip sweep``).

``spec`` turns ``--grid`` / ``--random`` / ``--seeds`` into runs with stable ids;
``campaign`` checks them, compiles each distinct problem once, fans the runs out as Ray
tasks (``tasks``) into ``DIR/runs/<id>/`` and resumes what is missing; ``results`` writes
``DIR/results.csv``; ``plots`` draws each metric against each swept key and a Pareto plot.
Ray is imported only when a campaign starts (the ``sweep`` extra).
"""
