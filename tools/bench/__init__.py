"""Benchmarks: commands that measure and print figures (tests never assert timings), one module each.

``sim`` (simulator robot-steps/s), ``ennc`` (ENNC against k-means, and phase 1 on many tuples), ``phase1`` (the
learner's phase 1 against its store size), ``actor`` (an actor's phase-2 slice against the bare simulator),
``transport`` (actor processes into the learner's store, with its :mod:`~tools.bench.publisher` processes) and
``broadcast`` (a policy broadcast against its prototype count); :mod:`~ennc_ql.bench` is ``ennc-ql bench``.
Nothing is imported here: a publisher process loads only what it needs.
"""
