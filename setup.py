"""Builds the C kernels (firmware_c/src: the portable kernel, also built for the Cortex-M4;
firmware_c/host: the host-only C of the gateways, device clocks and bindings) into
limbstream/_kernels*.so on pip install, and maps the repository's part folders into the one
import package: services/ -> limbstream.services, device_emulator/ ->
limbstream.device_emulator, dashboard/ (the page) -> limbstream.dashboard.

The library has no Python API of its own: limbstream.kernel loads it with ctypes.
The compile flags are the ones the Cortex-M4 build uses for its arithmetic
(-ffp-contract=off), so both targets compute the same segment points.

VQF, the orientation filter, is C++ from the `vqf` package, kept in firmware_c/vqf with its
filters' precision made a type (its README): its vqf.cpp, compiled inside the C wrapper
firmware_c/src/lsw_vqf.cpp into a static library (build_clib, with C++ flags) that setuptools
links into the extension, with the elementary functions it calls from firmware_c/src/lsw_math.hpp
(not libm: the firmware runs the same source).
"""
from glob import glob

from setuptools import Extension, find_packages, setup

KERNEL_CFLAGS = ["-std=c99", "-O3", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]
VQF_CXXFLAGS = ["-std=c++17", "-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-exceptions", "-fno-rtti",
                "-Wall"]
"""The M4 build's (firmware_c/Makefile VQF_CXXFLAGS): no FMA, no asserts. The host library holds VQF in
both precisions (LSW_VQF_BOTH), chosen per device at run time; the firmware one."""
VQF_DIR = "firmware_c/vqf"
"""VQF's C++ source, from the `vqf` package (docs/kernel.md, "Where VQF comes from")."""
VQF_LIBRARY = ("lsw_vqf", {
    "sources": ["firmware_c/src/lsw_vqf.cpp"],  # includes VQF_DIR/vqf.cpp
    "include_dirs": ["firmware_c/include", VQF_DIR],
    "macros": [("VQF_SINGLE_PRECISION", None), ("NDEBUG", None), ("LSW_VQF_BOTH", "1")],
    "cflags": VQF_CXXFLAGS,
    "obj_deps": {"": sorted(glob("firmware_c/include/*.h")) + ["firmware_c/src/lsw_ff.hpp", "firmware_c/src/lsw_math.hpp"] + [f"{VQF_DIR}/{name}" for name in ("vqf.cpp", "vqf.hpp")]},
})

PARTS = ("services", "device_emulator", "dashboard")
"""Folders of the repository that install as subpackages of limbstream."""
DATA_PACKAGES = ["limbstream.dashboard.vendor"]
"""Folders of data only (no __init__.py), declared so that their files ship (pyproject.toml,
package-data) and setuptools does not warn about a package it would have to guess."""
PACKAGES = find_packages(include=["limbstream", "limbstream.*"]) + [
    f"limbstream.{name}" for part in PARTS for name in find_packages(include=[part, f"{part}.*"])] + DATA_PACKAGES

setup(
    packages=PACKAGES,
    package_dir={f"limbstream.{part}": part for part in PARTS},
    libraries=[VQF_LIBRARY],
    ext_modules=[
        Extension(
            "limbstream._kernels",
            sources=sorted(glob("firmware_c/src/*.c")) + sorted(glob("firmware_c/host/*.c")),
            include_dirs=["firmware_c/include", "firmware_c/host"],
            depends=sorted(glob("firmware_c/include/*.h") + glob("firmware_c/src/*.h") + glob("firmware_c/host/*.h")),
            extra_compile_args=KERNEL_CFLAGS,
        )
    ]
)
