"""Classifiers: accuracy on separable synthetic shapes, proper probabilities, the numba kernel,
serialisation without pickle, and errors."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from activetouch.errors import ConfigError, DataError
from activetouch.recognition.classifiers import (
    CLASSIFIER_NAMES,
    LinearSVMClassifier,
    NearestNeighbourClassifier,
    classifier_from_arrays,
    fit_platt,
    make_classifier,
)
from activetouch.recognition.histogram import HistogramSpec
from activetouch.recognition.kernels import (
    KIND_LINEAR_OVR,
    KIND_NN_INNER,
    KIND_NN_INTERSECTION,
    ClassifierKernel,
    kernel_proba,
)
from activetouch.recognition.synthetic import synthetic_grasp
from activetouch.recognition.training import grasp_triangles, partial_histograms

SHAPES = ("sphere_small", "sphere_large", "box_long")
CONTACTS = (4, 8)


def _grasps(shape: str, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return grasp_triangles([synthetic_grasp(shape, rng, CONTACTS, reach_m=None) for _ in range(n)])


@pytest.fixture(scope="module")
def data() -> dict[str, object]:
    rng = np.random.default_rng(0)
    train = [_grasps(s, rng, 40) for s in SHAPES]
    spec = HistogramSpec.fit(np.vstack([t for obj in train for t in obj]))
    H, y = partial_histograms(train, spec, 100, 1, 10, rng)
    # Test set: raw counts of 3 fresh random grasps per histogram.
    test_H, test_y = [], []
    for k, s in enumerate(SHAPES):
        for _ in range(60):
            test_H.append(spec.counts(np.vstack(_grasps(s, rng, 3))))
            test_y.append(k)
    return {"spec": spec, "H": H, "y": y, "test_H": np.array(test_H), "test_y": np.array(test_y)}


@pytest.fixture(scope="module")
def fitted(data: dict) -> dict[str, object]:
    return {name: make_classifier(name).fit(data["H"], data["y"]) for name in CLASSIFIER_NAMES}


def _kernel_proba(k: ClassifierKernel, h: np.ndarray) -> np.ndarray:
    return kernel_proba(
        k.kind, k.W, k.b, k.row_class, k.platt_a, k.platt_b, k.temperature, k.n_classes, h
    )


@pytest.mark.parametrize(("name", "min_acc"), [("svm", 0.95), ("nn_inner", 0.95)])
def test_three_grasps_classified(data: dict, fitted: dict, name: str, min_acc: float) -> None:
    P = fitted[name].proba_many(data["test_H"])
    acc = float((P.argmax(axis=1) == data["test_y"]).mean())
    assert acc >= min_acc, f"{name}: accuracy {acc:.3f} on 3-grasp histograms"


def test_intersection_better_than_chance(data: dict, fitted: dict) -> None:
    P = fitted["nn_intersection"].proba_many(data["test_H"])
    assert (P.argmax(axis=1) == data["test_y"]).mean() >= 0.9


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("name", CLASSIFIER_NAMES)
def test_probabilities_and_kernel(data: dict, fitted: dict, name: str) -> None:
    clf = fitted[name]
    k = clf.kernel()
    D = data["spec"].n_bins
    assert clf.n_classes == 3 and k.n_classes == 3 and k.W.shape == (3, D)
    assert k.kind == {"svm": 0, "nn_inner": 1, "nn_intersection": 2}[name]
    zero = np.zeros(D)
    dense = np.random.default_rng(5).random(D)
    # Tiny and huge entries: their squares under/overflow, the probabilities must not change.
    extreme = [1e-170 * data["test_H"][0], 1e170 * data["test_H"][0]]
    rows = [zero, dense, *data["test_H"][::7], data["H"][0], *extreme]
    P = clf.proba_many(np.array(rows))
    np.testing.assert_allclose(P.sum(axis=1), 1.0, atol=1e-12)
    assert (P >= 0).all()
    np.testing.assert_allclose(P[0], 1 / 3, atol=1e-15)
    for i, h in enumerate(rows):
        p = clf.proba(h)
        assert p.shape == (3,)
        np.testing.assert_allclose(p, P[i], atol=1e-12)
        np.testing.assert_allclose(_kernel_proba(k, h), p, atol=1e-9, rtol=0)
        np.testing.assert_allclose(k.proba(h), p, atol=1e-9, rtol=0)
        # Raw counts and normalised histograms are the same evidence.
        np.testing.assert_allclose(clf.proba(5.0 * h), p, atol=1e-12)
    for h in extreme:
        np.testing.assert_allclose(clf.proba(h), clf.proba(data["test_H"][0]), atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    h=arrays(
        np.float64, 1000, elements=st.one_of(st.just(0.0), st.floats(0, 50, allow_subnormal=False))
    ),
    name=st.sampled_from(CLASSIFIER_NAMES),
)
# Found in CI: the smallest normal float as the only count (a / total overflowed in the SVM).
@example(h=np.eye(1, 1000)[0] * np.finfo(np.float64).tiny, name="svm")
def test_any_histogram_gives_a_distribution(fitted: dict, h: np.ndarray, name: str) -> None:
    clf = fitted[name]
    p = clf.proba(h)
    assert np.isfinite(p).all() and (p >= 0).all()
    assert abs(p.sum() - 1.0) < 1e-12
    np.testing.assert_allclose(_kernel_proba(clf.kernel(), h), p, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", CLASSIFIER_NAMES)
def test_arrays_round_trip_without_pickle(data: dict, fitted: dict, name: str) -> None:
    clf = fitted[name]
    arrays_ = clf.to_arrays()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in arrays_.values())
    scalars = {k: v.item() for k, v in arrays_.items() if v.ndim == 0}
    json.dumps(scalars)  # every 0-d entry is a JSON-able scalar
    buf = io.BytesIO()
    np.savez(buf, **arrays_)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as z:
        loaded = {k: z[k] for k in z.files}
    for back in (type(clf).from_arrays(loaded), classifier_from_arrays(loaded)):
        assert type(back) is type(clf) and back.n_classes == clf.n_classes
        np.testing.assert_array_equal(
            back.proba_many(data["test_H"]), clf.proba_many(data["test_H"])
        )


def test_from_arrays_rejects_bad_data(fitted: dict) -> None:
    good = fitted["svm"].to_arrays()
    with pytest.raises(DataError, match="format version"):
        LinearSVMClassifier.from_arrays({**good, "format_version": np.array(99)})
    with pytest.raises(DataError, match="lack"):
        LinearSVMClassifier.from_arrays({k: v for k, v in good.items() if k != "W"})
    with pytest.raises(DataError, match="shape"):
        LinearSVMClassifier.from_arrays({**good, "b": np.zeros(7)})
    with pytest.raises(DataError, match="not 'nn_inner'"):
        NearestNeighbourClassifier.from_arrays(
            {**good, "metric": np.array("inner"), "temperature_folds": np.array(5)}
        )
    with pytest.raises(DataError, match="unknown classifier"):
        classifier_from_arrays({**good, "classifier": np.array("forest")})
    with pytest.raises(DataError, match="NaN"):
        LinearSVMClassifier.from_arrays({**good, "W": good["W"] * np.nan})


def test_several_rows_per_class(fitted: dict, data: dict) -> None:
    """Kernels with more rows than classes (e.g. several templates per class) agree too."""
    for name in CLASSIFIER_NAMES:
        a = fitted[name].to_arrays()
        a["W"] = np.vstack([a["W"], a["W"][::-1] * 0.5 + 0.5 * a["W"]])
        for key in ("b", "platt_a", "platt_b"):
            a[key] = np.concatenate([a[key], a[key][::-1]])
        if name != "svm":
            # NN rows must keep the norm the kind expects (unit L2 / unit L1).
            W = a["W"]
            norm = np.linalg.norm(W, axis=1) if name == "nn_inner" else W.sum(axis=1)
            a["W"] = W / norm[:, None]
        a["row_class"] = np.array([0, 1, 2, 2, 1, 0])
        clf = classifier_from_arrays(a)
        k = clf.kernel()
        for h in [np.zeros(1000), *data["test_H"][::11]]:
            p = clf.proba(h)
            assert abs(p.sum() - 1) < 1e-12
            np.testing.assert_allclose(_kernel_proba(k, h), p, atol=1e-9, rtol=0)
            np.testing.assert_allclose(clf.proba_many(h[None, :])[0], p, atol=1e-12)


def test_two_classes(data: dict) -> None:
    two = data["y"] < 2
    svm = LinearSVMClassifier().fit(data["H"][two], data["y"][two])
    k = svm.kernel()
    assert k.W.shape[0] == 2 and k.n_classes == 2
    np.testing.assert_array_equal(k.W[0], -k.W[1])  # sklearn's single binary vector, both signs
    sel = data["test_y"] < 2
    P = svm.proba_many(data["test_H"][sel])
    assert (P.argmax(axis=1) == data["test_y"][sel]).mean() >= 0.95
    for h in data["test_H"][sel][::9]:
        np.testing.assert_allclose(_kernel_proba(k, h), svm.proba(h), atol=1e-9, rtol=0)


def test_svm_agrees_with_its_decision_function(data: dict, fitted: dict) -> None:
    svm = fitted["svm"]
    S = svm.decision_function(data["test_H"])
    k = svm.kernel()
    assert (k.platt_a < 0).all()  # higher score -> higher probability
    P = svm.proba_many(data["test_H"])
    assert (S.argmax(axis=1) == P.argmax(axis=1)).mean() > 0.95


def test_nn_temperature_and_templates(fitted: dict) -> None:
    for name in ("nn_inner", "nn_intersection"):
        clf = fitted[name]
        t = clf.kernel().temperature
        assert 1e-3 <= t <= 10
        T = clf.templates()
        np.testing.assert_allclose(T.sum(axis=1), 1.0)
        d = clf.distances(T[1])
        assert d.argmin() == 1 and d[1] == pytest.approx(0.0, abs=1e-12)


def test_fit_platt_recovers_a_sigmoid() -> None:
    rng = np.random.default_rng(3)
    s = rng.normal(size=4000)
    y = rng.random(4000) < 1.0 / (1.0 + np.exp(-3.0 * s + 0.5))
    a, c = fit_platt(s, y)
    assert a == pytest.approx(-3.0, abs=0.35) and c == pytest.approx(0.5, abs=0.2)


def test_fit_errors(data: dict) -> None:
    H, y = data["H"], data["y"]
    for name in CLASSIFIER_NAMES:
        clf = make_classifier(name)
        with pytest.raises(DataError, match="at least 2 classes"):
            clf.fit(H[y == 0], y[y == 0])
        with pytest.raises(DataError, match=r"classes \[1\]"):
            clf.fit(H[y != 1], y[y != 1])
        with pytest.raises(DataError, match="non-negative"):
            clf.fit(-H, y)
        with pytest.raises(DataError, match="integers"):
            clf.fit(H, y.astype(float))
        with pytest.raises(RuntimeError, match="not fitted"):
            clf.kernel()
    bad = H.copy()
    bad[0, 0] = np.nan
    with pytest.raises(DataError, match="finite"):
        LinearSVMClassifier().fit(bad, y)


def test_zero_training_rows_ignored(data: dict) -> None:
    H = np.vstack([data["H"], np.zeros((5, data["H"].shape[1]))])
    y = np.concatenate([data["y"], [0, 1, 2, 0, 1]])
    clf = NearestNeighbourClassifier("inner").fit(H, y)
    ref = NearestNeighbourClassifier("inner").fit(data["H"], data["y"])
    np.testing.assert_allclose(clf.kernel().W, ref.kernel().W)


def test_config_errors() -> None:
    with pytest.raises(ConfigError, match="unknown classifier"):
        make_classifier("forest")
    with pytest.raises(ConfigError, match="metric"):
        NearestNeighbourClassifier(metric="cosine")
    with pytest.raises(ConfigError):
        LinearSVMClassifier(C=0)
    assert {KIND_LINEAR_OVR, KIND_NN_INNER, KIND_NN_INTERSECTION} == {0, 1, 2}


def test_proba_shape_errors(fitted: dict) -> None:
    with pytest.raises(ValueError, match="shape"):
        fitted["svm"].proba(np.zeros(10))
    with pytest.raises(ValueError, match="shape"):
        fitted["nn_inner"].proba_many(np.zeros(1000))


def test_bench_smoke(tmp_path) -> None:
    from activetouch.recognition import bench

    out = tmp_path / "bench.json"
    assert bench.main(["--quick", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["n_bins"] == 1000 and figures["n_classes"] == 12
    for name in CLASSIFIER_NAMES:
        assert figures["us"][f"{name}.proba"] > 0 and figures["us"][f"{name}.kernel_proba"] > 0
