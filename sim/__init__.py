"""CPU simulator of indoor worlds: RGB-D sequences with ground truth, and a closed loop.

* `world`: procedural floor plans from a seed + YAML (`config/worlds/*.yaml`; `load_world`).
* `textures`: CC0 / public-domain photos and materials from scikit-image's data folder.
* `render`: vectorised ray caster, colour + metric depth (`Renderer.render`).
* `realism`: seeded lighting, noise, blur, depth noise and holes.
* `params`: `SimParams` (robot, camera mount, rates), the `sim` config section.
* `simulator`: closed loop `Simulator.reset(pose)` / `step(v, omega, dt)` -> `SimStep`.
* `trajectory`: route planning, map/query passes, waypoint follower.
* `source`: `SimSequenceSource`, a `StreamSource` for recording (`litevloc sim record`).
* `plot`: top-down plan PNG and contact sheets.
"""
