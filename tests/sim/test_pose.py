"""sim.pose and the instruments' capsule tracks: many times at once give the one-time values bit for bit."""
import numpy as np
from types import SimpleNamespace

from sim.pose import bracket, brackets, quat_matrices, quat_matrix, slerp, slerps
from tissuerender.instruments import InstrumentProbe


def _slerp_reference(q0, q1, u):
    """The one-pair slerp written out (Shoemake 1985), as sim.pose had it before the rows."""
    if u <= 0.0:
        return q0.copy()
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if u >= 1.0:
        return q1.copy()
    if d > 1.0 - 1e-12:
        q = (1.0 - u) * q0 + u * q1
    else:
        th = np.arccos(d)
        q = (np.sin((1.0 - u) * th) * q0 + np.sin(u * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def test_slerp_rows_equal_one_pair_calls_bit_for_bit():
    rng = np.random.default_rng(0)
    for k in range(200):
        q0, q1 = rng.normal(size=4), rng.normal(size=4)
        q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
        if k % 4 == 0:
            q1 = q0.copy()  # the chord branch
        u = np.concatenate([rng.uniform(-0.2, 1.2, 6), [0.0, 1.0]])
        rows = slerps(q0, q1, u)
        for uk, row in zip(u, rows):
            assert _slerp_reference(q0, q1, float(uk)).tobytes() == row.tobytes() == slerp(q0, q1, uk).tobytes()
        for q, R in zip(rows, quat_matrices(rows)):
            assert quat_matrix(q).tobytes() == R.tobytes()


def test_brackets_equal_bracket_inside_outside_and_at_keyframes():
    times = np.array([0.0, 0.25, 0.5])
    ts = np.array([-0.1, 0.0, 0.1, 0.25, 0.3, 0.5, 0.7])
    i, j, u = brackets(times, ts)
    assert [bracket(times, t) for t in ts] == list(zip(i.tolist(), j.tolist(), u.tolist()))
    assert bracket(times, 0.1) == (0, 1, 0.4)
    assert bracket(np.array([0.3]), 0.5) == (0, 0, 0.0)


def test_instrument_capsule_rows_equal_one_time_capsules_bit_for_bit():
    kf = lambda t, p, jaw=None, q=None: SimpleNamespace(t=t, position=p, jaw_deg=jaw, orientation=q)  # noqa: E731
    tools = [SimpleNamespace(kind="grasper", radius=0.004, length=0.15, axis=[-0.5, 0.3, -0.8],
                             keyframes=[kf(0.0, [0.03, -0.02, 0.12], 30.0), kf(0.25, [0.03, -0.02, 0.08], 0.0)]),
             SimpleNamespace(kind="l_hook", radius=0.003, length=0.1, axis=[0, 0, -1],
                             keyframes=[kf(0.0, [0, 0, 0.1], None, [1, 0, 0, 0]),
                                        kf(0.3, [0.01, 0, 0.05], None, [0.8, 0.2, 0.5, 0.1])])]
    ts = np.concatenate([[-0.1, 0.0, 0.25, 0.4], 0.1 + np.cumsum(np.full(8, 1.0 / 960.0))])
    for tool in tools:
        probe = InstrumentProbe(tool)
        rows = probe.capsule_rows(ts)
        assert rows.shape == (ts.size, 3, 7)
        for t, r in zip(ts, rows):
            one = np.array([[*a, *b, radius] for a, b, radius in probe.capsules(float(t))])
            assert one.tobytes() == r.tobytes()
        assert probe.positions_at(ts).tobytes() == np.array([probe.position(float(t)) for t in ts]).tobytes()
