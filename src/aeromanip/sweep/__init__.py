"""Parameter sweeps and Monte-Carlo campaigns of scenarios on Ray (``aeromanip sweep``).

``axes`` turns ``--grid`` / ``--random`` / ``--seeds`` into runs with stable ids;
``campaign`` checks them, compiles each distinct problem once, fans the runs out as Ray
tasks (``tasks``) into ``DIR/runs/<id>/`` and resumes what is missing; ``results`` writes
``DIR/results.csv``; ``campaign_plots`` draws each metric against each swept key and a Pareto plot.
Ray is imported only when a campaign starts (the ``sweep`` extra).

Exports:

* ``make_spec`` (grid, random draws, seeds -> ``SweepSpec``), ``Run``;
* ``plan_campaign`` (a scenario and a spec -> ``Plan``: every run built, nothing flown);
* ``run_campaign`` (a plan flown on Ray into a directory -> ``Outcome``), ``Settings``
  (workers, cluster address, figures...);
* ``read_results`` (``DIR/results.csv`` as rows), ``plot_sweep``.
"""

from __future__ import annotations

from aeromanip.registry import lazy_exports

# each import on first use: the campaign's plots load matplotlib
_LAZY = {
    "Run": "aeromanip.sweep.axes",
    "SweepSpec": "aeromanip.sweep.axes",
    "make_spec": "aeromanip.sweep.axes",
    "Plan": "aeromanip.sweep.plan",
    "plan_campaign": "aeromanip.sweep.plan",
    "Outcome": "aeromanip.sweep.campaign",
    "Settings": "aeromanip.sweep.campaign",
    "run_campaign": "aeromanip.sweep.campaign",
    "read_results": "aeromanip.sweep.results",
    "plot_sweep": "aeromanip.sweep.campaign_plots",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
