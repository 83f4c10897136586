"""The error both vector-env backends raise when a worker dies, in a module of its own so that the Ray
backend (`ray_vec_env`, an optional extra) and `vec_env` share it without importing each other."""


class WorkerCrashedError(RuntimeError):
    """A worker of a vector env died (killed, segfault, out of memory, its node lost); the message names
    the env index."""
