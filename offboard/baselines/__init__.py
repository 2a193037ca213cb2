"""Established trajectory-tracking controllers, as baselines for the paper's law.

- ``SE3Controller``: the geometric tracking controller on SE(3) of Lee, Leok and McClamroch
  (CDC 2010), in the form RotorPy's ``SE3Control`` implements it, written in NED/FRD.
- ``Px4PositionController``: PX4's multicopter position controller (``mc_pos_control``:
  P on position, PID on velocity, acceleration to a thrust vector with a tilt limit), whose
  attitude setpoint PX4's attitude and rate controllers then fly (in this repository:
  ``sitl_plant.inner_loops.Px4Loop``, the plant's ``px4`` inner loop).

Both are pure objects like ``RosalesController``: ``step(state, reference) -> command`` once per
control sample and ``reset()``; no sockets, clocks or files. Each command carries the collective
thrust (N) and an attitude (and body-rate) target; the SE(3) controller also gives its
attitude law as a torque function for the physics rate (``SE3Controller.torque``).
"""

from offboard.baselines.px4 import Px4Gains, Px4PositionController
from offboard.baselines.se3 import AttitudeTarget, SE3Controller, SE3Gains

__all__ = ["AttitudeTarget", "Px4Gains", "Px4PositionController", "SE3Controller", "SE3Gains"]
