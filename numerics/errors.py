"""The one exception type of the numerics package, and how a message quotes a value it refuses."""


class NumericsError(ValueError):
    """Invalid numeric input: NaN, wrong shapes, non-unit quaternions, matrices that are no rotation, singular or not
    square (`numerics.quaternion`, `numerics.small_linalg`).

    The message names the offending input and what is wrong with it, in one line. `rflow.errors.RFlowError` is a
    subclass, so ``except NumericsError`` catches the errors of both packages.
    """


def shown(value: object, limit: int = 80) -> str:
    """``repr(value)`` on one line (runs of whitespace, newlines of an array's repr among them, made one space) and
    cut to ``limit`` characters with "...": how an error message quotes a value it refuses."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."
