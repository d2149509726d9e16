"""Measurement: campaigns of measured poses and the discrepancy workflow.

- :mod:`~prp3mc.measurement.campaign` — reading and validating campaign CSV files.
- :mod:`~prp3mc.measurement.simulate` — simulated campaigns with hidden effects (exact chain).
- :mod:`~prp3mc.measurement.effects` — the effect library and its signatures.
- :mod:`~prp3mc.measurement.prediction` — the predicted distribution of every measurement.
- :mod:`~prp3mc.measurement.likelihood` — the likelihood engine (fits with and without effects).
- :mod:`~prp3mc.measurement.diagnostics` — the gap and the lack-of-fit diagnoses.
- :mod:`~prp3mc.measurement.selection` — naming effects, aliases, results.
- :mod:`~prp3mc.measurement.workflow` — :func:`discrepancy`, the whole workflow.

Imports uncertainty, kinematics and the foundations; never study or reports.
"""
