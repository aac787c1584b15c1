"""Deployment: the simulated swarm as Docker containers (`swarm deploy compose`, compose.py), and the command
each agent container runs to impair its own radio before it starts (`swarm deploy netem`, radio.py).

The image is built from deploy/Dockerfile; docs/deploy.md tells how to run it. Docker is not needed to write or
check the files: the tests validate them with the `docker-compose config` parser, and the netns swarm
(swarm.netem) is the tested equivalent of the running deployment. Nothing is imported here, so that the
agent container's `swarm deploy netem` does not load Open3D (compose.py does, to check the world).
"""
