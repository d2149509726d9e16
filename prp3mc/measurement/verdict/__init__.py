"""Whether the named model explains the campaign: the tests, the verdict and the gap.

- :mod:`~prp3mc.measurement.verdict.diagnostics` — the tests, the one verdict and the gap.
- :mod:`~prp3mc.measurement.verdict.holdout` — the gap on poses left out of the fit.
- :mod:`~prp3mc.measurement.verdict.compare` — the diagnoses before and after, the gap; ISO 9283 measured and predicted.
"""
