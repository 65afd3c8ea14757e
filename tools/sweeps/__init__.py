"""Sweeps: many learning processes, each tested on the same seeded trials, and their results in one folder.

:mod:`~tools.sweeps.reproduce` (the paper's Figures 5 and 6) and :mod:`~tools.sweeps.ablate` (one method under a
sweep of overrides), over :mod:`~tools.sweeps.jobs` (the learning processes and the :class:`~tools.sweeps.jobs.Backend`
that runs them: here, one at a time or on workers, or :class:`tools.slurm.array.SlurmArray`) and
:func:`~tools.sweeps.results.write_results` (the one way both leave their results). :mod:`ennc_ql.sweeps` holds
their commands and chooses the backend once.
"""
