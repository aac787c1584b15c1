"""Swarm: a peer-to-peer runtime for drone swarms that explore and map unknown buildings together."""

__version__ = "0.1.0"
