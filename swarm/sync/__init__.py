"""Map sharing between agents over the bus: patches pushed in chunks on seal, digests in heartbeats, missing
patches pulled from the nearest holder, every held patch served (see `swarm.sync.service`)."""
