"""The bottom layer of LiteVLoc (`litevloc.base`): what every other package may use.

* `errors`: `LiteVLocError`, the base class of every domain error (the CLI catches it).
* `geometry`: SE(3) and pinhole geometry on numpy arrays (frame and unit conventions).
* `loader`: strict YAML -> frozen dataclass loading (`ConfigError`).
* `frames`: `parse_frames` for `--frames A:B`.
* `process_usage`: this process's CPU seconds and memory (RSS now, peak).
* `stats`: percentiles of samples (latencies, errors) for status reports and benchmarks.
* `params`: the parameter dataclasses that the configuration tree (`config/schema.py`)
  references, so `config` imports no algorithm or hardware module.

This package imports only the standard library, numpy and PyYAML: `hw`, `models`,
`pipelines`, `runtime` and `config` import it, never the other way round.
"""
