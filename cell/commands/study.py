"""`cell study`: the paper's classifier comparison on operator-labelled points and sets.

Writes report.md, results.json and PNG plots into --out; progress goes to stderr.
"""

from __future__ import annotations

import sys

MAX_EXAMPLES = 10000  # per problem (the paper's study: 400, about two minutes)


def add_arguments(parser) -> None:
    parser.add_argument("--out", default="study", help="output folder (default ./study)")
    parser.add_argument("--budget", choices=("full", "tiny"), default="full",
                        help="full: 400 examples, 10 folds, 20..380 training examples x 5 draws (about "
                             "two minutes); tiny: a smoke run (default full)")
    parser.add_argument("--examples", type=int, default=None, help="examples per problem (default: the budget's)")
    parser.add_argument("--folds", type=int, default=None, help="cross-validation folds (default: the budget's)")
    parser.add_argument("--label-noise", type=float, default=0.0,
                        help="share of labels flipped at random, to imitate a less consistent person "
                             "(default 0: the simulated operator's own judgement)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the examples, their label noise and the cross-validation (default 0)")
    parser.add_argument("--cell", default=None, help="cell file (default: the shipped default cell)")


def run(args) -> int:
    import time
    from dataclasses import replace
    from pathlib import Path

    from cell.cellconfig import load_cell
    from cell.errors import BadInput
    from cell.fileio import check_writable, make_folder
    from cell.study.data import point_dataset, set_dataset, with_label_noise
    from cell.study.experiments import Budget, run_problem
    from cell.study.report import OUTPUTS, headline_table, write_report

    budget = Budget.named(args.budget)
    if args.examples is not None:
        if not 20 <= args.examples <= MAX_EXAMPLES:  # 1e11 labelled points would never end
            raise BadInput(f"--examples must be 20..{MAX_EXAMPLES}, got {args.examples}")
        budget = replace(budget, n=args.examples, sizes=tuple(s for s in budget.sizes if s < args.examples))
    if args.folds is not None:
        if not 2 <= args.folds <= budget.n // 2:
            raise BadInput(f"--folds must be between 2 and {budget.n // 2}")
        budget = replace(budget, folds=args.folds)
    if not 0.0 <= args.label_noise < 0.5:
        raise BadInput("--label-noise must be a share in [0, 0.5)")
    out = Path(args.out)
    make_folder(out, f"--out {out}")  # before minutes of work, not after
    for name in OUTPUTS:
        check_writable(out / name, "--out")
    cell = load_cell(args.cell)
    t0 = time.perf_counter()

    def say(msg):
        print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    say(f"labelling {budget.n} contact points with the simulated operator")
    points = with_label_noise(point_dataset(budget.n, args.seed, cell), args.label_noise, args.seed)
    say(f"labelling {budget.n} contact sets with the simulated operator")
    sets = with_label_noise(set_dataset(budget.n, args.seed, cell), args.label_noise, args.seed)
    results = {"points": run_problem(points, budget, args.seed, say),
               "sets": run_problem(sets, budget, args.seed, say)}
    try:
        files = write_report(results, out, budget, args.seed, time.perf_counter() - t0, args.label_noise)
    except OSError as e:
        raise BadInput(f"cannot write the study to {out}: {e}") from None
    say(f"wrote {', '.join(str(f) for f in files)}")
    print(headline_table(results))
    return 0
