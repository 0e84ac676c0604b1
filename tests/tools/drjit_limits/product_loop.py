"""Dr.Jit 1.5.0 (LLVM): a product accumulated in a symbolic loop, nested
in a loop whose body takes a local derivative with ``dr.backward_from``
(the replay of Mitsuba's prb, and the shadow march inside whitted's).

- Differentiated by storing its trajectory (``max_iterations=4``), with a
  mask among its state (which lanes go on), it fails to compile and the
  process aborts: "jit_llvm_compile(): parsing failed" ("'%p..' defined
  with type '<16 x i8>' but expected '<16 x i1>'": the stored mask).
- Carried as sums (``max_iterations=-1``, argument ``sums``), with a body
  that reads the differentiated variable itself, it fails to record:
  "jit_var_schedule(): not permitted". whitted's march reads parameters
  only through the scene's plugins (calls), where the sums are recorded;
  a light that moves makes the shadow ray's target such a variable.

    python product_loop.py [sums]
"""

import sys

import drjit as dr
from drjit.auto.ad import Float, UInt32

SUMS = "sums" in sys.argv


X = Float(0.5)
dr.make_opaque(X)
dr.enable_grad(X)


@dr.syntax
def power(count: UInt32) -> Float:
    """``X ** count`` by a loop of products."""
    k = UInt32(0)
    if dr.hint(SUMS, mode="scalar"):
        value = Float(1)
        relative = Float(0)
        while dr.hint(k < count, max_iterations=-1):
            factor = dr.gather(Float, X, k * 0)
            value *= dr.detach(factor)
            relative += factor / dr.detach(factor)
            k += 1
        return dr.replace_grad(value, value * relative)
    value = Float(1)
    going = k < count
    while dr.hint(going, max_iterations=4):
        value[going] = value * X
        k += 1
        going &= k < count
    return value


@dr.syntax
def walk(count: UInt32) -> Float:
    """Per lane, the sum of X^(i mod 4) over the i below ``count``; each
    term's derivative is sent back to ``X`` inside the loop."""
    i = UInt32(0)
    total = Float(0)
    with dr.suspend_grad():
        while i < count:
            with dr.resume_grad():
                term = power(i % 4)
                dr.backward_from(term)
            total += dr.detach(term)
            i += 1
    return total


result = walk(dr.arange(UInt32, 6))
dr.eval(result)
print("ok", result, dr.grad(X))
