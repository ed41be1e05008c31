"""Builds the optional C accelerators; the package works (slower) without them."""

import sys

from setuptools import Extension, setup

_FLAGS = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math", "-std=c99"]

setup(
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
    ]
)
