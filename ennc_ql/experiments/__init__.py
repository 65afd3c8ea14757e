"""Experiments: many learning processes, each tested on the same seeded trials, and their results in one folder.

``reproduce`` (the paper's Figures 5 and 6) and ``ablate`` (one method under a sweep of overrides) are the commands,
one module each, over :mod:`~ennc_ql.experiments.jobs` (the learning processes, one at a time or on workers) and
:func:`~ennc_ql.experiments.results.write_results` (the one way both leave their results).
"""
