"""ambid numerical core: AMB models, controllers, excitation design, FRF
estimation, fitting and session I/O.

Pure numpy/scipy; nothing in this package imports rclpy, so every function
here can be used from a notebook on recorded data.
"""

__version__ = "0.1.0"
