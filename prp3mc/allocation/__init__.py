"""Tolerance allocation: the least-cost classes that keep the pose error within a spec.

- :mod:`~prp3mc.allocation.optimum` — :func:`allocate`, :class:`AllocationResult` and the
  cost-accuracy front, the public entry.
- :mod:`~prp3mc.allocation.classes` — the menu of classes (the classes file).
- :mod:`~prp3mc.allocation.search` — the exact branch-and-bound search on the batched envelope.
- :mod:`~prp3mc.allocation.percentile` — the percentile spec: decided on the exact distribution
  (Monte Carlo for a correlated budget), searched along the normal screen, proven on small menus.

Imports the exact yield engine (stackup), Monte Carlo and the worst case (to decide, confirm and report), the
model, kinematics and the foundations.
"""
