"""Recording a simulated pass through a world to MCAP: what `litevloc sim record` runs."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from litevloc.base.params.sim import SimParams
from litevloc.runtime.tools.outputs import progress
from litevloc.sim.trajectory import PassName
from litevloc.sim.world import World


def record_pass(world: World, pass_name: PassName, seed: int, duration_s: float | None, params: SimParams,
                output: Path, plot: Path | None = None, workers: int = 1) -> dict[str, Any]:
    """Simulate `pass_name` through `world` (`duration_s` simulated seconds; None: the whole
    pass) and record it to the MCAP file `output` (and, with `plot`, a top-down PNG of the
    path), its frames rendered by `workers` processes (the same bytes for any number). Returns
    the summary (`sim record --json`): message counts, bytes, wall and simulated seconds, the
    world and its collisions."""
    from litevloc.hw.streams.mcap_io import record_messages
    from litevloc.runtime.tools.parallel_frames import rendered_frames
    from litevloc.sim.source import SimSequenceSource

    t0 = time.perf_counter()
    src = SimSequenceSource(world, pass_name, seed, duration_s, params)
    t_plan = time.perf_counter() - t0
    meta = {
        "source": src.name,
        "world": json.dumps(world.summary()),
        "seed": str(seed),
        "pass": pass_name,
        "lighting": repr(src.lighting),
        "params": repr(src.params),
    }
    counts = {"frames": 0, "odometry": 0, "ground_truth": 0}
    t1 = time.perf_counter()
    with progress(src.frame_count(), f"sim {pass_name}") as bar:
        messages = src.messages(rendered_frames(src, workers))
        counts.update(record_messages(messages, output, meta, on_frame=lambda: bar.update(1)))
    dt = time.perf_counter() - t1
    if plot is not None:
        from litevloc.sim.plot import plot_world

        plot_world(world, plot, [(pass_name, src.run.T_world_base[:, :2, 3])])
    truth = change_truth_path(output)
    if not world.spec.change.unchanged:
        truth.write_text(json.dumps(world.change_truth.to_dict(), indent=1) + "\n", encoding="utf-8")
    size = output.stat().st_size
    print(
        f"wrote {output}: {counts['frames']} frames, {counts['odometry']} odometry, "
        f"{counts['ground_truth']} "
        f"ground-truth poses, {src.duration_s:.1f} s simulated, {size / 1e6:.1f} MB in {dt:.1f} s "
        f"({counts['frames'] / max(dt, 1e-9):.1f} frames/s, {workers} render process(es); planning {t_plan:.1f} s)"
    )
    return {
        "output": str(output),
        **counts,
        "bytes": size,
        "seconds": dt,
        "planning_seconds": t_plan,
        "render_workers": workers,
        "simulated_seconds": src.duration_s,
        "seed": seed,
        "pass": pass_name,
        "world": world.summary(),
        "collisions": src.run.collisions,
        "change": world.spec.change.levels(),
        "change_truth": str(truth) if not world.spec.change.unchanged else None,
    }


def change_truth_path(recording: Path) -> Path:
    """Where the ground truth of a changed building's recording lies: REC.mcap -> REC.change.json
    (for benchmarks; the map and the localizer never read it)."""
    return recording.with_suffix(".change.json")
