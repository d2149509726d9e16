"""Measurement: campaigns of measured poses, and the discrepancy workflow that fits them.

- :mod:`prp3mc.measurement.campaign` — the data: reading and validating campaign files,
  simulating campaigns on the exact chain, ISO 9283 accuracy and repeatability, planning a campaign.
- The discrepancy workflow, one package per step, each importing only those above it:

  - :mod:`prp3mc.measurement.forward` — what the model predicts a campaign shows (effect signatures,
    the predicted distribution of every measurement);
  - :mod:`prp3mc.measurement.estimation` — the likelihood fit: nuisances, the engine relinearised on
    the exact chain, a cyclic error's interval, gross errors;
  - :mod:`prp3mc.measurement.naming` — which effects the campaign shows, their aliases, confounds;
  - :mod:`prp3mc.measurement.verdict` — the tests, the verdict and the held-out gap;
  - :mod:`prp3mc.measurement.discrepancy` — :func:`~prp3mc.measurement.discrepancy.workflow.discrepancy`,
    its result, the updated model and the predicted accuracy.

Imports the methods, the model, kinematics and the foundations; never study or reports.
"""
