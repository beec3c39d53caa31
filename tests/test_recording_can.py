"""A recording's CAN log filled by the drivers' recorder during a real (simulated-drive) session."""

from cell.recording import RecordingReader, RecordingWriter
from drivers.session import simulated_cell


def test_can_traffic_of_a_simulated_cell_session_reads_back(tmp_path):
    rec = RecordingWriter(tmp_path / "r")
    # the drivers record like candump: a bus of their own on the channel hears host and drives
    with simulated_cell(record=rec.can_log_path):
        pass
    rec.close("complete")
    r = RecordingReader(tmp_path / "r")
    assert r.complete
    msgs = r.can_messages()
    ids = {m.arbitration_id for m in msgs}
    assert 0x000 in ids  # NMT from the host
    assert {0x601, 0x605} <= ids and {0x581, 0x585} <= ids  # SDO requests (host) and answers (drives)
    assert {0x181, 0x185} <= ids  # TPDO1 of the drives
    times = [m.timestamp for m in msgs]
    assert times == sorted(times)
