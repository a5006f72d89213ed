"""The CANopen device: a canopen ``LocalNode`` from the shipped EDS, with TPDOs for the frames.

May import: the ground floor and ``bus.can`` (payload scaling).
"""
