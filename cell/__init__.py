"""Robot-cell controller for automated disassembly.

Data flow, one module per arrow:
frame -> contours (vision) -> candidate points (grasp.candidates) -> valid points
(grasp.learning) -> reachable pairs (grasp.cascade) -> valid sets -> selected grasp
(grasp.synthesis) -> arm/hand configuration (configuration) -> joint and gripper
commands (drivers) -> CAN frames.
"""

from cell.numerics import pin_blas

pin_blas()  # before anything loads numpy: the same kernels on every x86-64 machine (cell/numerics.py)

__version__ = "0.1.0"
