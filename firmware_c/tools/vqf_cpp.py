"""The folder of VQF's C++ sources inside the installed ``vqf`` package (``vqf.get_cpp_path()``).

VQF (Laidig & Seel, "VQF: Highly Accurate IMU Orientation Estimation with Bias Estimation and
Magnetic Disturbance Rejection", Information Fusion 2023; MIT licence) ships its C++ with its
Python package; setup.py and the Cortex-M4 build (firmware_c/Makefile) compile those files as they
are. ``vqf.get_cpp_path()`` needs ``pkg_resources``, which setuptools 81 and later no longer ship,
so the same folder is then taken with ``importlib.resources``.

Usage: ``python3 vqf_cpp.py`` prints the folder.
"""
from __future__ import annotations

import importlib.resources


def vqf_cpp_dir() -> str:
    """The folder holding ``vqf.hpp`` and ``vqf.cpp`` of the installed ``vqf`` package."""
    import vqf

    try:
        return str(vqf.get_cpp_path())
    except ImportError:  # pkg_resources is gone (setuptools >= 81)
        return str(importlib.resources.files("vqf") / "cpp")


if __name__ == "__main__":
    print(vqf_cpp_dir())
