import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # as the agents run; Open3D reads it at first use
