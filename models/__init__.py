"""Model layer: onnxruntime inference wrappers, the model registry and the torch exporters.

Run-time imports never pull torch: `litevloc.models.export` (torch -> ONNX) is the only
sub-package that imports it, and only `litevloc models export` loads it.

Public interface::

    from litevloc.models.types import Features, Matches, FeatureExtractor, Matcher, PlaceRecognizer
    from litevloc.base.params.models import ModelsConfig
    from litevloc.models.registry import (ModelError, default_cache_dir, load_extractor,
                                          load_matcher, load_place_recognizer)
"""
