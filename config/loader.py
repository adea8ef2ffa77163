"""Strict YAML -> frozen dataclass loading: re-exported from the bottom layer `litevloc.base.loader`
(moved there so `hw` reads its world files without importing `config`)."""

from __future__ import annotations

from litevloc.base.loader import (
    ConfigError as ConfigError,
)
from litevloc.base.loader import (
    apply_override as apply_override,
)
from litevloc.base.loader import (
    from_mapping as from_mapping,
)
from litevloc.base.loader import (
    load_yaml as load_yaml,
)
