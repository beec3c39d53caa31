"""The shipped EDS files: written by drivers/eds.py, one per node of the shipped cell, readable by canopen,
static PDO mapping matching the codecs."""

from __future__ import annotations

import canopen
import pytest

from drivers import codec
from drivers.eds import NODE_NAMES, eds_path, node_eds_file


@pytest.mark.parametrize("name", NODE_NAMES)
def test_shipped_eds_is_what_the_generator_writes(name):
    from cell.cellconfig import default_cell
    from drivers.sim import node_eds_text

    assert eds_path(node_eds_file(name)).read_text(encoding="utf-8") == node_eds_text(default_cell(), name)


@pytest.mark.parametrize("name", NODE_NAMES)
def test_pdo_mapping_matches_the_codecs(name):
    od = canopen.import_od(str(eds_path(node_eds_file(name))), 7)
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
