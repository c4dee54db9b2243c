"""The one exception type of the controllers package."""


class ControllerError(RuntimeError):
    """A controller or inverse-kinematics request that cannot be carried out (bad gains, unreachable pose).

    The message names the offending input and what is wrong with it, in one line.
    """
