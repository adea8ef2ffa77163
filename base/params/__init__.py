"""Parameter dataclasses of the subsystems (frozen; each field declared once with
`litevloc.base.settings.setting`, which validates it).

Each module holds the parameters of one subsystem; the configuration tree
(`config/schema.py`) reaches every one of them. Each field's declaration gives its typed
default, a description that stands alone, its unit and its range, which `litevloc config
show` and docs/parameters.md print. Only the standard library and numpy are imported here.
"""
