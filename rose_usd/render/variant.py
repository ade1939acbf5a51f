"""Choosing and setting Mitsuba's variant.

Order of preference: ``cuda_ad_rgb`` when an NVIDIA GPU is usable, ``llvm_ad_rgb`` when an LLVM
Dr.Jit can use is found (Debian's libllvm19: its LLVM 15 crashes Mitsuba), ``scalar_rgb`` otherwise
(correct but slow). ``ROSE_MITSUBA_VARIANT`` forces one.
"""

from __future__ import annotations

import functools
import glob
import os
import shutil
import warnings

from rose_usd.errors import EnvironmentProblem

# LLVM libraries known to work with Dr.Jit 1.5, best first. Debian's default LLVM 15 crashes.
_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/llvm-19/lib/libLLVM.so.19.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.18.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-18.so",
)


def find_llvm() -> str | None:
    """Path of a usable libLLVM for Dr.Jit's LLVM backend, or None."""
    preset = os.environ.get("DRJIT_LIBLLVM_PATH")
    if preset and os.path.exists(preset):
        return preset
    for path in _LLVM_CANDIDATES:
        if os.path.exists(path):
            return path
    for path in sorted(glob.glob("/usr/lib/llvm-*/lib/libLLVM.so.*"), reverse=True):
        version = path.rsplit("llvm-", 1)[-1].split("/", 1)[0]
        if version.isdigit() and int(version) >= 16:
            return path
    return None


def _gpu_present() -> bool:
    return shutil.which("nvidia-smi") is not None or os.path.exists("/dev/nvidia0")


@functools.cache
def mitsuba():
    """Import Mitsuba with the best variant set; returns the ``mitsuba`` module."""
    forced = os.environ.get("ROSE_MITSUBA_VARIANT")
    llvm = find_llvm()
    if llvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm
    import mitsuba as mi

    candidates = [forced] if forced else []
    if not forced:
        if _gpu_present():
            candidates.append("cuda_ad_rgb")
        if llvm:
            candidates.append("llvm_ad_rgb")
        candidates.append("scalar_rgb")
    errors = []
    for name in candidates:
        if name not in mi.variants():
            errors.append(f"{name}: not built")
            continue
        try:
            mi.set_variant(name)
            # a variant can be settable yet fail at first JIT use (no driver, broken LLVM)
            if name != "scalar_rgb":
                import drjit as dr

                dr.eval(mi.Float(1.0) + 1.0)
            if name == "scalar_rgb" and not forced:
                warnings.warn(
                    "Mitsuba runs its scalar_rgb variant (no usable LLVM 16+ found): rendering is slow. "
                    "Install Debian's libllvm19 (./dev.sh does) or set DRJIT_LIBLLVM_PATH.",
                    stacklevel=2,
                )
            return mi
        except Exception as exc:  # a broken backend must fall through to the next variant
            errors.append(f"{name}: {exc}")
    raise EnvironmentProblem(
        f"no Mitsuba variant works ({'; '.join(errors)})",
        hint="install Debian's libllvm19 and set DRJIT_LIBLLVM_PATH to libLLVM.so.19.1",
    )
