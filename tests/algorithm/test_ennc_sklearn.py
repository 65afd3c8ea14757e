"""ENNC as a scikit-learn estimator: scikit-learn's own estimator checks, then ENNC inside the tools built on the
estimator contract (Pipeline, cross_val_score, GridSearchCV, clone) on the iris data set."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import pytest
from sklearn.base import BaseEstimator, clone
from sklearn.datasets import load_iris
from sklearn.exceptions import NotFittedError
from sklearn.model_selection import GridSearchCV, cross_val_score, train_test_split
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.utils import get_tags
from sklearn.utils.estimator_checks import parametrize_with_checks

from algorithm.ennc import ENNC

# Few cycles keep the ~55 checks at a few seconds; one torch thread avoids the waits of parallel ops on busy
# cores (see ENNC's n_threads). The second instance covers the other initialisation and the newborn grace.
CHECKED = [
    ENNC(n_cycles=20, random_state=0, n_threads=1),
    ENNC(n_cycles=20, k_fight=1, init="mean", newborn_grace=True, random_state=0, n_threads=1),
]


# No expected failure is declared: every check must pass.
@parametrize_with_checks(CHECKED)
def test_sklearn_estimator_checks(
    estimator: BaseEstimator, check: Callable[[BaseEstimator], None], monkeypatch: pytest.MonkeyPatch
) -> None:
    # scikit-learn refuses to turn its array API dispatch on without scipy's flag and skips its NumPy-only
    # array API check otherwise; that check passes NumPy arrays only, so scipy's mode plays no part in it.
    monkeypatch.setenv("SCIPY_ARRAY_API", "1")
    check(estimator)


def test_a_continuous_target_is_refused_as_by_any_classifier() -> None:
    X = np.random.default_rng(0).normal(size=(40, 2))
    q_values = np.round(np.random.default_rng(1).normal(size=40), 3)  # 40 distinct floats: "continuous"
    with pytest.raises(ValueError, match="Unknown label type: continuous"):
        ENNC(n_cycles=5).fit(X, q_values)
    with pytest.raises(ValueError, match="Unknown label type: continuous"):
        ENNC(n_cycles=0).fit(X, (q_values > 0).astype(int), init_prototypes=X[:2], init_labels=[0.5, 1.0])


def iris_pipeline(**ennc_params: object) -> Pipeline:
    params = {"n_cycles": 50, "random_state": 0, "n_threads": 1, **ennc_params}
    return Pipeline([("scale", StandardScaler()), ("ennc", ENNC(**params))])  # type: ignore[arg-type]


def test_pipeline_fits_and_scores_iris_with_few_prototypes() -> None:
    X, y = load_iris(return_X_y=True)
    X_train, X_test, y_train, y_test = train_test_split(X, y, test_size=0.3, stratify=y, random_state=0)
    pipe = iris_pipeline().fit(X_train, y_train)
    assert pipe.score(X_test, y_test) > 0.85
    ennc = pipe.named_steps["ennc"]
    assert ennc.classes_.tolist() == [0, 1, 2]
    assert ennc.n_features_in_ == 4
    assert 3 <= ennc.n_prototypes_ <= 0.25 * len(X_train)


def test_cross_val_score_of_the_pipeline_on_iris() -> None:
    X, y = load_iris(return_X_y=True)
    scores = cross_val_score(iris_pipeline(), X, y, cv=5)
    assert scores.shape == (5,)
    assert scores.mean() > 0.85
    assert scores.min() > 0.7


def test_grid_search_over_n_cycles_prefers_evolving_over_the_single_start_prototype() -> None:
    X, y = load_iris(return_X_y=True)
    search = GridSearchCV(iris_pipeline(), {"ennc__n_cycles": [0, 40]}, cv=3).fit(X, y)
    # Zero cycles leave the single starting prototype, which predicts one class of three.
    assert search.best_params_ == {"ennc__n_cycles": 40}
    assert search.best_score_ > 0.85
    assert search.cv_results_["mean_test_score"][0] < 0.4
    assert search.best_estimator_.named_steps["ennc"].n_cycles_run_ == 40


def test_grid_search_over_k_fight_picks_a_grid_value() -> None:
    X, y = load_iris(return_X_y=True)
    search = GridSearchCV(iris_pipeline(n_cycles=30), {"ennc__k_fight": [1, 3]}, cv=3).fit(X, y)
    assert search.best_params_["ennc__k_fight"] in (1, 3)
    assert search.best_score_ > 0.85


def test_clone_keeps_the_parameters_and_drops_the_fit() -> None:
    X, y = load_iris(return_X_y=True)
    fitted = ENNC(n_cycles=7, k_fight=2, init="mean", newborn_grace=True, chunk_rows=64, random_state=4).fit(X, y)
    copy = clone(fitted)
    assert copy.get_params() == fitted.get_params()
    assert copy.get_params()["chunk_rows"] == 64 and copy.get_params()["init"] == "mean"
    with pytest.raises(NotFittedError):
        copy.predict_index(X)
    np.testing.assert_array_equal(clone(fitted).fit(X, y).prototypes_, fitted.prototypes_)


def test_set_params_through_the_pipeline() -> None:
    pipe = iris_pipeline().set_params(ennc__k_fight=1, ennc__n_cycles=3)
    assert pipe.named_steps["ennc"].k_fight == 1 and pipe.named_steps["ennc"].n_cycles == 3


def test_integer_valued_float_classes_fit_and_score() -> None:
    rng = np.random.default_rng(2)
    X = np.vstack([rng.normal(-3, 0.5, (30, 2)), rng.normal(3, 0.5, (30, 2))])
    y = np.repeat([2.0, -1.0], 30)  # rewards such as CMOMMT's are classes, not a continuous target
    clf = ENNC(n_cycles=20, random_state=0, n_threads=1).fit(X, y)
    assert clf.classes_.tolist() == [-1.0, 2.0]
    flipped = y.copy()
    flipped[:6] = -1.0
    assert clf.score(X, y) == 1.0
    assert clf.score(X, flipped) == pytest.approx(0.9)
    weights = np.r_[np.full(6, 3.0), np.ones(54)]
    assert clf.score(X, flipped, sample_weight=weights) == pytest.approx(54 / 72)
    assert cross_val_score(ENNC(n_cycles=20, random_state=0, n_threads=1), X, y, cv=3).min() == 1.0


def test_string_classes_and_a_warm_start_of_the_same_kind() -> None:
    X, y = load_iris(return_X_y=True)
    names = np.array(["setosa", "versicolor", "virginica"])[y]
    clf = ENNC(n_cycles=30, random_state=0, n_threads=1).fit(X, names)
    assert clf.classes_.tolist() == ["setosa", "versicolor", "virginica"]
    assert clf.score(X, names) > 0.85
    refit = ENNC(n_cycles=0).fit(X, names, init_prototypes=clf.prototypes_, init_labels=clf.labels_)
    np.testing.assert_array_equal(refit.predict(X), clf.predict(X))
    with pytest.raises(ValueError, match="both be numeric or both not"):
        ENNC(n_cycles=0).fit(X, names, init_prototypes=X[:1], init_labels=[1])


def test_a_random_state_instance_seeds_the_fit() -> None:
    X, y = load_iris(return_X_y=True)
    a = ENNC(n_cycles=20, random_state=np.random.RandomState(5), n_threads=1).fit(X, y)
    b = ENNC(n_cycles=20, random_state=np.random.RandomState(5), n_threads=1).fit(X, y)
    np.testing.assert_array_equal(a.prototypes_, b.prototypes_)
    assert a.n_prototypes_history_ == b.n_prototypes_history_


def test_tags_declare_cuda_fits_non_deterministic() -> None:
    assert get_tags(ENNC()).non_deterministic is False
    assert get_tags(ENNC(device="cuda:0")).non_deterministic is True
    assert get_tags(ENNC()).estimator_type == "classifier"


def test_read_only_input_is_accepted_without_warnings() -> None:
    X, y = load_iris(return_X_y=True)
    X.setflags(write=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clf = ENNC(n_cycles=5, random_state=0, n_threads=1).fit(X, y)
        assert clf.predict_index(X).shape == (150,)


def test_a_fit_that_fails_on_its_warm_start_leaves_the_estimator_unfitted() -> None:
    X, y = load_iris(return_X_y=True)
    clf = ENNC(n_cycles=1)
    with pytest.raises(ValueError, match="init_prototypes has 2 features, X has 4"):
        clf.fit(X, y, init_prototypes=X[:3, :2])
    with pytest.raises(NotFittedError):
        clf.predict(X)
