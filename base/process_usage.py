"""This process's CPU time and memory, as the commands' summaries and the benchmarks report them."""

from __future__ import annotations

import resource


def cpu_seconds(who: int = resource.RUSAGE_SELF) -> float:
    """User + system CPU seconds of this process, all its threads (`resource.RUSAGE_CHILDREN`:
    of its children that ended and were waited for)."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far (MB; Linux ru_maxrss is in KB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def memory_mb() -> dict[str, float]:
    """{"rss": resident set size now, "peak": its peak (VmHWM)} of this process in MB, from
    /proc/self/status; NaN where the system has no such file (not Linux)."""
    out = {"rss": float("nan"), "peak": float("nan")}
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    out["rss" if line.startswith("VmRSS") else "peak"] = int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return out
