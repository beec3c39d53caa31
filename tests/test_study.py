import json

import numpy as np
import pytest
from conftest import run_cli
from sklearn.utils.estimator_checks import parametrize_with_checks

from cell.study.data import point_dataset, set_dataset
from cell.study.methods import METHODS, RBFNetwork, fresh, model_size


def test_study_runs_on_a_tiny_budget_and_writes_the_report(tmp_path, capsys):
    out = tmp_path / "study"
    code, stdout, stderr = run_cli("study", "--budget", "tiny", "--out", out, capsys=capsys)
    assert code == 0
    assert "cross-validation" in stderr and "learning curve" in stderr  # progress while it runs
    from cell.study.report import OUTPUTS

    # OUTPUTS (the files `cell study` checks it can write before its minutes of work) is what it writes
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS)
    for f in ("report.md", "results.json", "cv_points.png", "cv_sets.png", "curve_points.png",
              "curve_sets.png", "times.png"):
        assert (out / f).stat().st_size > 0, f
        if f.endswith(".png"):
            assert (out / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = json.loads((out / "results.json").read_text())
    assert set(res["points"]["methods"]) == set(METHODS) == set(res["sets"]["methods"])
    for problem in ("points", "sets"):
        for m, r in res[problem]["methods"].items():
            assert len(r["cv_folds"]) == 3 and 0 <= r["cv_mean"] <= 1
            assert r["train_ms"] > 0 and r["classify_us"] > 0 and r["size"] > 0, m
    md = (out / "report.md").read_text()
    assert "| nearest neighbour |" in md and "Compared with the paper" in md
    assert "| method | points: CV accuracy |" in stdout


def test_bad_options_are_bad_input(tmp_path, capsys):
    code, _, err = run_cli("study", "--examples", "5", "--out", tmp_path, capsys=capsys)
    assert code == 2 and "--examples" in err


def test_labels_are_the_operators_judgement():
    ds = point_dataset(40, seed=5)
    assert ds.X.shape == (40, len(ds.feature_names)) and ds.y.sum() == 20
    assert ds.feature_names[0] == "dist_cog_mm" and 0 < ds.natural_valid_share < 1
    sets = set_dataset(40, seed=5)
    assert sets.X.shape[0] == 40 and sets.y.sum() == 20
    # a point far from the centre of gravity is never accepted (the operator's reach rule)
    from cell.operator import REACH_MM

    assert not np.any(ds.y & (ds.X[:, 0] > REACH_MM + 1e-6))


def test_methods_learn_a_simple_rule_and_report_sizes():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 3))
    y = (X[:, 0] > 0.2) | (X[:, 1] > 1.0)  # axis-aligned, so rules and trees can state it exactly
    for m in METHODS:
        model = fresh(m).fit(X[:150], y[:150])
        acc = np.mean(np.asarray(model.predict(X[150:])).astype(bool) == y[150:])
        assert acc > 0.75, m
        size, unit = model_size(model, 3)
        assert size > 0 and unit != "?"


@pytest.mark.parametrize("bad", [np.zeros((5, 2))])
def test_rbf_network_degenerate_input(bad):
    y = np.array([0, 1, 0, 1, 0])
    model = RBFNetwork(n_centres=4).fit(bad, y)  # all points equal: one centre, still predicts
    assert model.predict(bad).shape == (5,)


def test_label_noise_flips_the_asked_share(tmp_path, capsys):
    from cell.study.data import with_label_noise

    ds = point_dataset(200, seed=1)
    noisy = with_label_noise(ds, 0.2, seed=1)
    assert 0.1 < np.mean(noisy.y != ds.y) < 0.3 and np.array_equal(noisy.X, ds.X)
    assert with_label_noise(ds, 0.0) is ds
    code, _, err = run_cli("study", "--label-noise", "0.7", "--out", tmp_path, capsys=capsys)
    assert code == 2 and "--label-noise" in err
    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = run_cli("study", "--budget", "tiny", "--out", f, capsys=capsys)
    assert code == 2 and "not a folder" in err



@parametrize_with_checks([RBFNetwork(n_centres=5)])
def test_rbf_network_is_a_proper_scikit_learn_estimator(estimator, check):
    check(estimator)
