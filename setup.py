"""Builds the optional C accelerators; the package works (slower) without them.

An in-place build (``pip install -e .``) also byte-compiles the packages' sources, as pip does when it installs a
wheel: a Python that writes no bytecode (``PYTHONDONTWRITEBYTECODE``, common in containers) would otherwise compile
them at every ``steval`` start (0.1 to 0.4 s). The bytecode is checked by timestamp, so Python recompiles a source
edited since, in memory.
"""

import compileall
import py_compile
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

_PACKAGES = ("steval_link", "viewer")  # the source folders of the packages (viewer/ is steval_viewer)


class _BuildExt(build_ext):
    def run(self):
        super().run()
        if self.inplace:
            root = Path(__file__).resolve().parent
            for folder in _PACKAGES:
                mode = py_compile.PycInvalidationMode.TIMESTAMP  # (also where SOURCE_DATE_EPOCH asks for hashes)
                compileall.compile_dir(str(root / folder), quiet=1, invalidation_mode=mode)


_FLAGS = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math", "-std=c99"]

setup(
    cmdclass={"build_ext": _BuildExt},
    ext_modules=[
        Extension(
            "steval_link._st_mahony_native",
            sources=["steval_link/_st_mahony_native.c"],
            depends=["steval_link/_native_buffers.h"],
            extra_compile_args=_FLAGS,
            optional=True,
        ),
        Extension(
            "steval_link.estimators._ekf_native",
            sources=["steval_link/estimators/_ekf_native.c"],
            depends=["steval_link/_native_buffers.h"],
            extra_compile_args=_FLAGS,
            optional=True,
        ),
        Extension(
            "steval_link.emulation._core",
            sources=["steval_link/emulation/_core.c"],
            extra_compile_args=_FLAGS,
            optional=True,
        ),
    ],
)
