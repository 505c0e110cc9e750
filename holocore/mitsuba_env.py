"""The Mitsuba variant, chosen once per process (like Mitsuba's own examples).

CPU machines use ``llvm_ad_rgb``; it needs LLVM >= 16 (Debian's libllvm19): with older LLVM the llvm variants
abort the process on BSDF sampling, so we point Dr.Jit at libLLVM 19 before Mitsuba is imported. A CUDA
machine uses ``cuda_ad_rgb``. ``scalar_rgb`` is the (about 40x slower) fallback, never chosen silently.
"""

from __future__ import annotations

import glob
import os
from functools import lru_cache

__all__ = ["mitsuba", "variant", "is_jit"]

_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19*",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19*",
    "/usr/lib/llvm-19/lib/libLLVM.so*",
    "/usr/lib/x86_64-linux-gnu/libLLVM-1[6-9].so*",
)


def _find_libllvm() -> str | None:
    for pattern in _LLVM_GLOBS:
        hits = sorted(glob.glob(pattern))
        if hits:
            return hits[0]
    return None


def _cuda_available() -> bool:
    if os.environ.get("HOLO_NO_CUDA"):
        return False
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - torch absent or broken: no CUDA
        return False


@lru_cache(maxsize=1)
def mitsuba():
    """Import Mitsuba with the variant set (HOLO_MI_VARIANT overrides); returns the module."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = _find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi

    wanted = os.environ.get("HOLO_MI_VARIANT")
    if wanted is None:
        if _cuda_available() and "cuda_ad_rgb" in mi.variants():
            wanted = "cuda_ad_rgb"
        elif os.environ.get("DRJIT_LIBLLVM_PATH"):
            wanted = "llvm_ad_rgb"
        else:
            raise RuntimeError(
                "Mitsuba's llvm variant needs LLVM >= 16: install libllvm19 (scripts/setup.sh does) or set "
                "DRJIT_LIBLLVM_PATH; set HOLO_MI_VARIANT=scalar_rgb to accept the ~40x slower scalar variant"
            )
    mi.set_variant(wanted)
    return mi


def variant() -> str:
    return mitsuba().variant()


def is_jit() -> bool:
    return not variant().startswith("scalar")
