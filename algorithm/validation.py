"""Check ENNC against scikit-learn's 1-NN on the classification data sets that ship with scikit-learn.

1-NN keeps every training pattern; ENNC should come close to its accuracy with far fewer prototypes. Each data
set is split by stratified k-fold with a fixed seed, features are standardised on the training fold, and the
figures are means over the folds.

Usage::

    from algorithm.validation import compare_with_1nn

    records = compare_with_1nn(["iris", "wine"], n_splits=5)
    [(r.dataset, r.ennc_accuracy, r.knn_accuracy, r.n_prototypes) for r in records]
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sklearn import datasets as sk_datasets
from sklearn.model_selection import StratifiedKFold
from sklearn.neighbors import KNeighborsClassifier
from sklearn.preprocessing import StandardScaler

from algorithm.ennc import ENNC

logger = logging.getLogger(__name__)

#: Data sets bundled with scikit-learn (no download needed), smallest first.
DATASETS = ("iris", "wine", "breast_cancer", "digits")


@dataclass(frozen=True)
class ValidationRecord:
    """Mean test-fold figures of ENNC and 1-NN on one data set."""

    dataset: str
    ennc_accuracy: float
    """ENNC accuracy on the test folds, mean over folds."""
    knn_accuracy: float
    """1-NN (all training patterns) accuracy on the test folds, mean over folds."""
    n_prototypes: float
    """ENNC prototypes at the end of training, mean over folds."""
    n_train: float
    """Training patterns per fold, mean over folds."""
    n_folds: int


def compare_with_1nn(
    datasets: Sequence[str] = DATASETS,
    n_splits: int = 5,
    random_state: int = 0,
    ennc_params: Mapping[str, Any] | None = None,
) -> list[ValidationRecord]:
    """Stratified ``n_splits``-fold comparison of ENNC with ``KNeighborsClassifier(n_neighbors=1)``.

    ``random_state`` seeds the fold split; fold k fits ENNC with ``random_state + k`` unless
    ``ennc_params`` (extra :class:`ENNC` constructor arguments) gives one.
    """
    params = dict(ennc_params or {})
    records = []
    for name in datasets:
        if name not in DATASETS:
            raise ValueError(f"unknown data set {name!r}; choose from {DATASETS}")
        X, y = getattr(sk_datasets, f"load_{name}")(return_X_y=True)
        folds = StratifiedKFold(n_splits=n_splits, shuffle=True, random_state=random_state).split(X, y)
        ennc_acc, knn_acc, n_protos, n_train = [], [], [], []
        for k, (train, test) in enumerate(folds):
            scaler = StandardScaler().fit(X[train])
            x_train, x_test = scaler.transform(X[train]), scaler.transform(X[test])
            ennc = ENNC(**{"random_state": random_state + k, **params}).fit(x_train, y[train])
            knn = KNeighborsClassifier(n_neighbors=1).fit(x_train, y[train])
            ennc_acc.append(ennc.score(x_test, y[test]))
            knn_acc.append(float(knn.score(x_test, y[test])))
            n_protos.append(ennc.n_prototypes_)
            n_train.append(len(train))
        record = ValidationRecord(
            dataset=name,
            ennc_accuracy=float(np.mean(ennc_acc)),
            knn_accuracy=float(np.mean(knn_acc)),
            n_prototypes=float(np.mean(n_protos)),
            n_train=float(np.mean(n_train)),
            n_folds=n_splits,
        )
        logger.info("%s", record)
        records.append(record)
    return records
