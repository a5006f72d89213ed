"""Plain CAN output: identifiers, payload scaling, E2E protection, the shipped DBC, the
publisher, the bus monitor and bus configuration.

May import: the ground floor and other ``bus.can`` modules.
"""
