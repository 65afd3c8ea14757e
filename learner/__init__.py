"""Learning algorithms of ENNC-QL."""

from learner.ennc import ENNC

__all__ = ["ENNC"]
