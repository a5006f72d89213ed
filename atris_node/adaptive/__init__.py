"""Scene adaptation: the per-frame scene assessment and the adaptive N and exposure controllers.

Owns: ``assessment`` (what a frame says about the scene) and ``controller`` (what to change).
May import: the ground floor and demod. Never node, bus, pipeline, sim, drivers or cli.
"""
