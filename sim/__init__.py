"""CPU simulator of indoor buildings: RGB-D sequences with ground truth, and a closed loop.

* `spec`: `WorldSpec`, a building generator's parameters (`config/worlds/*.yaml`).
* `world`: a generated building (`load_world`), made by `layout` (rooms, corridors, doors,
  walls), `furnish` (furniture and clutter), `decor` (wall materials and pictures) and
  `goals` (the goal-image rule); its parts are in `elements`.
* `pictures`, `materials`, `textures`: generated pictures, wall and furniture surfaces (and
  the first simulator's CC0 / public-domain photographs), baked into texture arrays.
* `render`: vectorised ray caster, colour + metric depth (`Renderer.render`).
* `realism`: seeded lighting, noise, blur, depth noise and holes.
* `simulator`: closed loop `Simulator.reset(pose)` / `step(v, omega, dt)` -> `SimStep`.
* `trajectory`: route planning, mapping/query passes, waypoint follower.
* `local_planner`, `search`: the simulated robot's own local planner and its search for a first fix.
* `source`: `SimSequenceSource`, a `StreamSource` for recording (`litevloc sim record`).
* `plot`: top-down plan PNG and contact sheets.
"""
