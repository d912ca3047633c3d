"""The load (force and moment) a contact impulse puts on a tool, a plane or a surface pair."""
from __future__ import annotations

from numba import njit


@njit(cache=True)
def add_wrench(load, sign, jx, jy, jz, rx, ry, rz):
    """``load[0:3] += sign j`` and ``load[3:6] += sign (r x j)``: the impulse j applied at arm r (from the load's
    reference point). ``sign`` is +1 or -1, so a caller without one (+1) adds exactly j and r x j."""
    load[0] += sign * jx
    load[1] += sign * jy
    load[2] += sign * jz
    load[3] += sign * (ry * jz - rz * jy)
    load[4] += sign * (rz * jx - rx * jz)
    load[5] += sign * (rx * jy - ry * jx)
