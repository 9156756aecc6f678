"""How a run uses the machine it runs on, apart from what it computes.

- :mod:`.fft`: the FFT implementation the transforms use (scipy.fft, or Intel's MKL
  through mkl_fft where installed and chosen);
- :mod:`.threads`: BLAS kept on the calling thread inside the frame loops, bounded
  thread pools, and the process settings the command line makes before numpy loads;
- :mod:`.memory`: the memory a measurement needs and the budget it is held to;
- :mod:`.paging`: read-only copies of large arrays in a file mapping;
- :mod:`.compiled`: each folder's compiled loops (numba), loaded on first use or not at
  all.
"""
