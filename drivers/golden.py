"""A short recorded session shipped as a candump `.log` fixture: enable, one move, one grip.

The simulated session is deterministic (simulated time, settled bus), so the frames and their
time stamps are the same on every run; a test re-records it and compares, which catches any
change of the bytes on the bus. After a deliberate protocol change: `python -m drivers.golden`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from cell.kinematics import Joints
from drivers.session import simulated_cell

FIXTURE = "enable_move_grip.log"


def fixture_path() -> Path:
    return Path(str(resources.files("drivers") / "fixtures" / FIXTURE))


def record_golden_session(path: str | Path) -> None:
    with simulated_cell(channel="golden", record=path) as (arm, drives):
        s = arm.joints()
        arm.move_joints(Joints(s.j1_deg + 2.0, s.j2_deg - 1.0, s.j3_mm - 5.0, s.j4_deg))
        drives.gripper_object_width_mm = 70.0
        arm.gripper.grip(70.0)


def remake_fixture(out: Path) -> None:
    """Record the session beside `out` and put it in its place: a CAN log is never written over
    (`python -m drivers.golden` ended in a traceback), and a failed recording leaves the old one."""
    fresh = out.with_name(f"{out.stem}.new{out.suffix}")  # (a CAN log keeps its suffix: python-can reads by it)
    fresh.unlink(missing_ok=True)
    try:
        record_golden_session(fresh)
        fresh.replace(out)
    finally:
        fresh.unlink(missing_ok=True)


if __name__ == "__main__":
    out = Path(__file__).resolve().parent / "fixtures" / FIXTURE
    remake_fixture(out)
    print(out)
