"""`cell` command line: a plain table of subcommand -> module, imported only when used.

Each module in `cell.commands` defines `add_arguments(parser)` and `run(args) -> int`.
Heavy imports (cv2, sklearn, canopen, rerun) belong inside `run`, so `cell --help` is fast.
Errors of the `CellError` family become a message on stderr and their exit code
(2 for bad input); no traceback reaches the user for anything the user can fix. An OSError (a path or
device that cannot be used, a full or failing disk too) is bad input too, named by its file, except a
recording a full or failing disk stopped (RecordingFailed: cell run, cell hw --record) and a full or failing
disk (ENOSPC, EDQUOT, EIO) in cell run or cell hw: exit 1, as a run that stopped; any other exception is a
bug, reported in one line with exit 1 (CELL_TRACEBACK=1 lets the traceback through).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import importlib.util
import logging
import os
import sys

from cell.errors import BadInput, CellError

# (words, module, one-line help). Two words make a group ("calibrate intrinsics").
COMMANDS: list[tuple[tuple[str, ...], str, str]] = [
    (("grasp",), "cell.commands.grasp", "plan a grasp for one or more scene files"),
    (("rules",), "cell.commands.rules", "print the learned decision trees as if-then rules"),
    (("plan",), "cell.commands.plan", "plan grasps for every step of a disassembly sequence"),
    (("study",), "cell.commands.study", "reproduce the paper's learning study (classifier comparison)"),
    (("examples", "generate"), "cell.commands.examples", "generate teaching examples with the simulated operator"),
    (("segment",), "cell.commands.segment", "segment camera frames into part contours"),
    (("render",), "cell.commands.render", "render a camera frame of a scene with the simulated camera"),
    (("calibrate", "intrinsics"), "cell.commands.calibrate", "camera intrinsics from chessboard/ChArUco images"),
    (("calibrate", "plane"), "cell.commands.calibrate_plane", "image <-> base-frame mapping from fiducials"),
    (("map",), "cell.commands.map", "map pixels to mm on a plane, or mm to pixels"),
    (("run",), "cell.commands.run", "run a disassembly in the cell (simulated by default)"),
    (("replay",), "cell.commands.replay", "re-run perception and planning on a recorded session"),
    (("station",), "cell.commands.station", "serve the operator station (local web page)"),
    (("hw", "status"), "cell.commands.hw", "bring the nodes up and print their state"),
    (("hw", "sim"), "cell.commands.hw", "serve the simulated drives on a CAN bus until stopped"),
    (("hw", "reset"), "cell.commands.hw", "clear the drives' faults and enable them where they stand"),
    (("hw", "home"), "cell.commands.hw", "home the arm (hardware-in-loop)"),
    (("hw", "jog"), "cell.commands.hw", "jog one joint by a small step (hardware-in-loop)"),
    (("hw", "gripper"), "cell.commands.hw", "open or close the gripper (hardware-in-loop)"),
    (("hw", "corner"), "cell.commands.hw", "move to a tray corner and back (hardware-in-loop)"),
    (("hw", "pick"), "cell.commands.hw", "plan a grasp on a scene file and pick the part (hardware-in-loop)"),
    (("bench", "grasp"), "cell.commands.bench_grasp", "benchmark grasp synthesis: cascade vs brute force"),
    (("bench", "vision"), "cell.commands.bench_vision", "benchmark segmentation accuracy and speed"),
    (("bench", "stability"), "cell.commands.bench_stability", "share of stable grasps over the parts library"),
    (("bench", "can"), "cell.commands.bench_can", "benchmark CAN round trip and bus load per pick"),
    (("bench", "perception"), "cell.commands.bench_perception",
     "time the loop's perception of a frame at 6, 28 and 60 parts, matching the old way and the new"),
]


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # "-1e1", "-1,-1,5,5" are values, not options (argparse knows only "-5" and "-.5"): without this,
        # `hw jog j1 -1e1` said "the following arguments are required: step"
        from cell.commands._vision_args import allow_negative_pairs

        allow_negative_pairs(self)

    # A command taking several positional files (`grasp A.json --json B.json`) parses them intermixed with
    # its options: argparse's plain parse took the positionals before the first option only, and refused
    # the later ones as "unrecognized arguments". Set by build_parser for such commands.
    intermixed = False
    _parsing_intermixed = False

    def parse_known_args(self, args=None, namespace=None):
        if not self.intermixed or self._parsing_intermixed:
            return super().parse_known_args(args, namespace)
        if args is not None and "--" in args:
            return self._parse_files_after_dashes(list(args), namespace)
        self._parsing_intermixed = True  # parse_known_intermixed_args calls parse_known_args twice
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._parsing_intermixed = False

    def _parse_files_after_dashes(self, args, namespace):
        """Everything after "--" is a file, added to those among the options before it. (Python 3.11's intermixed
        parse takes the "--" away in its first pass, and `grasp --json -- -a.json` then read -a.json as an
        unknown option; the plain parse refused `grasp a.json --json -- b.json`: the files were already taken.)"""
        i = args.index("--")
        files = next(a for a in self._actions if not a.option_strings and a.nargs in ("+", "*"))
        nargs, files.nargs = files.nargs, "*"  # the files before "--" may be none
        try:
            ns, extras = self.parse_known_args(args[:i], namespace)
        finally:
            files.nargs = nargs
        after = [files.type(a) if files.type else a for a in args[i + 1:]]
        setattr(ns, files.dest, list(getattr(ns, files.dest) or []) + after)
        if nargs == "+" and not getattr(ns, files.dest):
            self.error(f"the following arguments are required: {files.metavar or files.dest}")
        return ns, extras

    def error(self, message):  # argparse's own usage errors are bad input too: exit 2
        self.print_usage(sys.stderr)
        raise BadInput(message)


def _available() -> list[tuple[tuple[str, ...], str, str]]:
    out = []
    for words, module, help_ in COMMANDS:
        if importlib.util.find_spec(module) is not None:
            out.append((words, module, help_))
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="cell", description="Disassembly cell controller: grasp synthesis learned "
                     "from examples, vision, CANopen drives.")
    parser._commands = {}  # words -> the command's own parser
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    groups: dict[str, argparse._SubParsersAction] = {}
    for words, module, help_ in _available():
        if len(words) == 1:
            p = sub.add_parser(words[0], help=help_, description=help_)
        else:
            if words[0] not in groups:
                g = sub.add_parser(words[0], help=f"{words[0]} commands")
                groups[words[0]] = g.add_subparsers(dest="subcommand", metavar="SUBCOMMAND", parser_class=_Parser)
            p = groups[words[0]].add_parser(words[1], help=help_, description=help_)
        p.set_defaults(_module=module, _words=words)
        importlib.import_module(module).add_arguments(p)
        p.intermixed = any(not a.option_strings and a.nargs in ("+", "*") for a in p._actions)
        parser._commands[words] = p
    return parser


def _refuse_empty_values(parser, args) -> None:
    """`--record "$DIR"` with DIR unset was no recording, `run "$ASM"` the default assembly, `study --out ""`
    the current folder: an empty value is never a path, a name or a number here."""
    for action in parser._commands[args._words]._actions:
        if args._words == ("grasp",) and action.dest == "scenes":
            continue  # each scene gets its own line, "" a bad_input one among the others (CONTRACT's batch form)
        v = getattr(args, action.dest, None)
        if v == "" or (isinstance(v, list) and "" in v):
            name = action.option_strings[-1] if action.option_strings else (action.metavar or action.dest.upper())
            raise BadInput(f"{name} is empty: give a value")


def warnings_to_stderr(logger: logging.Logger | None = None) -> None:
    """Warnings the library logs (a drive that keeps its own quick stop, ...) reach the user as
    `cell: warning: ...` beside `cell: error: ...`, not as Python's bare last-resort lines. Left as it is
    when the logger already has a handler (an application or pytest set one up)."""
    logger = logging.getLogger() if logger is None else logger
    if logger.handlers:
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_CellFormatter())
    handler.setLevel(logging.WARNING)
    logger.addHandler(handler)


class _CellFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"cell: {record.levelname.lower()}: {record.getMessage()}"


def _os_error_text(e: OSError) -> str:
    """"/x/out.png: No space left on device", not "[Errno 28] No space left on device"."""
    if e.filename is not None and e.strerror:
        return f"{e.filename}{'' if e.filename2 is None else f' -> {e.filename2}'}: {e.strerror}"
    return e.strerror or str(e)


# the commands that run the cell: a full or failing disk mid-session is the machine's state, not bad input (exit
# 1, as a run that stopped); in every other command it is an unusable file (2, as CONTRACT says)
MACHINE_COMMANDS = ("cell.commands.run", "cell.commands.hw")
DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EIO)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    warnings_to_stderr()
    args = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not hasattr(args, "_module"):
            parser.print_help(sys.stderr)
            return 2
        _refuse_empty_values(parser, args)
        if isinstance(getattr(args, "seed", None), int) and args.seed < 0:  # numpy's generators refuse it
            raise BadInput(f"--seed must be 0 or more, got {args.seed}")
        return int(importlib.import_module(args._module).run(args) or 0)
    except CellError as e:
        print(f"cell: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("cell: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as e:  # a path or device the user named cannot be used (permissions, a full disk, ...)
        from cell.recording import RecordingFailed

        print(f"cell: error: {_os_error_text(e)}", file=sys.stderr)
        # a recording the disk stopped (cell run, cell hw --record) ends as a stopped run (1), as does a full
        # disk in a session of the cell; any other unusable file, full or failing disks too, is what CONTRACT
        # says of it (2)
        machine = getattr(args, "_module", None) in MACHINE_COMMANDS
        return 1 if isinstance(e, RecordingFailed) or (machine and e.errno in DISK_ERRNOS) else 2
    except Exception as e:  # a bug: one line, not a traceback; CELL_TRACEBACK=1 shows where it happened
        if os.environ.get("CELL_TRACEBACK"):
            raise
        print(f"cell: internal error: {type(e).__name__}: {e} (please report it with the command line; "
              "CELL_TRACEBACK=1 shows where it happened)", file=sys.stderr)
        return 1
