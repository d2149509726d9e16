"""What the model predicts a campaign shows.

- :mod:`~prp3mc.measurement.forward.signatures` — the effect library's signatures at the campaign's poses.
- :mod:`~prp3mc.measurement.forward.prediction` — the predicted distribution of every measurement.
"""
