"""Code negotiation between units on one bus: NAMEs, frames, peer table, plan, receive
barrier, SYNC timing, hopping, bus link, inbox (what peers said), row and plan choice, the
state machine (``machine.Negotiator``) with its services (contest, agreement, syncmode,
lease), and the simulated fleet used by tests.

May import: the ground floor and other ``bus.negotiation`` modules.
"""
