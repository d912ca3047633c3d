"""Keep the CPUs awake while llvmpipe runs a chain: idle-priority spinning threads.

llvmpipe's rasterizer threads sleep on a semaphore or a barrier between the passes of a chain, and the
calling thread sleeps while it waits for them (``voluntary_ctxt_switches`` in /proc shows dozens per
chain), where numba's OpenMP workers, which spin between parallel regions, sleep none in the NumPy
backend's chain. On a virtual machine a sleeping thread's vCPU halts, and waking it goes through the
hypervisor. Whether these threads gain beyond the machine's noise is measured in docs/postfx.md, "How
fast, and why"; issue 15 item 7 removes them unless it does.

The threads run with ``SCHED_IDLE``: the kernel runs them only on a CPU that has nothing else to run and
preempts them at once when a normal thread wakes there, so they take no time from llvmpipe, from this
process or from other programs. They spin only inside ``KeepAwake`` (a chain): an atomic load of a flag
(with the x86 ``pause`` hint) and a ``sched_yield`` per turn; otherwise they wait on a condition. Where
``SCHED_IDLE`` cannot be set they do nothing (spinning at normal priority would compete with llvmpipe).
When other programs keep every CPU busy the threads do not run at all, and a chain waits only briefly
for them to start. Set the environment variable ``TISSUERENDER_GL_KEEP_AWAKE=0`` to switch them off:
that changes nothing but speed (the same pixels, tested). Their CPU time counts in the process's CPU
time (the benchmark's ``osmesa_cpu_ms_total``).
"""
from __future__ import annotations

import ctypes
import os
import platform
import threading

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

ENV = "TISSUERENDER_GL_KEEP_AWAKE"
MAX_THREADS = 16
_X86 = platform.machine().lower() in ("x86_64", "amd64", "i686", "i386")


@intrinsic
def _load_relaxed(typingctx, flag):
    """``flag[0]`` of an int64 array as an atomic (monotonic) load, so that a loop reads it every time; on
    x86 preceded by ``pause`` (a spin-wait hint: less power, no pipeline flush on exit)."""
    if not (isinstance(flag, types.Array) and flag.dtype == types.int64):
        return None

    def codegen(context, builder, sig, args):
        if _X86:
            pause = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), []),
                                                   "llvm.x86.sse2.pause")
            builder.call(pause, [])
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        return builder.load_atomic(data, "monotonic", 8)

    return types.int64(flag), codegen


@intrinsic
def _call(typingctx, address):
    """Call the C function ``int f(void)`` at ``address`` (a run-time value, so the kernel stays cacheable)."""
    if not isinstance(address, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        fnty = ir.FunctionType(ir.IntType(32), [])
        builder.call(builder.inttoptr(args[0], fnty.as_pointer()), [])
        return context.get_dummy_value()

    return types.void(address), codegen


@njit(nogil=True, cache=True)
def _spin(flag, yield_address) -> int:
    """Spin without the GIL until ``flag[0]`` is not 0, calling ``sched_yield`` (at ``yield_address``, 0:
    none) every turn; returns the number of turns."""
    turns = 0
    while _load_relaxed(flag) == 0:
        if yield_address:
            _call(yield_address)
        turns += 1
    return turns


def _sched_yield_address() -> int:
    try:
        return ctypes.cast(ctypes.CDLL(None).sched_yield, ctypes.c_void_p).value or 0
    except (OSError, AttributeError):
        return 0


def enabled() -> bool:
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


class KeepAwake:
    """``with KeepAwake.get():`` spins one idle-priority thread per CPU (at most MAX_THREADS) until the block
    ends. The threads are created on first use and kept; between blocks they wait on a condition."""

    _instance: "KeepAwake | None" = None

    @classmethod
    def get(cls) -> "KeepAwake":
        if cls._instance is None:
            cls._instance = cls(min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                    else (os.cpu_count() or 1), MAX_THREADS))
        return cls._instance

    def __init__(self, threads: int):
        self.flag = np.ones(1, np.int64)  # 0: spin, else: stop
        self.cond = threading.Condition()
        self.round = 0
        self.spinning = 0
        self.ready = 0
        self.idle_priority: list[bool] = []
        self.native_ids: list[int] = []
        self.turns = 0  # spin turns of all threads so far
        self.yield_address = _sched_yield_address()
        _spin(self.flag, self.yield_address)  # compile (or load from the cache) here, not in a thread
        self.threads = [threading.Thread(target=self._run, name=f"tissuerender-keep-awake-{i}", daemon=True)
                        for i in range(threads)]
        for thread in self.threads:
            thread.start()
        with self.cond:
            self.cond.wait_for(lambda: self.ready == len(self.threads), timeout=5.0)
        self.active = any(self.idle_priority)

    def _run(self):
        try:
            os.sched_setscheduler(threading.get_native_id(), os.SCHED_IDLE, os.sched_param(0))
            ok = True
        except (AttributeError, OSError):
            ok = False
        with self.cond:
            self.idle_priority.append(ok)
            self.native_ids.append(threading.get_native_id())
            self.ready += 1
            self.cond.notify_all()
        if not ok:
            return  # never spin at normal priority
        seen = 0
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.round != seen)
                seen = self.round
                self.spinning += 1
                self.cond.notify_all()
            turns = _spin(self.flag, self.yield_address)
            with self.cond:
                self.spinning -= 1
                self.turns += turns
                self.cond.notify_all()

    def __enter__(self):
        if not self.active:
            return self
        with self.cond:
            self.flag[0] = 0
            self.round += 1
            self.cond.notify_all()
            # the threads need the GIL to reach the spin, and GL calls may hold it for a long time: give them
            # a moment (on a busy machine they would not run anyway, and a longer wait here and in __exit__
            # made the chain slower than without the threads)
            self.cond.wait_for(lambda: self.spinning == sum(self.idle_priority), timeout=0.0005)
        return self

    def __exit__(self, *exc):
        if not self.active:
            return False
        self.flag[0] = 1  # no wait: a thread that gets no CPU to see the flag now stops when it does
        return False


def _forget_in_child() -> None:
    """A forked child has none of the parent's threads: it starts its own on first use."""
    KeepAwake._instance = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)
