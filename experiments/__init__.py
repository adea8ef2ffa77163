"""Experiments (`litevloc.experiments`): the benchmarks' logic as library functions.

Each module runs one experiment on library calls (never on CLI modules) and returns its
results as plain data; `bench/<name>.py` scripts and the `litevloc bench` commands parse
arguments, call one function here, print its table and write its JSON under `out/bench/`.
This package sits just below the command line: it may import `runtime` (not `cli`),
`sim`, `pipelines`, `models`, `hw`, `config` and `base`; only `bench/` and `cli`
import it.
"""
