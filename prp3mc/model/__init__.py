"""The error model: what can go wrong (laws, budgets, effects) and how it moves the pose, to first order.

- :mod:`~prp3mc.model.laws` — catalogue-style laws of single error inputs.
- :mod:`~prp3mc.model.catalogue` — named laws with their sources.
- :mod:`~prp3mc.model.budget` — error budgets: named inputs with laws, Sobol groups, ``[effects]``.
- :mod:`~prp3mc.model.copula` — a budget's ``[correlation]`` table as a Gaussian copula.
- :mod:`~prp3mc.model.effects` — the systematic effect library and a budget's ``[effects]`` table.
- :mod:`~prp3mc.model.linear` — the linear model of a budget at a batch of poses, and its exact moments.
- :mod:`~prp3mc.model.validity` — a cheap probe of the linear model against the exact chain.
- :mod:`~prp3mc.model.interop` — budgets and results handed to SALib, OpenTURNS and xarray.

Every method (:mod:`prp3mc.montecarlo`, :mod:`prp3mc.worstcase`, :mod:`prp3mc.sobol`,
:mod:`prp3mc.allocation`) stands on this package. Imports kinematics and the foundations only.
"""
