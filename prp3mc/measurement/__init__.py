"""Measurement: campaigns of measured poses, and the discrepancy workflow that fits them.

- :mod:`prp3mc.measurement.campaign` — the data: reading and validating campaign files,
  simulating campaigns on the exact chain, ISO 9283 accuracy and repeatability, planning a campaign.
- :mod:`prp3mc.measurement.fit` — the fit: effect signatures, the predicted distribution,
  nuisances, the likelihood engine relinearised on the exact chain, gross errors, naming effects,
  confounds, the verdict, the
  held-out gap, the updated model and :func:`~prp3mc.measurement.fit.workflow.discrepancy`.

Imports the methods, the model, kinematics and the foundations; never study or reports.
"""
