"""SLURM: training runs as batch jobs and sweeps as job arrays, on any SLURM cluster.

By role: :mod:`~ennc_ql.slurm.sbatch` (the client commands, sbatch options), :mod:`~ennc_ql.slurm.allocation` (the
job's nodes and addresses, where each process goes, ``srun``), :mod:`~ennc_ql.slurm.job` (a training run's folder
and job script, and the job's own side, on the process topology of :mod:`ennc_ql.cluster`),
:mod:`~ennc_ql.slurm.array` (a sweep's learning processes as one job array, and one task's side) and
:mod:`~ennc_ql.slurm.command` (``ennc-ql slurm``). docs/slurm.md is the user's guide.
"""
