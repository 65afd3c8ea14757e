"""The ENNC-QL algorithm, free of any process or transport: ENNC and its operators, ENNC-QL phase 1, VQQL,
discretizations, Q tables and the phase-2 tabular agent, experience tuples, policies and the policy file, the
learning-trial driver, and the conversions to and from wire messages.

Acting never loads torch: only :mod:`algorithm.ennc` (and :mod:`algorithm.phase1`, which fits ENNC) import it.
``from algorithm import ENNC`` works and imports torch at that moment.
"""

from typing import Any

__all__ = ["ENNC"]


def __getattr__(name: str) -> Any:
    # PEP 562: the estimator (and with it torch) is loaded on first use, not by `import algorithm`.
    if name == "ENNC":
        from algorithm.ennc import ENNC

        return ENNC
    raise AttributeError(f"module 'algorithm' has no attribute {name!r}")
