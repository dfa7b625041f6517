"""Fixtures of the loop tests: synthetic scenes built once per session (~1 s each)."""

from helpers.loop_scenes import corridor, revisit_mono, revisit_rgbd  # noqa: F401
