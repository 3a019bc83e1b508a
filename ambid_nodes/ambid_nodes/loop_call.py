"""A compiled per-sample kernel bound to the buffers it works on, called with (message, k) only."""

from __future__ import annotations

import numpy as np

try:
    from ambid_nodes._loop_call import LoopCall
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_call, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup' (it needs gcc and the Python headers)") from exc


class BoundKernel:
    """``call(data, k) -> int`` runs ``kernel`` on the buffers named in its context.

    ``kernel`` is a numba cfunc of type :data:`ambid_nodes.loop_kernels.LOOP_KERNEL`;
    ``call`` is a C callable (:mod:`ambid_nodes._loop_call`) costing ~0.1 us
    beyond the kernel's own work. The context is an int64 vector the kernel
    reads: :meth:`bind` writes an array's address and length into two words
    and keeps the array alive while it is bound, :meth:`set` writes an
    integer, :meth:`set_float` a float64's bits. The kernel trusts what it
    reads, so only these methods write the context.
    """

    def __init__(self, kernel, n_words: int) -> None:
        self.context = np.zeros(n_words, dtype=np.int64)
        self._bound: dict[int, np.ndarray] = {}
        self.address = kernel.address
        self.call = LoopCall(kernel.address, self.context)

    def bind(self, word: int, array, dtype, columns: int | None = None, writes: bool = True) -> None:
        """Name ``array`` in words ``word`` (address) and ``word + 1`` (length, rows if 2-D).

        Args:
            array: a C-contiguous numpy array of ``dtype``, 1-D, or 2-D with ``columns`` columns;
                or a bytearray (bound as uint8, and then not resizable while bound).
            writes: the kernel writes the array: it must be writable.
        Raises:
            ValueError: any other array (the kernel would read past it or misread it).
        """
        arr = np.frombuffer(array, dtype=np.uint8) if isinstance(array, bytearray) else array
        ndim = 1 if columns is None else 2
        if (not isinstance(arr, np.ndarray) or arr.dtype != np.dtype(dtype) or arr.ndim != ndim
                or (columns is not None and arr.shape[1] != columns) or not arr.flags.c_contiguous
                or (writes and not arr.flags.writeable)):
            what = f"{arr.shape} {arr.dtype}" if isinstance(arr, np.ndarray) else type(array).__name__
            shape = "1-D" if columns is None else f"2-D, {columns} columns"
            raise ValueError(f"BoundKernel.bind: word {word} needs a{' writable' if writes else ''} C-contiguous "
                             f"{np.dtype(dtype)} array ({shape}), got {what}")
        self._bound[word] = arr
        self.context[word] = arr.ctypes.data
        self.context[word + 1] = arr.shape[0]

    def set(self, word: int, value: int) -> None:
        self.context[word] = value

    def set_float(self, word: int, value: float) -> None:
        self.context.view(np.float64)[word] = value


class ContextWord:
    """An int attribute kept in word ``word`` of the owner's BoundKernel ``owner.<kernel>``: the one
    home of a value both the node's Python path and its compiled path read. With ``none`` given,
    None is stored as that value."""

    def __init__(self, kernel: str, word: int, none: int | None = None) -> None:
        self.kernel, self.word, self.none = kernel, word, none

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self
        value = int(getattr(obj, self.kernel).context[self.word])
        return None if value == self.none else value

    def __set__(self, obj, value: int | None) -> None:
        if value is None and self.none is not None:
            value = self.none
        getattr(obj, self.kernel).context[self.word] = value


class ContextArray:
    """An array attribute bound at word ``word`` of the owner's BoundKernel ``owner.<kernel>``
    (:meth:`BoundKernel.bind`: assigning checks and binds it)."""

    def __init__(self, kernel: str, word: int, dtype, columns: int | None = None, writes: bool = True) -> None:
        self.kernel, self.word, self.dtype, self.columns, self.writes = kernel, word, dtype, columns, writes

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self
        return getattr(obj, self.kernel)._bound[self.word]

    def __set__(self, obj, value: np.ndarray) -> None:
        getattr(obj, self.kernel).bind(self.word, value, self.dtype, self.columns, self.writes)
