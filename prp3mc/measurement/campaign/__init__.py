"""Campaign data: what was measured, and campaigns simulated with hidden effects.

- :mod:`~prp3mc.measurement.campaign.data` — reading and validating campaign CSV files (:class:`Campaign`).
- :mod:`~prp3mc.measurement.campaign.simulate` — simulated campaigns on the exact nonlinear chain.
- :mod:`~prp3mc.measurement.campaign.iso9283` — ISO 9283 pose accuracy and repeatability.
- :mod:`~prp3mc.measurement.campaign.plan` — planning a campaign: D-optimal poses, interleaved visits, directions.
"""
