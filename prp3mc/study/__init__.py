"""Studies: study files, the runner and ``summary.json``.

- :mod:`~prp3mc.study.reader` — the TOML study file: parsing and validation with line numbers.
- :mod:`~prp3mc.study.runner` — running a study's analyses; its result classes.
- :mod:`~prp3mc.study.summary` — the summary statistics that users pin in CI.

Imports uncertainty, kinematics and the foundations; never measurement or reports.
"""
