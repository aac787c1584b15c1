"""Swarm: a peer-to-peer runtime for drone swarms that explore and map unknown buildings together."""

from swarm.lean_open3d import defer_plotly

defer_plotly()  # before any module of the package imports open3d

__version__ = "0.1.0"
