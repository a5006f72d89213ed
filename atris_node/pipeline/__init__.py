"""The measurement stages, in the order a distortion map flows through them.

Owns: bands → peaks → identity → geometry → sectors → obstacles (→ objects), with roi and
interference beside them, each stage's compiled loops in ``<stage>_kernels.py``, and
:class:`~atris_node.pipeline.chain.Pipeline` in ``chain.py``, which runs them in that order.
May import: the ground floor (types, config, errors, codes, jit, calibration, mounting) and
demod. Never node, bus, adaptive, sim, drivers, cli or bench.
This ``__init__`` imports nothing, so ``pipeline.geometry`` loads without the kernels.
"""
