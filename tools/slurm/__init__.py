"""SLURM: training runs as batch jobs and sweeps as job arrays, on any SLURM cluster.

By role: :mod:`~tools.slurm.sbatch` (the client commands, sbatch options), :mod:`~tools.slurm.allocation` (the
job's nodes and addresses, where each process goes, ``srun``), :mod:`~tools.slurm.job` (a training run's folder
and job script, and the job's own side, on the process topology of :mod:`tools.cluster`),
:mod:`~tools.slurm.array` (a sweep's learning processes as one job array, and one task's side); its command is
:mod:`ennc_ql.slurm` (``ennc-ql slurm``). docs/guide/slurm.md is the user's guide.
"""
