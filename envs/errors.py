"""The one exception type of the simulation package."""


class EnvError(RuntimeError):
    """A scene, episode, demonstration or rendering request that cannot be carried out.

    The message names the offending input and what is wrong with it, in one line.
    """
