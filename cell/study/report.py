"""The study's outputs: a Markdown report and PNG plots in one folder, plus results.json."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cell.fileio import write_atomic, write_json_atomic
from cell.study.experiments import Budget, ProblemResult
from cell.study.methods import METHODS

TITLES = {"points": "contact points, local attributes (paper step 2)",
          "sets": "contact sets, global attributes (paper step 4)"}
# what write_report writes into its folder: checked before the study (minutes of work), not after
OUTPUTS = ("report.md", "results.json", "times.png", *(f"{kind}_{name}.png" for name in TITLES
                                                         for kind in ("cv", "curve")))


def _save(fig, path: Path) -> None:
    """savefig wrote the file in place (half a PNG when stopped part way, a read-only one overwritten)."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_atomic(path, buf.getvalue())


def _plots(res: ProblemResult, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    name = res.dataset.name
    files = []
    # 1. cross-validation, as the paper's Fig. 2 / 10: each method's fold accuracies fitted by a normal
    fig, ax = plt.subplots(figsize=(7, 4))
    xs = np.linspace(0.5, 1.05, 400)
    for m in METHODS:
        mu, sd = res.cv_mean(m), max(res.cv_std(m), 1e-3)
        ax.plot(100 * xs, np.exp(-0.5 * ((xs - mu) / sd) ** 2) / (sd * math.sqrt(2 * math.pi)) / 100,
                label=f"{m} ({100 * mu:.1f} ± {100 * sd:.1f})")
    ax.set_xlabel("correct classifications (%)")
    ax.set_ylabel("density (normal fit)")
    ax.set_title(f"{res.dataset.name}: {len(res.cv[next(iter(METHODS))])}-fold cross-validation, "
                 f"{len(res.dataset.y)} examples")
    ax.legend(fontsize=7)
    fig.tight_layout()
    f = f"cv_{name}.png"
    _save(fig, out / f)
    files.append(f)
    # 2. accuracy against the number of training examples (Fig. 3 / 11)
    fig, ax = plt.subplots(figsize=(7, 4))
    for m in METHODS:
        sizes = sorted(res.curve[m])
        ax.plot(sizes, [100 * np.mean(res.curve[m][s]) for s in sizes], marker="o", ms=3, label=m)
    ax.set_xlabel("training examples")
    ax.set_ylabel("correct classifications (%)")
    ax.set_title(f"{name}: accuracy against the number of training examples")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    f = f"curve_{name}.png"
    _save(fig, out / f)
    files.append(f)
    return files


def _time_plot(results: dict[str, ProblemResult], out: Path) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    methods = list(METHODS)
    w = 0.38
    for k, (name, res) in enumerate(results.items()):
        x = np.arange(len(methods)) + (k - 0.5) * w
        axs[0].bar(x, [res.train_ms[m] for m in methods], w, label=name)
        axs[1].bar(x, [res.classify_us[m] for m in methods], w, label=name)
    for ax, t in zip(axs, ("training time (ms, all examples)", "classification time (µs per sample)"), strict=True):
        ax.set_yscale("log")
        ax.set_title(t)
        ax.set_xticks(np.arange(len(methods)))
        ax.set_xticklabels([m.replace(" (RIPPER)", "\n(RIPPER)").replace(" ", "\n", 1) for m in methods], fontsize=7)
        ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, out / "times.png")
    return "times.png"


def headline_table(results: dict[str, ProblemResult]) -> str:
    lines = ["| method | points: CV accuracy | sets: CV accuracy | training (ms, points / sets) | "
             "classification (µs/sample, points / sets) | model size (points / sets) |",
             "|---|---:|---:|---:|---:|---|"]
    p, s = results["points"], results["sets"]
    for m in METHODS:
        lines.append(
            f"| {m} | {100 * p.cv_mean(m):.1f} ± {100 * p.cv_std(m):.1f} % | "
            f"{100 * s.cv_mean(m):.1f} ± {100 * s.cv_std(m):.1f} % | "
            f"{p.train_ms[m]:.1f} / {s.train_ms[m]:.1f} | {p.classify_us[m]:.2f} / {s.classify_us[m]:.2f} | "
            f"{p.size[m][0]} / {s.size[m][0]} {p.size[m][1].split(' (')[0]} |")
    return "\n".join(lines)


def _problem_table(res: ProblemResult) -> str:
    sizes = sorted(next(iter(res.curve.values())))
    shown = [s for s in (sizes[0], sizes[len(sizes) // 2], sizes[-1])] if sizes else []
    head = "| method | CV mean | CV spread (sd) | " + " | ".join(f"n = {s}" for s in shown) + \
        " | training ms | classification µs/sample | size |"
    lines = [head, "|---|" + "---:|" * (4 + len(shown)) + "---|"]
    for m in METHODS:
        cells = " | ".join(f"{100 * np.mean(res.curve[m][s]):.1f} %" for s in shown)
        lines.append(f"| {m} | {100 * res.cv_mean(m):.1f} % | {100 * res.cv_std(m):.1f} | {cells} | "
                     f"{res.train_ms[m]:.1f} | {res.classify_us[m]:.2f} | {res.size[m][0]} {res.size[m][1]} |")
    return "\n".join(lines)


def comparison_text(results: dict[str, ProblemResult]) -> str:
    """What the figures say about the paper's findings, stated from the figures themselves."""
    p, s = results["points"], results["sets"]
    out = []
    for name, r in (("points", p), ("sets", s)):
        ranked = sorted(METHODS, key=lambda m: -r.cv_mean(m))
        out.append(f"- **{name}**: ranking by cross-validated accuracy: " + ", ".join(
            f"{m} {100 * r.cv_mean(m):.1f} %" for m in ranked) + ".")
    nn = "nearest neighbour"
    for name, r in (("points", p), ("sets", s)):
        best = max(METHODS, key=lambda m: r.cv_mean(m))
        gap = r.cv_mean(best) - r.cv_mean(nn)
        verdict = "is the best method, as in the paper" if best == nn else (
            f"is {100 * gap:.1f} points behind the best ({best})" + (
                ", within one fold spread" if gap <= r.cv_std(nn) else ""))
        out.append(f"- Nearest neighbour on {name} {verdict}.")
    for name, r in (("points", p), ("sets", s)):
        tree = r.cv_mean("decision tree")
        best = max(r.cv_mean(m) for m in METHODS)
        out.append(f"- Decision tree on {name}: {100 * tree:.1f} % ({100 * (best - tree):.1f} points below the best) "
                   f"with {r.size['decision tree'][0]} nodes; RIPPER {100 * r.cv_mean('rule list (RIPPER)'):.1f} % "
                   f"with {r.size['rule list (RIPPER)'][0]} {r.size['rule list (RIPPER)'][1]}: the readable models "
                   f"{'stay close' if best - tree <= 0.05 else 'fall behind'}.")
    mp = np.mean([p.cv_mean(m) for m in METHODS])
    ms = np.mean([s.cv_mean(m) for m in METHODS])
    sz = [(m, p.size[m][0], s.size[m][0]) for m in ("decision tree", "rule list (RIPPER)")]
    out.append(f"- Global attributes (sets) vs local (points): mean accuracy over the six methods "
               f"{100 * ms:.1f} % vs {100 * mp:.1f} %; "
               + "; ".join(f"{m} size {b} vs {a}" for m, a, b in sz) + ". The paper found sets easier "
               "(higher accuracy, smaller trees and rule lists); "
               + ("the same holds here." if ms > mp and all(b < a for _, a, b in sz) else
                  "here the accuracy is higher on sets and the readable models are no larger." if ms > mp and all(
                      b <= a for _, a, b in sz) else "here that holds only in part (see the figures)."))
    nn_us = max(p.classify_us[nn], s.classify_us[nn])
    tree_us = max(p.classify_us["decision tree"], s.classify_us["decision tree"])
    out.append(f"- On-line cost: nearest neighbour classifies in {nn_us:.2f} µs/sample against "
               f"{tree_us:.2f} µs for the tree. The paper discarded nearest neighbour for its on-line time, "
               "linear in the number of examples; with a few hundred examples and a k-d tree it is still "
               "fast here, so the tree's case rests on readability (its rules can be printed: "
               "`cell rules`).")
    return "\n".join(out)


def write_report(results: dict[str, ProblemResult], out_dir: str | Path, budget: Budget, seed: int,
                 elapsed_s: float, label_noise: float = 0.0) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pngs = []
    for r in results.values():
        pngs += _plots(r, out)
    pngs.append(_time_plot(results, out))
    md = ["# Learning study: which classifier for grasp points and grasp sets?", "",
          f"Reproduces the comparison of the paper (sections 4.2 and 6.2) on data labelled by the simulated "
          f"operator. Budget: {budget.n} examples per problem, {budget.folds}-fold cross-validation, "
          f"training sizes {', '.join(map(str, budget.sizes))} ({budget.repeats} draws each), seed {seed}; "
          f"labels flipped at random: {100 * label_noise:.0f} %; run time {elapsed_s:.0f} s.", "",
          "## Headline", "", headline_table(results), "",
          "## Compared with the paper", "", comparison_text(results), ""]
    for name, r in results.items():
        ds = r.dataset
        md += [f"## {TITLES.get(name, name)}", "",
               f"{len(ds.y)} examples, class-balanced ({int(ds.y.sum())} accepted), drawn from {ds.n_parts} "
               f"library parts at random poses; before balancing the operator accepted "
               f"{100 * ds.natural_valid_share:.0f} % of the candidates. Attributes: "
               f"{', '.join(f'`{n}`' for n in ds.feature_names)}.", "",
               _problem_table(r), "",
               f"![cross-validation](cv_{name}.png)", "", f"![learning curve](curve_{name}.png)", ""]
        tree = r.models["decision tree"]
        from sklearn.tree import export_text

        md += ["Decision tree learned from all examples:", "", "```",
               export_text(tree, feature_names=list(ds.feature_names), decimals=2).rstrip(), "```", "",
               "RIPPER rule list (rejected when any rule fires, accepted otherwise):", "", "```",
               r.models["rule list (RIPPER)"].rules_text(list(ds.feature_names)).replace("] V [", "]\nOR [")[:4000],
               "```", ""]
    md += ["## Times", "", "![times](times.png)", ""]
    report = out / "report.md"
    write_atomic(report, "\n".join(md) + "\n")
    summary = {name: {"n": len(r.dataset.y), "natural_valid_share": r.dataset.natural_valid_share,
                      "methods": {m: {"cv_mean": r.cv_mean(m), "cv_std": r.cv_std(m), "cv_folds": r.cv[m],
                                      "curve": {str(k): v for k, v in r.curve[m].items()},
                                      "train_ms": r.train_ms[m], "classify_us": r.classify_us[m],
                                      "size": r.size[m][0], "size_unit": r.size[m][1]} for m in METHODS}}
               for name, r in results.items()}
    summary["budget"] = {"n": budget.n, "folds": budget.folds, "sizes": list(budget.sizes),
                         "repeats": budget.repeats, "seed": seed, "label_noise": label_noise}
    write_json_atomic(out / "results.json", summary)
    return [report, out / "results.json", *(out / p for p in pngs)]
