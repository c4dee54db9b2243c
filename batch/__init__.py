"""Long batch runs that survive faults: a JSON Lines journal of finished units (`journal`) and a supervisor
that runs units in spawned processes or on Ray, recording a dead or overrunning worker as a failed unit
(`runner`). Knows nothing of MuJoCo or torch: a unit is any picklable payload, a record any JSON object."""

from batch.errors import BatchError
from batch.journal import Journal
from batch.runner import BACKENDS, BatchConfig, BatchOutcome, run_batch

__all__ = ["BACKENDS", "BatchConfig", "BatchError", "BatchOutcome", "Journal", "run_batch"]
