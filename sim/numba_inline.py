"""A faster copy of the callee's IR when numba inlines an ``inline="always"`` function (compile time only).

numba's ``InlineWorker.inline_ir`` (numba/core/inline_closurecall.py) deep-copies the callee's IR one block at a
time, each block with a fresh ``copy.deepcopy`` memo. Every ``ir.Var`` refers to the function's one ``ir.Scope``,
which holds all its variables, so each block's copy copies the whole scope again: the cost grows as blocks times
variables (numba issues #8989, #9204; numba-cuda #688). Our lane kernels inline large functions (the EBM lane
loops, the XPBD energy sweeps, the shading kernel), where this copying was about half of their compile time
(docs/design.md, "Compile time").

:func:`install` replaces that method by the same code with two changes: the blocks are copied by one
``copy.deepcopy`` of the block dictionary, so with one memo (the copy then shares one scope, as the original IR
does), and the "unmutated copy of the callee IR" it returns, which no caller uses, is the callee IR it was given
(which it does not mutate) rather than a second copy (as numba-cuda #689). The statements, variables and labels are
the same, so the compiled code is the same (the kernels' results are
bit-identical: tests/sim/test_numba_inline.py). It is installed only when numba's method has the exact source this
was written against; with any other numba the stock method stays (slower to compile, nothing else changes), and
``TISSUERENDER_STOCK_NUMBA_INLINE=1`` keeps it too.
"""
from __future__ import annotations

import inspect
import os
import textwrap
import types

# the parts of numba's inline_ir (0.59-0.68 at least) and what they become: the blocks copied with one memo; the
# "unmutated copy" it returns (which no caller in numba uses) is the unmutated input itself instead of a second copy
_REPLACEMENTS = [
    ("""    def copy_ir(the_ir):
        kernel_copy = the_ir.copy()
        kernel_copy.blocks = {}
        for block_label, block in the_ir.blocks.items():
            new_block = copy.deepcopy(the_ir.blocks[block_label])
            kernel_copy.blocks[block_label] = new_block
        return kernel_copy
""", """    def copy_ir(the_ir):
        kernel_copy = the_ir.copy()
        kernel_copy.blocks = copy.deepcopy(the_ir.blocks)
        return kernel_copy
"""),
    ("""    callee_ir = copy_ir(callee_ir)
""", """    callee_ir_original = callee_ir
    callee_ir = copy_ir(callee_ir)
"""),
    ("""    # save an unmutated copy of the callee_ir to return
    callee_ir_original = copy_ir(callee_ir)
""", ""),
]

installed = False
stock_inline_ir = None  # numba's own method, once replaced


def install() -> bool:
    """Install the one-memo copy (once per process); returns whether it is installed."""
    global installed, stock_inline_ir
    if installed:
        return True
    if os.environ.get("TISSUERENDER_STOCK_NUMBA_INLINE") == "1":
        return False
    from numba.core import inline_closurecall

    worker = inline_closurecall.InlineWorker
    try:
        source = textwrap.dedent(inspect.getsource(worker.inline_ir))
    except (OSError, TypeError):
        return False
    for stock, _ in _REPLACEMENTS:
        if source.count(stock) != 1:
            return False  # another numba: leave its method alone
    for stock, ours in _REPLACEMENTS:
        source = source.replace(stock, ours)
    code = compile(source, inspect.getsourcefile(worker.inline_ir), "exec")
    function_code = next(c for c in code.co_consts if isinstance(c, types.CodeType) and c.co_name == "inline_ir")
    patched = types.FunctionType(function_code, inline_closurecall.__dict__, "inline_ir",
                                 worker.inline_ir.__defaults__)
    patched.__doc__ = worker.inline_ir.__doc__
    patched.__qualname__ = worker.inline_ir.__qualname__
    stock_inline_ir = worker.inline_ir
    worker.inline_ir = patched
    installed = True
    return True


install()
