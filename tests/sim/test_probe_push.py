"""Probe.push_out keeps a substep's centre and capsules (issue 21, performance): the sweeps of one substep ask for the
same time, so the capsules are built once per time, and the result is bit for bit the kernel's over fresh capsules."""
import numpy as np

from sim.probe import Probe, push_out_of_capsule_load


class CountingProbe(Probe):
    calls = 0

    def capsules(self, t):
        self.calls += 1
        return super().capsules(t)


def make_probe():
    return CountingProbe(kind="capsule", radius=0.2, times=[0.0, 1.0], positions=[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]],
                         axis=[0.0, 0.6, 0.8], length=0.5)


def reference(x, t, w):
    """The kernel over capsules built afresh: what push_out did before it kept them."""
    p = Probe(kind="capsule", radius=0.2, times=[0.0, 1.0], positions=[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]],
              axis=[0.0, 0.6, 0.8], length=0.5)
    load = np.zeros(6)
    a, b = p.segment(t)
    moved = push_out_of_capsule_load(x, w, a, b, 0.2, p.position(t), load)
    return moved, load


def test_capsules_built_once_per_time_and_results_unchanged():
    rng = np.random.default_rng(3)
    x0 = rng.uniform(-0.4, 0.4, (200, 3))
    w = np.where(rng.random(200) < 0.1, 0.0, 2.0)  # some held nodes: never moved
    probe = make_probe()
    x, x_ref = x0.copy(), x0.copy()
    for t in (0.25, 0.25, 0.25, 0.5, 0.5):  # two substeps' sweeps
        load = np.zeros(6)
        moved = probe.push_out(x, t, w, load)
        moved_ref, load_ref = reference(x_ref, t, w)
        assert moved == moved_ref
        assert np.array_equal(x, x_ref) and np.array_equal(load, load_ref)
    assert probe.calls == 2  # one per distinct time, not one per sweep
    moved_first = reference(x0.copy(), 0.25, w)[0]
    assert moved_first > 10  # the nodes inside the capsule at 0.25 s were pushed: the comparison saw real work
    assert np.array_equal(x[w == 0.0], x0[w == 0.0])
