"""One unit and fleets of them: lifecycle, wiring from the configuration, process supervision.

Owns: ``unit`` (lifecycle and real-time loop), ``measure`` (the per-map work), ``wiring``,
``runner``, ``launch``, ``soak``, ``fleetview``, ``snapshot``.
May import: everything below it (ground floor, demod, pipeline, adaptive, bus, drivers).
Never cli or bench.
"""
