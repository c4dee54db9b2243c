"""The one exception type of the RiemannianFlow package."""


class RFlowError(ValueError):
    """Invalid data or model input: NaN, wrong shapes, non-unit quaternions, non-SPD matrices, bad checkpoints.

    The message names the offending input and what is wrong with it, in one line.
    """
