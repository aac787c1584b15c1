"""The simulator: worlds (meshes and their geometry), and PX4-compatible MAVLink vehicles.

- `worlds`: `load_world`, `BUILTIN_WORLDS`, `spawn_points`, `World` (distance, inside-solid, occupancy, save).
- `layouts` (built-in worlds as boxes) and `buildings` (generated ones, `gen:SEED[:options]`).
- `server`: `run_simulator` / `SimServer` host every vehicle in one process; `sim_command` is `swarm sim`.
- `vehicle` (MAVLink) over `autopilot` (flight logic) over `kinematics` (a point mass under PX4's position and
  velocity loops); `collisions`.

The simulator knows nothing of agents: it is a MAVLink autopilot and a world, nothing more.
"""
