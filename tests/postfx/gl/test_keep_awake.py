"""The idle-priority threads that keep the CPUs awake during an OSMesa chain."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

import postfx
from postfx.blur import Blur
from postfx.chromatic_aberration import ChromaticAberration
from postfx.gl import keep_awake, library
from postfx.tonemap import Tonemap

needs_osmesa = pytest.mark.skipif(not library.library_available(),
                                  reason="libOSMesa missing: install the Debian package libosmesa6")


def wait_until(condition, seconds=5.0):
    """Poll ``condition``: under a loaded test run idle-priority threads start and stop late."""
    deadline = time.monotonic() + seconds
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.001)
    return condition()


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE") or not os.path.isdir("/proc/self/task"), reason="Linux only")
def test_threads_run_at_idle_priority_and_spin_only_inside_the_block():
    awake = keep_awake.KeepAwake.get()
    assert awake.active and len(awake.native_ids) == len(awake.threads) >= 1
    assert all(os.sched_getscheduler(t) == os.SCHED_IDLE for t in awake.native_ids)
    before = awake.turns

    with awake:
        assert wait_until(lambda: awake.spinning == len(awake.threads))
        time.sleep(0.1)
    assert wait_until(lambda: awake.spinning == 0)  # all of them stop after the block
    assert awake.turns > before
    after = awake.turns
    time.sleep(0.3)
    assert awake.turns == after and awake.spinning == 0  # no turn outside the block: waiting on the condition


@needs_osmesa
@pytest.mark.osmesa
def test_chain_spins_unless_switched_off_and_gives_the_same_pixels(monkeypatch):
    rng = np.random.default_rng(3)
    img = (rng.random((48, 64, 3)) * 3.0).astype(np.float32)
    lens = postfx.Lens(70.0, 64, 48)
    chain = [("chromatic_aberration", ChromaticAberration(strength_r=0.01)), ("blur", Blur(sigma_px=1.0)),
             ("tonemap", Tonemap())]
    awake = keep_awake.KeepAwake.get()
    before = awake.turns
    on = postfx.apply_chain(img, None, chain, lens, backend="osmesa", seed=4).image
    assert wait_until(lambda: awake.spinning == 0) and awake.turns > before
    monkeypatch.setenv(keep_awake.ENV, "0")
    assert not keep_awake.enabled()
    before = awake.turns
    off = postfx.apply_chain(img, None, chain, lens, backend="osmesa", seed=4).image
    assert awake.turns == before
    assert np.array_equal(on, off)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX only")
def test_a_forked_child_starts_its_own_threads():
    awake = keep_awake.KeepAwake.get()
    pid = os.fork()
    if pid == 0:  # the child: a new instance whose threads exist and spin
        try:
            child = keep_awake.KeepAwake.get()
            ok = child is not awake and child.active
            with child:
                ok = ok and wait_until(lambda: child.spinning == len(child.threads))
            os._exit(0 if ok else 1)
        except BaseException:
            os._exit(2)
    deadline = time.monotonic() + 30.0
    done, status = 0, 0
    while not done and time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        time.sleep(0.01)
    if not done:  # a child stuck on a lock some other thread held at the fork: do not hang the suite
        os.kill(pid, 9)
        os.waitpid(pid, 0)
    assert done and os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
