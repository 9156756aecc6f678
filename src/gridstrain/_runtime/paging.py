"""Arrays kept in a temporary file, which the operating system pages in and out.

A series measurement holds the reference's phase maps from the reference's pass to
the last state's kinematics, but nothing reads them while a state's frames are
being read and transformed, the part of the run that needs the most memory of its
own (method B's per-frame transforms). :class:`PagedArrays` copies such arrays
into an unlinked temporary file mapped in memory: the arrays keep their identity
(every holder sees the same read-only views), :meth:`PagedArrays.page_out` gives
their pages back to the system while they are not needed, and the next read brings
them back from the page cache (or from the file, if the system needed the memory
meanwhile). The file's blocks are reserved when it is made (``posix_fallocate``),
so that writing through the mapping can never meet a full disk; where that, or
the mapping, is not possible, :func:`page` keeps the arrays in memory.
"""

from __future__ import annotations

import mmap
import os
import tempfile

import numpy as np

__all__: list[str] = []


class PagedArrays:
    """Read-only copies of ``arrays`` (a dict of name to ndarray) in a file mapping.

    Parameters
    ----------
    arrays : dict of str to ndarray
        The arrays to copy (unchanged).
    folder : path-like
        Where the temporary file is made (unlinked at once: nothing is left behind,
        whatever ends the process).

    Raises
    ------
    OSError
        The file cannot be made, its blocks reserved or mapped.
    ValueError
        Every array is empty (nothing to page).
    """

    def __init__(self, arrays: dict, *, folder):
        page = mmap.PAGESIZE
        offsets, total = {}, 0
        for name, a in arrays.items():
            offsets[name] = total
            total += -(-a.nbytes // page) * page  # each array on its own pages
        if total == 0:
            raise ValueError("nothing to page: every array is empty")
        with tempfile.TemporaryFile(dir=folder) as f:
            os.posix_fallocate(f.fileno(), 0, total)
            # the mapping outlives the descriptor
            self._map = mmap.mmap(f.fileno(), total)
        self.arrays = {}
        for name, a in arrays.items():
            view = np.ndarray(a.shape, dtype=a.dtype, buffer=self._map, offset=offsets[name])
            view[...] = a
            view.flags.writeable = False
            self.arrays[name] = view

    def page_out(self) -> None:
        """Give the arrays' pages back to the system until they are read again
        (their contents stay in the file and the page cache)."""
        advice = getattr(mmap, "MADV_DONTNEED", None)
        if advice is not None:
            self._map.madvise(advice)


class Unpaged:
    """What :func:`page` stands for before (or instead of) paging: nothing to give
    back."""

    def page_out(self) -> None:
        """Nothing: the arrays are in memory."""


def page(arrays: dict, *, folder) -> PagedArrays | None:
    """:class:`PagedArrays` of ``arrays`` in ``folder``, or None where the system
    cannot (no ``posix_fallocate``, a full disk, a file system without mappings)."""
    if not hasattr(os, "posix_fallocate") or not hasattr(mmap.mmap, "madvise"):
        return None
    try:
        return PagedArrays(arrays, folder=folder)
    except (OSError, ValueError):
        return None
