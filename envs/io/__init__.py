"""pih's file outputs: the owned-output policy (`owned_output`: the marker pih writes into what it made, the checks
before overwriting, atomic writes of JSON, text, npz and figures), reading an .npz safely (`npz`) and values made
JSON-ready (`jsonable`). Below every other sub-package of envs.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "AtomicOutput": "envs.io.owned_output",
    "check_output": "envs.io.owned_output",
    "check_output_folder": "envs.io.owned_output",
    "save_figure": "envs.io.owned_output",
    "save_npz": "envs.io.owned_output",
    "strict_json": "envs.io.owned_output",
    "write_json": "envs.io.owned_output",
    "write_text": "envs.io.owned_output",
    "open_npz": "envs.io.npz",
    "to_jsonable": "envs.io.jsonable",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
