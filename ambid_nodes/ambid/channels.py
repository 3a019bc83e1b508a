"""Channel names and order, the same everywhere: bearing A x, bearing B x, bearing A y, bearing B y.

The axes are turned 45 deg from the vertical; axial positions are measured
from the middle of the shaft, A on the negative side.
"""

AXES = ("a_x", "b_x", "a_y", "b_y")
DISPLACEMENT_NAMES = tuple(f"y_{a}" for a in AXES)  # measured displacements [m]
CURRENT_NAMES = tuple(f"u_{a}" for a in AXES)  # control currents [A]
