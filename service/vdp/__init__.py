"""vdp: CAN-bus field logging and two-stage estimation of vehicle dynamic parameters.

The estimation core (:mod:`vdp.core`) is pure numpy; everything that touches a
bus, a file, the clock or HTTP is an adapter around it.
"""

__version__ = "0.1.0"
