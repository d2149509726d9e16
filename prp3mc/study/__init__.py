"""Studies: study files, the runner and ``summary.json``.

- :mod:`~prp3mc.study.reader` — the TOML study file: parsing and validation with line numbers.
- :mod:`~prp3mc.study.results` — what a run returns: StudyResult, ConfigurationResult, PoseSamples.
- :mod:`~prp3mc.study.sweep` — the ``[sweep]`` table: expansion, naming, the design-space frame.
- :mod:`~prp3mc.study.runner` — running a study's analyses, one task per configuration.
- :mod:`~prp3mc.study.distributed` — those tasks on a Dask cluster (the only module importing Dask).
- :mod:`~prp3mc.study.summary` — the summary statistics that users pin in CI.

Imports the methods, the model, kinematics and the foundations; never measurement or reports.
"""
