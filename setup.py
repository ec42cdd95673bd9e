"""Builds the C kernels (firmware_c/) into limbstream/_kernels*.so on pip install.

The library has no Python API of its own: limbstream.kernel loads it with ctypes.
The compile flags are the ones the Cortex-M4 build uses for its arithmetic
(-ffp-contract=off), so both targets compute the same segment points.
"""
from glob import glob

from setuptools import Extension, setup

KERNEL_CFLAGS = ["-std=c99", "-O3", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]

setup(
    ext_modules=[
        Extension(
            "limbstream._kernels",
            sources=sorted(glob("firmware_c/src/*.c")),
            include_dirs=["firmware_c/include"],
            depends=sorted(glob("firmware_c/include/*.h") + glob("firmware_c/src/*.h")),
            extra_compile_args=KERNEL_CFLAGS,
        )
    ]
)
