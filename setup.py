"""Builds the CPU rasterizer kernel at install time; everything else is in pyproject.toml.

``gsslam/mapping/rasterize_cpu.c`` is a plain C library loaded with ctypes (no Python API), compiled
twice (float and double) into one shared library ``gsslam/mapping/_rasterize_cpu<EXT_SUFFIX>``. The
recipe (flags, variants, source hash) lives in ``gsslam/mapping/rasterize_build.py`` so that the
first-use build of an edited checkout follows the same one. Without a working C compiler the install
still succeeds: the kernel is then built at first use, or the pure-torch reference is used.
"""

import importlib.util
import os
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

_HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location(
    "_gsslam_rasterize_build", _HERE / "gsslam" / "mapping" / "rasterize_build.py"
)
recipe = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(recipe)


class BuildCtypesLibrary(build_ext):
    """build_ext for a library without Python API: one source compiled once per variant, then linked."""

    def build_extension(self, ext: Extension) -> None:
        if ext.name != recipe.EXT_NAME:
            super().build_extension(ext)
            return
        source = Path(ext.sources[0])
        key = recipe.source_key(_HERE / source if not source.is_absolute() else source)
        objects = []
        for tag, real, exp in recipe.VARIANTS:
            objects += self.compiler.compile(
                [str(source)],
                output_dir=os.path.join(self.build_temp, tag),
                macros=recipe.macros(tag, real, exp, key),
                extra_postargs=list(recipe.CFLAGS),
            )
        self.compiler.link_shared_object(
            objects,
            self.get_ext_fullpath(ext.name),
            libraries=list(recipe.LIBRARIES),
            extra_postargs=list(recipe.LDFLAGS),
            target_lang="c",
        )


setup(
    ext_modules=[
        # optional: a failed compile only warns; gsslam then builds at first use or uses torch
        Extension(recipe.EXT_NAME, sources=["gsslam/mapping/rasterize_cpu.c"], optional=True)
    ],
    cmdclass={"build_ext": BuildCtypesLibrary},
)
