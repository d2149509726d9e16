"""Studies: study files, the runner and ``summary.json``.

- :mod:`~prp3mc.study.reader` — the TOML study file: parsing and validation with line numbers.
- :mod:`~prp3mc.study.results` — what a run returns: StudyResult, ConfigurationResult, PoseSamples.
- :mod:`~prp3mc.study.runner` — running a study's analyses.
- :mod:`~prp3mc.study.summary` — the summary statistics that users pin in CI.

Imports uncertainty, kinematics and the foundations; never measurement or reports.
"""
