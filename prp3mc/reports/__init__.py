"""Reports: figures and self-contained HTML reports built from result objects.

- :mod:`~prp3mc.reports.plots` — figures of results; every function takes ``ax=`` and returns the Figure.
- :mod:`~prp3mc.reports.sweep_plots` — a design sweep's figures of merit against its parameters.
- :mod:`~prp3mc.reports.study_report` — a study's report folder.
- :mod:`~prp3mc.reports.discrepancy_report` — a discrepancy analysis's report folder.
- :mod:`~prp3mc.reports.canvas` — the figure reports draw on (Agg, matplotlib's constrained layout), ticks, wrapping.

The only wing that imports matplotlib (lazily, and never switches the backend).
"""
