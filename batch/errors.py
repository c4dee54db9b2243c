"""The one exception type of the batch package."""


class BatchError(RuntimeError):
    """A batch run or journal that cannot be started or continued; the message names the input and the problem."""


class WorkerInitError(BatchError):
    """A worker's ``init`` raised (the batch's set-up is at fault, not the machine): ``kind`` is the exception's type
    name and ``detail`` the first line of its message, so a caller can report an error of its own input as its own
    (e.g. a user's policy factory that fails)."""

    def __init__(self, kind: str, detail: str):
        super().__init__(f"a worker failed to start: {kind}: {detail}" if detail else f"a worker failed to start: {kind}")
        self.kind, self.detail = kind, detail
