"""The paper's four quantitative criteria, for both classification problems.

1. accuracy in a ten-fold (stratified) cross-validation on `n` examples: mean and spread;
2. accuracy against the number of training examples (20 .. 380), tested on the rest of the
   `n` examples, averaged over `repeats` random draws;
3. training time (fit on all `n`);
4. classification time per sample;
plus model size as the readability measure.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from sklearn.model_selection import StratifiedKFold

from cell.study.data import Dataset
from cell.study.methods import METHODS, fresh, model_size


@dataclass(frozen=True)
class Budget:
    n: int = 400
    folds: int = 10
    sizes: tuple[int, ...] = tuple(range(20, 381, 40)) + (380,)
    repeats: int = 5
    timing_fits: int = 3  # training time = the fastest of this many fits

    @classmethod
    def named(cls, name: str) -> Budget:
        if name == "full":
            return cls()
        if name == "tiny":
            return cls(n=40, folds=3, sizes=(20,), repeats=1, timing_fits=1)
        raise ValueError(name)


@dataclass
class ProblemResult:
    dataset: Dataset
    cv: dict[str, list[float]] = field(default_factory=dict)  # method -> per-fold accuracy
    curve: dict[str, dict[int, list[float]]] = field(default_factory=dict)  # method -> n_train -> accs
    train_ms: dict[str, float] = field(default_factory=dict)
    classify_us: dict[str, float] = field(default_factory=dict)  # per sample
    size: dict[str, tuple[int, str]] = field(default_factory=dict)
    models: dict[str, object] = field(default_factory=dict)  # fitted on all n (for the rules shown)

    def cv_mean(self, m: str) -> float:
        return float(np.mean(self.cv[m]))

    def cv_std(self, m: str) -> float:
        return float(np.std(self.cv[m], ddof=1)) if len(self.cv[m]) > 1 else 0.0


def _accuracy(model, X, y) -> float:
    return float(np.mean(np.asarray(model.predict(X)).astype(bool) == y))


def run_problem(ds: Dataset, budget: Budget, seed: int = 0,
                progress: Callable[[str], None] | None = None) -> ProblemResult:
    say = progress or (lambda s: None)
    X, y = ds.X, ds.y
    res = ProblemResult(ds)
    methods = list(METHODS)
    skf = StratifiedKFold(n_splits=budget.folds, shuffle=True, random_state=seed)
    for i, m in enumerate(methods):
        accs = []
        for tr, te in skf.split(X, y):
            accs.append(_accuracy(fresh(m).fit(X[tr], y[tr]), X[te], y[te]))
        res.cv[m] = accs
        say(f"{ds.name}: cross-validation {i + 1}/{len(methods)} {m}: {np.mean(accs):.3f}")
    rng = np.random.default_rng(seed)
    sizes = [s for s in budget.sizes if s < len(y) - 1]
    draws = {s: [_stratified_draw(y, s, rng) for _ in range(budget.repeats)] for s in sizes}
    for i, m in enumerate(methods):
        res.curve[m] = {}
        for s in sizes:
            accs = []
            for tr in draws[s]:
                te = np.setdiff1d(np.arange(len(y)), tr)
                accs.append(_accuracy(fresh(m).fit(X[tr], y[tr]), X[te], y[te]))
            res.curve[m][s] = accs
        say(f"{ds.name}: learning curve {i + 1}/{len(methods)} {m}")
    for m in methods:
        fits = []
        for _ in range(budget.timing_fits):
            t0 = time.perf_counter()
            model = fresh(m).fit(X, y)
            fits.append(time.perf_counter() - t0)
        res.train_ms[m] = 1e3 * min(fits)
        reps, t0 = 0, time.perf_counter()
        while True:  # classify the whole set until 50 ms have passed: per-sample time
            model.predict(X)
            reps += 1
            if time.perf_counter() - t0 > 0.05:
                break
        res.classify_us[m] = 1e6 * (time.perf_counter() - t0) / (reps * len(y))
        res.size[m] = model_size(model, X.shape[1])
        res.models[m] = model
    say(f"{ds.name}: timing and model size done")
    return res


def _stratified_draw(y: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n training indices with both classes present (half each where possible)."""
    pos, neg = np.flatnonzero(y), np.flatnonzero(~y)
    k = min(max(1, n // 2), len(pos))
    return np.concatenate([rng.choice(pos, k, replace=False), rng.choice(neg, n - k, replace=False)])
