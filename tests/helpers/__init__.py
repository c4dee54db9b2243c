"""What the tests share, imported one way (``from tests.helpers.skill_fixtures import tiny_skill``): fixtures
(`skill_fixtures`, `stiffness_fixtures`, `dataset_fixtures`, `evaluation_fixtures`, `panda_fixtures`, `env_states`),
the units of the batch tests (`batch_units`), the Python reference of a compiled kernel (`closed_loop_reference`),
policies for `pih evaluate --policy tests.helpers.policies_for_tests:NAME` (`policies_for_tests`) and the recorded
cases of the flow skill (`policy_record_cases`)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
"""The repository's root (pyproject.toml, the packages, tests/): where subprocesses of the tests run."""
