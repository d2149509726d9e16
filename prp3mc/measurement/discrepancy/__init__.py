"""The discrepancy workflow end to end and what it writes.

- :mod:`~prp3mc.measurement.discrepancy.workflow` — :func:`discrepancy`, the whole pipeline.
- :mod:`~prp3mc.measurement.discrepancy.results` — :class:`DiscrepancyResult`.
- :mod:`~prp3mc.measurement.discrepancy.updated` — the updated model and what a controller can compensate.
- :mod:`~prp3mc.measurement.discrepancy.accuracy` — predicted accuracy: original, updated, compensated.
"""
