"""Demonstrations: the scripted expert's demos recorded in physics (`record`), the demo file (`file`), import from
other recordings (`importing`) and the demos as a real cell records them (`noise`). Export is envs.datasets.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "collect_demos": "envs.demos.record",
    "DemoSet": "envs.demos.file",
    "load_demos": "envs.demos.file",
    "save_demos": "envs.demos.file",
    "RecordedDemos": "envs.demos.importing",
    "import_demos": "envs.demos.importing",
    "DemoNoise": "envs.demos.noise",
    "add_demo_noise": "envs.demos.noise",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
