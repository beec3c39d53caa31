"""The operator station: a local web page served by the cell (see server.py).

`StationServer(backend, control)` serves the page; `LiveView` is the backend a cell loop
fills in (frame, outlines, proposal, teach callback); `cell.station.demo.DemoCell` is a
small simulated cell for `cell station` and the tests.
"""

from cell.station.live import LiveView
from cell.station.server import StationBackend, StationServer, new_token

__all__ = ["LiveView", "StationBackend", "StationServer", "new_token"]
