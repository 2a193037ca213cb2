"""sitl_plant: a Python software-in-the-loop quadrotor that behaves like a PX4 autopilot on MAVLink.

Layout (pure math in the middle, I/O at the edges):

- ``sitl_plant.dynamics``: pure models ``f(x, input, params) -> xdot`` (paper model, rigid body),
  frames and rotations, wind and sensor models, the RK4 integrator.
- ``offboard.model.vehicle``: ``VehicleParams`` and their TOML loader.
- ``sitl_plant.simulation``: ``VehicleSim``, which steps a model at the physics rate with an
  inner loop, ground contact, wind and sensors; no sockets.
- the MAVLink autopilot (``sitl_plant.autopilot``, ``sitl_plant.link``, ``sitl_plant.cli``) sits on top.
"""
