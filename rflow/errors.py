"""The one exception type of the RiemannianFlow package."""


class RFlowError(ValueError):
    """Invalid data or model input: NaN, wrong shapes, non-unit quaternions, non-SPD matrices, bad checkpoints.

    The message names the offending input and what is wrong with it, in one line.
    """


def shown(value: object, limit: int = 80) -> str:
    """``repr(value)`` on one line (runs of whitespace, newlines of an array's repr among them, made one space) and
    cut to ``limit`` characters with "...": how an error message quotes a value it refuses."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."
