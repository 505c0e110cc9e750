"""The Mitsuba variant, chosen once per process (like Mitsuba's own examples).

CPU machines use ``llvm_ad_rgb``; it needs LLVM >= 16 (Debian's libllvm19): with older LLVM the llvm variants
abort the process on BSDF sampling, so we point Dr.Jit at libLLVM 19 before Mitsuba is imported. A CUDA
machine uses ``cuda_ad_rgb``. ``scalar_rgb`` is the (about 40x slower) fallback, never chosen silently.

Which one: ``HOLO_MI_VARIANT`` names it outright; otherwise ``HOLO_DEVICE`` (``--device``, see
:mod:`holocore.runtime.device`) decides: ``cuda`` -> ``cuda_ad_rgb``, ``cpu`` -> ``llvm_ad_rgb``, ``auto``
(default) -> CUDA when torch sees a GPU and Mitsuba has the variant. :func:`compute_device` is the torch device
that matches.
"""

from __future__ import annotations

import glob
import os
from functools import lru_cache

from holocore.runtime.device import cuda_available

__all__ = ["mitsuba", "variant", "is_jit", "compute_device", "variant_if_set"]

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


@lru_cache(maxsize=1)
def mitsuba():
    """Import Mitsuba with the variant set (HOLO_MI_VARIANT overrides); returns the module."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = _find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi

    wanted = os.environ.get("HOLO_MI_VARIANT")
    dev = os.environ.get("HOLO_DEVICE", "auto").strip().lower() or "auto"
    if wanted is None and dev.startswith("cuda"):
        if "cuda_ad_rgb" not in mi.variants():
            raise RuntimeError(f"HOLO_DEVICE={dev}, but this Mitsuba build has no cuda_ad_rgb variant")
        if dev not in ("cuda", "cuda:0"):
            raise RuntimeError(f"HOLO_DEVICE={dev}: Mitsuba runs on the first visible GPU; select it with "
                               "CUDA_VISIBLE_DEVICES and use --device cuda")
        wanted = "cuda_ad_rgb"
    if wanted is None:
        if dev == "auto" and cuda_available() and "cuda_ad_rgb" in mi.variants():
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


def variant_if_set() -> str | None:
    """The variant when :func:`mitsuba` has run in this process, else None (without importing Mitsuba)."""
    return mitsuba().variant() if mitsuba.cache_info().currsize else None


def compute_device():
    """The torch device that goes with the variant: CUDA for ``cuda_*`` variants, else the CPU."""
    import torch

    return torch.device("cuda") if variant().startswith("cuda") else torch.device("cpu")


def is_jit() -> bool:
    return not variant().startswith("scalar")
