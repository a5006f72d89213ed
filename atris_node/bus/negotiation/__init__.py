"""Code negotiation between units on one bus: NAMEs, frames, peer table, plan, receive
barrier, SYNC timing, hopping, the state machine, and the simulated fleet used by tests.

May import: the ground floor and other ``bus.negotiation`` modules.
"""
