"""`cell station`: serve the operator station (local web page) for the demo cell.

The cell loop (`cell run --station`, the lead's) serves the same page for the real cell; this
command serves it for `cell.station.demo.DemoCell`, a small simulated tray, so the page can
be tried and shown without the rest of the cell. `--cell F` puts the demo in that cell (its tray,
camera frame, gripper, arm and home joints), as every other command takes it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

MAX_MOTION_S = 600.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cell", metavar="FILE", help="cell file (default: the shipped default cell): the demo's tray, "
                                                  "camera frame, jaws, arm and home joints")
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1: this PC only)")
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0 = any free port)")
    p.add_argument("--token", help="session token for commands, at least 8 characters (default: a random one, printed)")
    p.add_argument("--allow-remote", action="store_true",
                   help="allow binding to a non-loopback address (the token then guards the arm)")
    p.add_argument("--examples", default="station_examples.jsonl",
                   help="example file taught and rejected grasps are appended to "
                        "(default ./station_examples.jsonl)")
    p.add_argument("--approve-each", "--approve", dest="approve_each", action="store_true",
                   help="start with 'approve each grasp' on")
    p.add_argument("--motion-s", type=float, default=1.0, help="simulated duration of one pick, 0..600 s (default 1)")
    p.add_argument("--for-s", type=float, default=None, help="serve this long, then exit (default: until ^C)")


def run(args) -> int:
    import threading
    import time

    from cell.cellconfig import load_cell
    from cell.commands._vision_args import seconds
    from cell.commands.run import sigterm_as_interrupt
    from cell.errors import BadInput
    from cell.fileio import check_writable
    from cell.runtime.control import RunControl
    from cell.station.demo import DemoCell
    from cell.station.server import LOOPBACK_HOSTS, StationServer

    if not (0 <= args.port <= 65535):
        raise BadInput(f"--port must be 0..65535, not {args.port}")
    # NaN or 1e300 s made the pick thread's sleep raise (the page waited for a pick that had died)
    if not 0 <= args.motion_s <= MAX_MOTION_S:
        raise BadInput(f"--motion-s must be 0..{MAX_MOTION_S:g} s, got {args.motion_s:g}")
    seconds(args.for_s, "--for-s")
    if args.host not in LOOPBACK_HOSTS and not args.allow_remote:  # (the server's own refusal names no flag)
        raise BadInput(f"--host {args.host} would let anyone on the network reach the arm; give --allow-remote "
                       "too (the session token then guards it), or keep the default 127.0.0.1")
    config = load_cell(args.cell)  # a bad file: BadInput, exit 2, before anything is served or written
    if args.cell is not None and Path(args.examples).resolve() == Path(args.cell).resolve():
        raise BadInput(f"--examples {args.examples} is the cell file: taught grasps would be appended to it; "
                       "name another file")
    check_writable(args.examples, "--examples")  # a path under a file failed only at the first taught grasp
    control = RunControl(require_approval=args.approve_each)
    cell = DemoCell(control, args.examples, cell=config, motion_s=args.motion_s)
    server = StationServer(cell, control, host=args.host, port=args.port, token=args.token,
                           allow_remote=args.allow_remote)
    with server, sigterm_as_interrupt():  # SIGTERM (a service manager, kill) ends it as Ctrl-C does
        cell.start()
        print(f"operator station (demo cell) at {server.base_url}", flush=True)
        print(f"open: {server.url}", flush=True)
        if server.on_every_interface:
            print(f"served on every interface: from another machine, this machine's address, port {server.port}, "
                  "with the token", flush=True)
        print(f"token: {server.token}", flush=True)
        print(f"cell: {config.name} ({config.source})", flush=True)
        print(f"examples: {args.examples}", flush=True)
        try:
            if args.for_s is not None:  # at most TIMEOUT_MAX (292 years): 1e300 was an OverflowError
                time.sleep(min(args.for_s, threading.TIMEOUT_MAX))
            else:
                while True:
                    time.sleep(3600)
        except KeyboardInterrupt:
            pass
        finally:
            cell.close()
    print("station closed", flush=True)
    return 0
