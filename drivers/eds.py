"""The EDS files of the cell's drives (shipped in drivers/eds/, one per node), and the generator that wrote them.

Every drive is a CiA 402 device with the same communication objects and the static PDO
mapping described in `drivers.codec`; the gripper adds a grip-force limit (0x2100). Each
node's EDS has as DefaultValues what that node holds at power-on and after the NMT resets:
the values the cell file sets (`drivers.sim_objects.power_on_values`; the shipped files are
the shipped cell's, `drivers.sim.node_eds_paths` writes others for another cell).
`python -m drivers.eds` rewrites the shipped files; a test checks they match.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path

import canopen

from drivers import codec

U8, U16, U32, I8, I16, I32, VSTR = 0x0005, 0x0006, 0x0007, 0x0002, 0x0003, 0x0004, 0x0009
VAR, ARRAY, RECORD = 0x7, 0x8, 0x9

NODE_NAMES = ("j1", "j2", "j3", "j4", "gripper")
GRIP_FORCE_INDEX = 0x2100  # grip force limit, UNSIGNED16 in 0.1 N (cell.cellconfig.grip_force_units)


def eds_path(name: str) -> Path:
    return Path(str(resources.files("drivers") / "eds" / name))


def node_eds_file(name: str) -> str:
    """The shipped EDS file of node `name` (j1-j4, gripper)."""
    return f"{name}.eds"


@functools.lru_cache(maxsize=64)
def object_dictionary(path: str, node_id: int) -> canopen.ObjectDictionary:
    """The parsed EDS for one node id, parsed once per process (parsing takes ~15 ms). The
    dictionary only describes objects; values live in the nodes, so sharing it is safe."""
    return canopen.import_od(path, node_id)


def _objects(gripper: bool) -> list[tuple]:
    """(index, name, kind, [subs]) with subs (subindex, name, type, access, default, pdo)."""

    def var(index, name, dtype, access, default, pdo=0):
        return (index, name, VAR, [(0, name, dtype, access, default, pdo)])

    def pdo_comm(index, name, cob):
        return (
            index,
            name,
            RECORD,
            [
                (0, "Highest sub-index supported", U8, "const", "5", 0),
                (1, "COB-ID", U32, "rw", cob, 0),
                (2, "Transmission type", U8, "rw", "255", 0),
                (3, "Inhibit time", U16, "rw", "0", 0),
                (5, "Event timer", U16, "rw", "0", 0),
            ],
        )

    def pdo_map(index, name, entries):
        subs = [(0, "Number of mapped objects", U8, "ro", str(len(entries)), 0)]
        for i in range(1, 5):
            value = entries[i - 1] if i <= len(entries) else 0
            subs.append((i, f"Mapped object {i}", U32, "ro", f"0x{value:08X}", 0))
        return (index, name, RECORD, subs)

    device_type = "0x00020192"  # CiA 402, servo drive
    objs = [
        var(0x1000, "Device type", U32, "ro", device_type),
        var(0x1001, "Error register", U8, "ro", "0", 1),
        # the drives consume SYNC (synchronous TPDO1 types 0-240), produce none
        var(0x1005, "COB-ID SYNC", U32, "rw", f"0x{codec.SYNC_COB:08X}"),
        var(
            0x1008,
            "Manufacturer device name",
            VSTR,
            "const",
            "disassembly-cell gripper" if gripper else "disassembly-cell SCARA axis",
        ),
        var(0x1014, "COB-ID EMCY", U32, "ro", "$NODEID+0x80"),
        (
            0x1016,
            "Consumer heartbeat time",
            ARRAY,
            [
                (0, "Number of entries", U8, "const", "1", 0),
                (1, "Consumer heartbeat time 1", U32, "rw", "0", 0),
            ],
        ),
        var(0x1017, "Producer heartbeat time", U16, "rw", "100"),
        (
            0x1018,
            "Identity object",
            RECORD,
            [
                (0, "Number of entries", U8, "const", "4", 0),
                (1, "Vendor-ID", U32, "ro", "0x00000000", 0),
                (2, "Product code", U32, "ro", "0x00000402" if not gripper else "0x00000403", 0),
                (3, "Revision number", U32, "ro", "0x00010000", 0),
                (4, "Serial number", U32, "ro", "0", 0),
            ],
        ),
        pdo_comm(0x1400, "RPDO1 communication parameter", "$NODEID+0x200"),
        pdo_comm(0x1401, "RPDO2 communication parameter", "$NODEID+0x300"),
        pdo_comm(0x1402, "RPDO3 communication parameter", "$NODEID+0x400"),
        pdo_comm(0x1403, "RPDO4 communication parameter", "$NODEID+0x80000500"),
        pdo_map(0x1600, "RPDO1 mapping parameter", list(codec.RPDO_MAPPINGS[0])),
        pdo_map(0x1601, "RPDO2 mapping parameter", list(codec.RPDO_MAPPINGS[1])),
        pdo_map(0x1602, "RPDO3 mapping parameter", list(codec.RPDO_MAPPINGS[2])),
        pdo_map(0x1603, "RPDO4 mapping parameter", []),
        # TPDOs: bit 30 set, no RTR allowed (the drives answer none)
        pdo_comm(0x1800, "TPDO1 communication parameter", "$NODEID+0x40000180"),
        pdo_comm(0x1801, "TPDO2 communication parameter", "$NODEID+0xC0000280"),
        pdo_comm(0x1802, "TPDO3 communication parameter", "$NODEID+0xC0000380"),
        pdo_comm(0x1803, "TPDO4 communication parameter", "$NODEID+0xC0000480"),
        pdo_map(0x1A00, "TPDO1 mapping parameter", list(codec.TPDO1_MAPPING)),
        pdo_map(0x1A01, "TPDO2 mapping parameter", []),
        pdo_map(0x1A02, "TPDO3 mapping parameter", []),
        pdo_map(0x1A03, "TPDO4 mapping parameter", []),
    ]
    if gripper:
        objs.append(var(GRIP_FORCE_INDEX, "Grip force limit", U16, "rw", "400"))
    objs += [
        # what the drive does when the connection is lost (the host's heartbeat missed, 0x1016): an option
        # code as those below
        var(0x6007, "Abort connection option code", I16, "rw", "1"),
        var(0x603F, "Error code", U16, "ro", "0", 1),
        var(0x6040, "Controlword", U16, "rw", "0", 1),
        var(0x6041, "Statusword", U16, "ro", "0", 1),
        # how the drive stops on leaving OPERATION ENABLED (CiA 402; the values the simulated
        # drives honour are in drivers.sim_state_machine.OPTION_CODES, any other is refused)
        var(0x605A, "Quick stop option code", I16, "rw", "6"),
        var(0x605B, "Shutdown option code", I16, "rw", "0"),
        var(0x605C, "Disable operation option code", I16, "rw", "1"),
        var(0x605D, "Halt option code", I16, "rw", "1"),
        var(0x605E, "Fault reaction option code", I16, "rw", "2"),
        var(0x6060, "Modes of operation", I8, "rw", "0", 1),
        var(0x6061, "Modes of operation display", I8, "ro", "0", 1),
        var(0x6064, "Position actual value", I32, "ro", "0", 1),
        var(0x6065, "Following error window", U32, "rw", "2000"),
        var(0x607A, "Target position", I32, "rw", "0", 1),
        (
            0x607D,
            "Software position limit",
            ARRAY,
            [
                (0, "Number of entries", U8, "const", "2", 0),
                (1, "Min position limit", I32, "rw", "-2147483648", 0),
                (2, "Max position limit", I32, "rw", "2147483647", 0),
            ],
        ),
        var(0x6081, "Profile velocity", U32, "rw", "10000", 1),
        var(0x6083, "Profile acceleration", U32, "rw", "100000", 1),
        var(0x6084, "Profile deceleration", U32, "rw", "100000", 1),
        var(0x6085, "Quick stop deceleration", U32, "rw", "200000"),
        var(0x6502, "Supported drive modes", U32, "ro", "0x00000001"),
    ]
    return objs


def render_eds(gripper: bool, values: dict[tuple[int, int], int] | None = None, name: str | None = None) -> str:
    """The EDS text; `values` ((index, sub-index) -> value) are DefaultValues in place of the generic
    ones, `name` the node it describes."""
    objs = _objects(gripper)
    values = dict(values or {})
    for k, (index, oname, kind, subs) in enumerate(objs):
        subs = [(sub, *rest[:3], str(values.pop((index, sub))) if (index, sub) in values else rest[3], rest[4])
                for sub, *rest in subs]
        objs[k] = (index, oname, kind, subs)
    if values:
        raise ValueError(f"no such objects in the EDS: {sorted(values)}")
    groups = {"MandatoryObjects": [], "OptionalObjects": [], "ManufacturerObjects": []}
    for o in objs:
        index = o[0]
        key = (
            "MandatoryObjects"
            if index in (0x1000, 0x1001, 0x1018)
            else "ManufacturerObjects"
            if 0x2000 <= index < 0x6000
            else "OptionalObjects"
        )
        groups[key].append(index)
    product = "gripper" if gripper else "SCARA axis" if name is None else f"SCARA axis {name}"
    lines = [
        "[FileInfo]",
        f"FileName={node_eds_file(name or ('gripper' if gripper else 'axis'))}",
        "FileVersion=1",
        "FileRevision=0",
        "EDSVersion=4.0",
        f"Description=disassembly-cell {product}, CiA 402 profile position (simulated and real)",
        "CreatedBy=drivers/eds.py",
        "",
        "[DeviceInfo]",
        "VendorName=disassembly-cell",
        f"ProductName={product}",
        "ProductNumber=0",
        "RevisionNumber=0x00010000",
        "OrderCode=",
        "BaudRate_10=0",
        "BaudRate_20=0",
        "BaudRate_50=0",
        "BaudRate_125=1",
        "BaudRate_250=1",
        "BaudRate_500=1",
        "BaudRate_800=0",
        "BaudRate_1000=1",
        "SimpleBootUpMaster=0",
        "SimpleBootUpSlave=1",
        "Granularity=8",
        "DynamicChannelsSupported=0",
        "GroupMessaging=0",
        "NrOfRXPDO=4",
        "NrOfTXPDO=4",
        "LSS_Supported=0",
        "",
        "[DummyUsage]",
        "Dummy0001=0",
        "Dummy0002=0",
        "Dummy0003=0",
        "Dummy0004=0",
        "Dummy0005=0",
        "Dummy0006=0",
        "Dummy0007=0",
        "",
    ]
    for key, indices in groups.items():
        lines.append(f"[{key}]")
        lines.append(f"SupportedObjects={len(indices)}")
        lines += [f"{i + 1}=0x{index:04X}" for i, index in enumerate(indices)]
        lines.append("")
    for index, oname, kind, subs in objs:
        if kind == VAR:
            _, _, dtype, access, default, pdo = subs[0]
            lines += [
                f"[{index:04X}]",
                f"ParameterName={oname}",
                f"ObjectType=0x{VAR:X}",
                f"DataType=0x{dtype:04X}",
                f"AccessType={access}",
                f"DefaultValue={default}",
                f"PDOMapping={pdo}",
                "",
            ]
            continue
        lines += [
            f"[{index:04X}]",
            f"ParameterName={oname}",
            f"ObjectType=0x{kind:X}",
            f"SubNumber={len(subs)}",
            "",
        ]
        for sub, sname, dtype, access, default, pdo in subs:
            lines += [
                f"[{index:04X}sub{sub:X}]",
                f"ParameterName={sname}",
                f"ObjectType=0x{VAR:X}",
                f"DataType=0x{dtype:04X}",
                f"AccessType={access}",
                f"DefaultValue={default}",
                f"PDOMapping={pdo}",
                "",
            ]
    return "\n".join(lines)


def main() -> None:
    from cell.cellconfig import default_cell
    from drivers.sim import node_eds_text

    cell = default_cell()
    for name in NODE_NAMES:
        path = Path(__file__).resolve().parent / "eds" / node_eds_file(name)
        path.write_text(node_eds_text(cell, name), encoding="utf-8")
        print(path)


if __name__ == "__main__":
    main()
