"""`cell plan ASSEMBLY.json [--json] [--figures DIR] [--examples FILE] [--cell FILE]`.

Plans each step of the disassembly sequence against the parts still present (CONTRACT.md).
Exit 0 when every step has a grasp, 3 when some step has none, 2 on bad input.
"""

from __future__ import annotations

import json
from pathlib import Path


def add_arguments(p):
    p.add_argument("assembly", metavar="ASSEMBLY", help="assembly JSON file (CONTRACT.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object per step")
    p.add_argument("--figures", metavar="DIR", help="write one PNG per step (paper Figs. 20-23), step_NN_<part>.png; "
                   "an earlier plan's step_NN_*.png there that this plan does not write are removed")
    p.add_argument("--examples", metavar="FILE", help="teaching-example file (default: the shipped one)")
    p.add_argument("--cell", metavar="FILE", help="cell file (overrides the assembly's own 'cell' key)")


def run(args) -> int:
    from cell.cellconfig import load_cell
    from cell.commands.grasp import load_planner_inputs
    from cell.disassembly import plan_assembly
    from cell.grasp.synthesis import GraspPlanner
    from cell.scene import load_assembly

    if args.figures:  # a place that cannot take them is refused first
        from cell.fileio import check_folder_writable

        check_folder_writable(Path(args.figures), f"--figures {args.figures}")
    assembly = load_assembly(args.assembly)
    cell = load_cell(args.cell or assembly.cell_path)
    examples = load_planner_inputs(args.examples)
    if args.figures:  # made once the inputs are read (a bad one leaves nothing behind), before the planning
        from cell.fileio import check_writable, make_folder

        make_folder(Path(args.figures), f"--figures {args.figures}")
        for step, part_id in enumerate(assembly.sequence):  # a read-only one: refused before the planning
            check_writable(Path(args.figures) / figure_name(step, part_id), "--figures")
    planner = GraspPlanner(cell, examples)
    from cell.heap import freeze_startup

    freeze_startup()  # no full collection of the start-up objects inside a step's time_ms
    steps = plan_assembly(planner, assembly)
    for s in steps:
        if args.json:
            print(json.dumps(s.to_json()), flush=True)
        else:
            print(_line(s), flush=True)
    if args.figures:
        from cell.errors import BadInput
        from cell.figures import step_figure

        written = set()
        for s in steps:
            path = Path(args.figures) / figure_name(s.step, s.scene.target)
            try:
                _write_figure_atomically(s, cell, path, step_figure)
            except OSError as e:
                raise BadInput(f"--figures {args.figures}: cannot write {path.name}: {e.strerror}") from None
            written.add(path.name)
        stale = _remove_stale_figures(Path(args.figures), written)
        if not args.json:
            print(f"figures: {args.figures}" + (f" ({stale} of an earlier plan removed)" if stale else ""))
    failed = [s for s in steps if not s.ok]
    if not args.json:
        print(f"{len(steps) - len(failed)} of {len(steps)} steps have a grasp")
    return 3 if failed else 0


def _write_figure_atomically(step_plan, cell, path, draw) -> None:
    """Draw into a temp folder, then replace `path` whole (savefig straight into the folder left half a
    PNG when drawing failed or the process was stopped part way)."""
    import tempfile
    from pathlib import Path

    from cell.fileio import write_atomic

    with tempfile.TemporaryDirectory(prefix="cell-figure-") as tmp:
        drawn = draw(step_plan, cell, Path(tmp) / path.name)
        write_atomic(path, Path(drawn).read_bytes())


def _remove_stale_figures(folder: Path, written: set[str]) -> int:
    """Remove the step figures of an earlier plan that this one did not write (another assembly, fewer steps):
    the folder then shows one plan, not a mix. Only names figure_name makes are touched."""
    import re

    ours = re.compile(r"step_\d{2,}_.+\.png")
    stale = [f for f in folder.glob("step_*.png") if f.name not in written and ours.fullmatch(f.name)]
    for f in stale:
        try:
            f.unlink()
        except FileNotFoundError:
            pass
        except OSError as e:
            from cell.errors import BadInput

            raise BadInput(f"--figures {folder}: cannot remove an earlier plan's {f.name}: {e.strerror}") from None
    return len(stale)


def figure_name(step: int, part_id: str) -> str:
    """`step_NN_<id>.png` with the id made a safe file name: part ids are free strings, and a '/'
    or '..' in one must not write outside the folder, nor a long one exceed the name limit."""
    import re

    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", part_id).strip(".") or "part"
    return f"step_{step:02d}_{safe[:80]}.png"


def _line(s) -> str:
    if not s.ok:
        return f"step {s.step}: {s.scene.target}: NO GRASP ({s.error}): {s.reason}"
    g = s.result.grasp
    q = g.joints
    step = "" if s.result.step_mm is None else f" (at the finer {s.result.step_mm:g} mm outline step)"
    return (f"step {s.step}: {g.target}{step}: contacts {g.contacts_mm.round(1).tolist()}, "
            f"opening {g.opening_mm:.1f} mm, axis {g.axis_deg:.1f} deg, z {g.grasp_z_mm:.1f} mm, "
            f"elbow {q.elbow if q else '-'}, {s.result.counts['valid_sets']} valid sets, {s.result.time_ms:.1f} ms")
