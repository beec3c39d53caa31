"""`cell replay DIR [--examples FILE] [--json]`.

Re-runs perception and planning on a recorded session's frames with the simulated drives and
checks that every decision and command matches the recording. Exit 0 when all match, 1 at
the first divergence (named on stderr), 2 on a missing or corrupt recording, or on one whose end
was never recorded (killed, or failed: a full disk); with --json then too a JSON line on stdout:
`incomplete`, how many recorded decisions `matched` before the end, `error`, `session`, `problems` (`match`
null). A stopped session was recorded up to its stop: it can match (exit 0), and the output says that it was
stopped, after how many parts and why; a stop on a drive or bus fault is re-created, or taken from the
recording where it cannot be, and a note says which. With `--examples FILE` (other teaching examples) the
differences are listed instead (exit 0).
"""

from __future__ import annotations

import json
import sys

from cell.errors import BadInput


def add_arguments(p):
    p.add_argument("recording", metavar="DIR", help="a recording directory written by `cell run --record`")
    p.add_argument("--examples", metavar="FILE", help="try another example file: report differences, not fail")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")


def run(args) -> int:
    from cell.runtime.replay import Divergence, replay

    try:
        try:
            result = replay(args.recording, args.examples,
                            progress=lambda s: print(s, file=sys.stderr if args.json else sys.stdout, flush=True))
        except OSError as e:  # the recording cannot be read (EIO), the replay's own CAN log cannot be written
            # (a full /tmp; a RecordingFailed): no divergence (1), a recording replay cannot check (2)
            from cell.cli import _os_error_text

            raise BadInput(_os_error_text(e)) from None
    except BadInput as e:
        if args.json:  # exit 2 all the same; a script tells a session cut short from a corrupt folder by it
            print(json.dumps(_refused_verdict(args.recording, e)), flush=True)
        raise
    except Divergence as e:
        from cell.numerics import numeric_platform, platform_difference
        from cell.recording import RecordingReader

        rec = RecordingReader(args.recording)
        # numbers computed by other libraries or kernels may differ in their last digits: say so beside it
        software = rec.manifest.get("software")
        numeric = software.get("numeric") if isinstance(software, dict) else None
        platform = platform_difference(numeric, numeric_platform())
        if numeric is None:  # made before the kernels were pinned: with this CPU's own, as it was then
            platform = ("made before the cell pinned its BLAS kernels (cell/numerics.py): try again with this "
                        f"CPU's own, OPENBLAS_CORETYPE= OPENBLAS_NUM_THREADS= cell replay {args.recording}")
        if args.json:  # how the recorded session ended, as a match reports it
            from cell.runtime.replay import recorded_end

            print(json.dumps({"match": False, "divergence": str(e), "session": recorded_end(rec),
                              "platform_difference": platform}))
        print(f"cell replay: divergence: {e}", file=sys.stderr)
        if platform:
            print(f"cell replay: recorded with other numeric libraries or kernels: {platform}"
                  if numeric is not None else f"cell replay: the recording was {platform}", file=sys.stderr)
        return 1
    result["match"] = not result["differences"]
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['matched']} of {result['decisions']} decisions match the recording")
        for d in result["differences"]:
            print(f"  differs: {d}")
        for note in result["notes"]:
            print(f"  note: {note}")
        _say_how_it_ended(result["session"])
    return 0


def _refused_verdict(directory, e: BadInput) -> dict:
    """--json's answer for a recording replay refused (exit 2): `incomplete` (its end was never recorded: killed,
    failed, a full disk) with how many recorded decisions `matched` before it, and how the session ended as far
    as the manifest says (`session`, `problems`); or not (a missing or corrupt recording: `matched` null)."""
    from cell.recording import RecordingReader
    from cell.runtime.replay import recorded_end

    out = {"match": None, "incomplete": False, "matched": None, "error": str(e), "session": None, "problems": []}
    try:
        rec = RecordingReader(directory)
    except (BadInput, OSError):
        return out
    out.update(incomplete=not rec.complete, matched=getattr(e, "matched", None),  # (RecordingIncomplete's)
               session=recorded_end(rec), problems=rec.problems)
    return out


def _say_how_it_ended(end: dict) -> None:
    """A session that did not run to the end matches only as far as it went: say so (exit 0 all the same:
    it was closed whole, unlike a killed or failed one, which is exit 2)."""
    if end["status"] == "complete":
        return
    parts = (f" after {end['parts_removed']} of {end['parts_total']} parts removed"
             if end["parts_total"] is not None else "")
    print(f"the recorded session was {end['status']} ({end['recording']}){parts}"
          + (f": {end['stopped']}" if end.get("stopped") else ""))
