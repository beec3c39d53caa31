"""`cell examples generate`: a teaching session of the simulated operator, written as an example file."""

from __future__ import annotations

import sys

MAX_COUNT = 10000  # accepted grasps in one session (the paper's: 60)


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, help="example file to write (JSON Lines)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--append", action="store_true", help="append to an existing file (example ids must be new)")
    mode.add_argument("--overwrite", action="store_true", help="replace an existing file (atomically)")
    parser.add_argument("--count", type=int, default=60,
                        help="accepted grasps to give (default 60, as in the paper)")
    parser.add_argument("--seed", type=int, default=0,
                        help="random seed (default 0; the file is deterministic for a seed)")
    parser.add_argument("--families", default=None,
                        help="comma-separated part families to draw from (default: the whole library)")
    parser.add_argument("--rejections", type=float, default=1 / 3,
                        help="share of presentations where the operator first rejects a bad grasp "
                        "(default 1/3)")
    parser.add_argument("--neighbours", type=float, default=0.15,
                        help="share of presentations with one or two neighbouring parts (default 0.15)")
    parser.add_argument("--cell", default=None, help="cell file (default: the shipped default cell)")


def run(args) -> int:
    import json
    from pathlib import Path

    from cell.cellconfig import load_cell
    from cell.commands._vision_args import count, refuse_out_over_an_input
    from cell.errors import BadInput
    from cell.examples import append_examples, examples_appended_to
    from cell.fileio import check_writable, replace_lines_atomic
    from cell.operator import generate_examples

    count(args.count, "--count", MAX_COUNT)  # a few a second: 1e23 ran without end
    if not (0.0 <= args.rejections <= 1.0 and 0.0 <= args.neighbours <= 1.0):
        raise BadInput("--rejections and --neighbours are shares between 0 and 1")
    out = Path(args.out)
    if out.exists() and not (args.append or args.overwrite):
        raise BadInput(f"{out} exists: pass --append to add to it or --overwrite to replace it")
    if out.exists() and out.is_dir():
        raise BadInput(f"--out {out} is a folder")
    check_writable(out, "--out")  # before the session, not after it
    refuse_out_over_an_input(out, [args.cell])  # --overwrite replaced the cell file with examples
    if args.append and out.exists():  # a broken file too (a truncated last line was refused after the session)
        examples_appended_to(out.read_bytes(), out)
    families = [f.strip() for f in args.families.split(",") if f.strip()] if args.families else None
    if families == []:  # "," or " ": was an IndexError, not the whole library
        raise BadInput(f"--families {args.families!r} names no family")
    cell = load_cell(args.cell)

    def progress(i, n):
        print(f"\rexamples: {i}/{n} accepted", end="", file=sys.stderr, flush=True)

    examples = generate_examples(args.count, args.seed, families, cell, args.rejections, args.neighbours,
                                 progress)
    print(file=sys.stderr)
    try:
        if args.overwrite and out.exists():
            replace_lines_atomic(out, [json.dumps(e.to_json(), separators=(",", ":")) for e in examples])
        else:
            append_examples(out, examples)
    except OSError as e:
        raise BadInput(f"cannot write {out}: {e}") from None
    n_ok = sum(e.valid for e in examples)
    print(f"wrote {len(examples)} examples ({n_ok} accepted, {len(examples) - n_ok} rejected) to {args.out}")
    return 0
