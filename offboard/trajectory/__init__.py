"""Trajectories in the local NED frame; see ``base.Trajectory``."""

from offboard.trajectory.base import Phase, Reference, Trajectory

__all__ = ["Phase", "Reference", "Trajectory"]
