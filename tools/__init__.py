"""The libraries the ``ennc-ql`` commands use, beside ``learner/`` and ``actors/``; nothing here imports ``ennc_ql``.

By role: :mod:`~tools.cluster` (a run's process topology: the learner, the actors and a router as OS processes or on
one process, their endpoints, supervision and recording), :mod:`~tools.slurm` (that topology placed on a SLURM
allocation, and sweeps as job arrays), :mod:`~tools.chaos` (the fault suite), :mod:`~tools.bench` (the benchmarks),
:mod:`~tools.sweeps` (reproduce and ablate: many learning processes and their results), and what they share:
:mod:`~tools.config` (config dataclasses as flags and TOML), :mod:`~tools.secure` (a secure run's certificates and
configurations), :mod:`~tools.system` (signals, free ports, a child's death with its parent),
:mod:`~tools.progress` (the progress bar of the long runs on stderr) and :mod:`~tools.allocator` (glibc malloc
settings).
"""
