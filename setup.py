"""Builds the C kernels (firmware_c/src: the portable kernel, also built for the Cortex-M4;
firmware_c/host: the host-only C of the gateways, device clocks and bindings) into
limbstream/_kernels*.so on pip install, and maps the repository's part folders into the one
import package: services/ -> limbstream.services, device_emulator/ ->
limbstream.device_emulator, dashboard/ (the page) -> limbstream.dashboard.

The library has no Python API of its own: limbstream.kernel loads it with ctypes.
The compile flags are the ones the Cortex-M4 build uses for its arithmetic
(-ffp-contract=off), so both targets compute the same segment points.
"""
from glob import glob

from setuptools import Extension, find_packages, setup

KERNEL_CFLAGS = ["-std=c99", "-O3", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]

PARTS = ("services", "device_emulator", "dashboard")
"""Folders of the repository that install as subpackages of limbstream."""
PACKAGES = find_packages(include=["limbstream", "limbstream.*"]) + [
    f"limbstream.{name}" for part in PARTS for name in find_packages(include=[part, f"{part}.*"])]

setup(
    packages=PACKAGES,
    package_dir={f"limbstream.{part}": part for part in PARTS},
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
