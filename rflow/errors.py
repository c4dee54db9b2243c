"""The one exception type of the RiemannianFlow package."""

from numerics.errors import NumericsError


class RFlowError(NumericsError):
    """Invalid data or model input: NaN, wrong shapes, non-unit quaternions, non-SPD matrices, bad checkpoints.

    The message names the offending input and what is wrong with it, in one line. A subclass of
    `numerics.errors.NumericsError` (a ValueError), which the quaternion algebra and the small linear algebra raise.
    """
