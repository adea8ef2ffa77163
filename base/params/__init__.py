"""Parameter dataclasses of the subsystems (frozen, validated in `__post_init__`).

Each module holds the parameters of one subsystem; the subsystem's own module re-exports
them under their old names. Only the standard library and numpy are imported here.
"""
