"""The compiled loops (numba, the ``fast`` extra): each folder's loops are one module,
loaded by :func:`load` on their first use, never when gridstrain is imported (numba's
import and its cached machine code cost a fresh process a few hundred milliseconds)."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["load"]


def load(package: str, name: str) -> ModuleType | None:
    """The module of compiled loops ``name`` (relative, ``"._kernels"``) of
    ``package``, or None where it cannot run: numba not installed (the module's import
    fails, or it says so by a false ``AVAILABLE``), or numba unable to set up its cache
    (no writable directory: it raises RuntimeError at the decorators). The module is
    looked up in ``sys.modules``, not as the package's attribute, so that a test that
    removes it makes it load again; callers keep the answer (``functools.cache``)."""
    try:
        module = importlib.import_module(name, package)
    except (ImportError, RuntimeError):
        return None
    return module if getattr(module, "AVAILABLE", True) else None
