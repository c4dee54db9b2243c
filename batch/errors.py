"""The one exception type of the batch package."""


class BatchError(RuntimeError):
    """A batch run or journal that cannot be started or continued; the message names the input and the problem."""
