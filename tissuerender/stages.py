"""Stage bookkeeping: which pipeline stages ran, how long each took, and why it was planned.

Every stage of a render (simulation step, embedding, raster, BVH build, thickness pass, shading,
post-effects, writing) runs inside ``with recorder.run("name"):``. The recorder is the evidence
behind "simulate only the effects a scene calls for": the manifest lists the executed stages with
their timings, and tests assert that an unplanned stage never appears.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field


@dataclass
class StageRecorder:
    """Accumulates ``name -> (calls, seconds)`` for the stages that actually ran."""

    calls: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def run(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.calls[name] = self.calls.get(name, 0) + 1
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def ran(self, name: str) -> bool:
        return self.calls.get(name, 0) > 0

    def summary(self) -> dict[str, dict[str, float]]:
        return {k: {"calls": self.calls[k], "seconds": round(self.seconds[k], 6)} for k in self.calls}


def recorder_or_new(recorder: StageRecorder | None) -> StageRecorder:
    """The given recorder, or a fresh one for callers that do not track stages."""
    return recorder if recorder is not None else StageRecorder()
