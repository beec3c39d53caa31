"""Robot-cell controller for automated disassembly.

Data flow, one module per arrow:
frame -> contours (vision) -> candidate points (grasp.candidates) -> valid points
(grasp.learning) -> reachable pairs (grasp.cascade) -> valid sets -> selected grasp
(grasp.synthesis) -> arm/hand configuration (configuration) -> joint and gripper
commands (drivers) -> CAN frames.
"""

from cell.numerics import limit_image_pixels, pin_blas

pin_blas()  # before anything loads numpy: the same kernels on every x86-64 machine (cell/numerics.py)
limit_image_pixels()  # before anything loads cv2: an image too large for the memory is refused, not decoded

__version__ = "0.1.0"
