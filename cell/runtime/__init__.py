"""The cell at run time: locating the parts, the pick motion, the loop, the simulated world."""
