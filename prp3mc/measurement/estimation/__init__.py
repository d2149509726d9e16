"""The likelihood fit of a campaign: nuisances, effects on the exact chain, gross errors.

- :mod:`~prp3mc.measurement.estimation.nuisance` — registration and drift of the instrument.
- :mod:`~prp3mc.measurement.estimation.relinearise` — the exact chain linearised about an estimate (Gauss-Newton).
- :mod:`~prp3mc.measurement.estimation.likelihood` — the likelihood engine (fits with and without effects, the repeatable fraction).
- :mod:`~prp3mc.measurement.estimation.cyclic` — a cyclic screw error's amplitude interval (covers near 0).
- :mod:`~prp3mc.measurement.estimation.outliers` — gross errors at a stated family-wise false-alarm rate.
- :mod:`~prp3mc.measurement.estimation.testable` — the repeatable fraction's entry, and what the campaign cannot test.
"""
