"""Parameter dataclasses of the subsystems (frozen, validated in `__post_init__`).

Each module holds the parameters of one subsystem; the configuration tree
(`config/schema.py`) reaches every one of them. Each field has its typed default and, on the
line directly above it, a one-line `#` description that `litevloc config show` prints.
Only the standard library and numpy are imported here.
"""
