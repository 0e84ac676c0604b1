"""Dr.Jit 1.5.0 (LLVM): a symbolic branch whose input carries a derivative,
inside a symbolic loop whose body takes a local derivative with
``dr.backward_from`` (the replay of Mitsuba's prb), aborts the process with
"jit_var(...): unknown variable!", frozen or not. The same body with a
select instead of the branch gives the gradient.

whitted's shadow test skips packets without shadow rays by such a branch;
inside the gradient's tree replay, for a light that moves, it does not.

    python if_in_loop.py [freeze] [select]
"""

import sys

import drjit as dr
from drjit.auto.ad import Float, UInt32

FREEZE = "freeze" in sys.argv
BRANCH = "select" not in sys.argv


@dr.syntax
def walk(count: UInt32, x: Float) -> Float:
    """Per lane, the sum of (x i)^2 over the even i below ``count``; each
    term's derivative is sent back to ``x`` inside the loop."""
    i = UInt32(0)
    total = Float(0)
    with dr.suspend_grad():
        while i < count:
            with dr.resume_grad():
                scaled = x * Float(i)
                term = Float(0)
                even = (i % 2) == 0
                if dr.hint(BRANCH, mode="scalar"):
                    if even:
                        term = scaled * scaled
                else:
                    term = dr.select(even, scaled * scaled, 0)
                dr.backward_from(term)
            total += dr.detach(term)
            i += 1
    return total


x = Float(2.0)
dr.make_opaque(x)
dr.enable_grad(x)
run = dr.freeze(walk) if FREEZE else walk
result = run(dr.arange(UInt32, 5), x)
dr.eval(result)
print("ok", result, dr.grad(x))
