"""Errors meant for a person: each message is one line, and the CLI prints it and exits non-zero."""


class SwarmError(Exception):
    """Base of every user-facing error (bad input, unusable world, port in use...)."""


class WorldError(SwarmError):
    """A world that cannot be loaded or used (unknown name, unreadable or empty mesh, bad start point)."""


class PortInUseError(SwarmError):
    """A UDP/TCP port the swarm needs is already taken by another process."""


class BusError(SwarmError):
    """The Zenoh session cannot be opened or used."""
