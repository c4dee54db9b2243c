"""Pictures of episodes: headless OpenGL (`rendering`), episode videos (`video`) and the figures of skills, evaluations
and the protocol (`figures`).
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "gl_context": "envs.media.rendering",
    "use_headless_rendering": "envs.media.rendering",
    "EpisodeVideo": "envs.media.video",
    "VideoConfig": "envs.media.video",
    "plot_outcomes": "envs.media.figures",
    "plot_skill": "envs.media.figures",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
