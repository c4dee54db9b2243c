"""The work cell as built in MJCF, without episode stepping: the peg and hole cross-sections (`shapes`), the shape
sorter with its holes and chamfers (`sorter`), the peg (`peg`), the rubber finger pads (`pads`), contact parameters
(`contact`), what scene to build and its goal geometry (`scene_config`, no MuJoCo), the composed scene (`scene`) and
what the success check needs to know of a hole (`hole`). Knows nothing of tasks, episodes or policies.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "SceneConfig": "envs.cell.scene_config",
    "Scene": "envs.cell.scene",
    "SceneIds": "envs.cell.scene",
    "build_scene": "envs.cell.scene",
    "HoleSpec": "envs.cell.hole",
    "SHAPES": "envs.cell.shapes",
    "CrossSection": "envs.cell.shapes",
    "peg_cross_section": "envs.cell.shapes",
    "ContactConfig": "envs.cell.contact",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
