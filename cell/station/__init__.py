"""The operator station: a local web page served by the cell (see server.py)."""

from cell.station.server import StationBackend, StationServer, new_token

__all__ = ["StationBackend", "StationServer", "new_token"]
