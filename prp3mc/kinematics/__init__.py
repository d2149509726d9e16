"""Kinematics: the manipulator's geometry, its batched chain and first-order sensitivities.

- :mod:`~prp3mc.kinematics.geometry` — legs, strokes, presets and regions (mm, deg at the boundary).
- :mod:`~prp3mc.kinematics.chain` — inverse and exact forward kinematics, A, B, feasibility checks.
- :mod:`~prp3mc.kinematics.sensitivity` — H_q and J_q = A⁻¹H_q of the ten error families.
- :mod:`~prp3mc.kinematics.exact` — the exact perturbed closure, the oracle of the linear model.

Imports only the foundations (errors, _toml, units).
"""
