"""Tolerance allocation: the least-cost classes that keep the pose error within a spec.

- :mod:`~prp3mc.allocation.optimum` — :func:`allocate`, :class:`AllocationResult` and the
  cost-accuracy front, the public entry.
- :mod:`~prp3mc.allocation.classes` — the menu of classes (the classes file).
- :mod:`~prp3mc.allocation.search` — the exact branch-and-bound search on the batched envelope.

Imports Monte Carlo and the worst case (to confirm and report), the model, kinematics and the foundations.
"""
