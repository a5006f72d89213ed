"""ATRIS node: a modulated laser-triangulation range sensor on a CAN bus.

The data flows one way: sub-frames -> demodulation -> distortion map -> line samples
-> points -> sectors -> frames on the bus.
"""

from atris_node.errors import AtrisError

__version__ = "0.1.0"

__all__ = ["AtrisError", "__version__"]
