"""The cell at run time: run control between operator and loop, and the cell loop."""
