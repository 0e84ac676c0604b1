"""Exits 0 when Dr.Jit compiles and runs a kernel with the libLLVM named by
its argument (see :func:`mitsuba_whitted.llvm.probe`); a library that Dr.Jit
cannot use aborts it.

Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` when its LLVM back end starts, so the
path is set before Dr.Jit is imported.
"""

import os
import sys


def main(library: str) -> None:
    os.environ["DRJIT_LIBLLVM_PATH"] = library
    import drjit as dr
    smaller = dr.minimum(dr.llvm.Float([1, 2, 3]), dr.llvm.Float(2))
    assert smaller.numpy().tolist() == [1, 2, 2]


if __name__ == "__main__":
    main(sys.argv[1])
