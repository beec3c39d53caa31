"""The shipped EDS files: written by drivers/eds.py, readable by canopen, static PDO mapping
matching the codecs."""

from __future__ import annotations

import canopen
import pytest

from drivers import codec
from drivers.eds import AXIS_EDS, GRIPPER_EDS, eds_path, render_eds


@pytest.mark.parametrize(("name", "gripper"), [(AXIS_EDS, False), (GRIPPER_EDS, True)])
def test_shipped_eds_is_what_the_generator_writes(name, gripper):
    assert eds_path(name).read_text(encoding="utf-8") == render_eds(gripper)


@pytest.mark.parametrize("name", [AXIS_EDS, GRIPPER_EDS])
def test_pdo_mapping_matches_the_codecs(name):
    od = canopen.import_od(str(eds_path(name)), 7)
    assert od[0x1800][1].default == codec.TPDO1_BASE + 7 | 0x40000000  # bit 30: no RTR
    assert od[0x1400][1].default == codec.RPDO1_BASE + 7
    assert od[0x1401][1].default == codec.RPDO2_BASE + 7
    assert od[0x1402][1].default == codec.RPDO3_BASE + 7
    assert od[0x1403][1].default & 0x80000000  # RPDO4 not used
    tpdo = [od[0x1A00][i].default for i in range(1, od[0x1A00][0].default + 1)]
    assert tpdo == [0x60410010, 0x60640020, 0x60610008]  # statusword, position actual, mode display
    assert sum(m & 0xFF for m in tpdo) == 8 * 7  # the 7-byte TPDO1 of drivers.codec
    assert [od[0x1600 + k][1].default for k in range(3)] == [0x60400010, 0x607A0020, 0x60600008]
    assert od[0x6502].default & codec.SUPPORTED_MODES_PP
