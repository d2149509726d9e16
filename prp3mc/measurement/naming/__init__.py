"""Which effects a campaign shows: naming them, their aliases, and what it cannot tell apart.

- :mod:`~prp3mc.measurement.naming.named` — :class:`NamedEffect`, an effect the workflow added to the model.
- :mod:`~prp3mc.measurement.naming.subsets` — best subsets and alias sets of systematic effects.
- :mod:`~prp3mc.measurement.naming.selection` — naming effects with exchange moves, aliases.
- :mod:`~prp3mc.measurement.naming.identify` — gross errors and names, relinearised until stable; the linearity guard.
- :mod:`~prp3mc.measurement.naming.confounds` — what a campaign cannot tell apart (``confounded``).
"""
