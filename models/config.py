"""Parameters of the model layer: re-exported from the bottom layer `litevloc.base.params.models`."""

from __future__ import annotations

from litevloc.base.params.models import (
    DEFAULT_PLACE_RECOGNIZER as DEFAULT_PLACE_RECOGNIZER,
)
from litevloc.base.params.models import (
    EXTRACTORS as EXTRACTORS,
)
from litevloc.base.params.models import (
    MATCHERS as MATCHERS,
)
from litevloc.base.params.models import (
    PLACE_RECOGNIZERS as PLACE_RECOGNIZERS,
)
from litevloc.base.params.models import (
    ModelsConfig as ModelsConfig,
)
