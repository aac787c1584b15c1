import sys

from swarm.cli import main

if __name__ == "__main__":  # not again in a process pool's spawned worker, which imports this as __mp_main__
    sys.exit(main())
