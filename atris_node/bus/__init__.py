"""Everything that goes over the wire, split by protocol: ``can``, ``canopen``, ``negotiation``.

May import: the ground floor only (types, config, errors, codes). Never pipeline, demod,
adaptive, sim, node, drivers or cli: the bus carries values, it does not compute them.
"""
