"""Long batch runs that survive faults: a JSON Lines journal of finished units (`journal`) and a supervisor
that runs units in spawned processes or on Ray (`runner`), running a unit whose worker was lost again and
listing every infrastructure event (`supervision`). Knows nothing of MuJoCo or torch: a unit is any picklable
payload, a record any JSON object."""

from batch.config import BACKENDS, BatchConfig
from batch.errors import BatchError, WorkerInitError
from batch.journal import Journal
from batch.runner import BatchOutcome, run_batch
from batch.supervision import describe_event

__all__ = ["BACKENDS", "BatchConfig", "BatchError", "BatchOutcome", "Journal", "WorkerInitError", "describe_event", "run_batch"]
