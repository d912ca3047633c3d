"""Grasping and static contact planes in the scene format (issue 21 items 2 and 4; docs/interaction.md).

- a tool's ``grasp = [{t_close, t_release, radius, compliance, tear_force}]``: its jaws close at ``t_close`` on the
  body nodes within ``radius`` of its path point and let go at ``t_release`` (``sim.contact.Grasp``);
- a body's ``floor = {point, normal, friction}``: a static plane it cannot pass, with Coulomb friction
  (``sim.contact.ContactPlane``); the force on it is reported in ``tool_forces.csv`` (row ``floor:<object>``);
- ``[[contacts]] bodies = ["a", "b"], friction = mu``: two bodies, or a body and a static surface, that cannot pass
  through each other, with Coulomb friction (``sim.contact_bodies``, ``tissuerender.contacts``); the force on ``b``
  from ``a`` is reported in ``tool_forces.csv`` (row ``contact:a:b``).

Both are XPBD constraints: :func:`check_interaction` rejects them, naming the key and the integrator, in a scene
simulated by another integrator, or not simulated at all.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sim.contact import ContactPlane, Grasp

INTERACTION_INTEGRATORS = ("xpbd",)
GRASP_RADIUS_FACTOR = 1.5  # default grasp radius: 1.5 tool radii (the nodes on the jaws' surface and just beyond)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class GraspSpec(_Strict):
    t_close: Annotated[float, Field(ge=0.0, le=1e6, description="time the jaws close [s]")]
    t_release: Annotated[float, Field(ge=0.0, le=1e6, description="time they open [s] (> t_close)")]
    radius: Annotated[float, Field(gt=0.0, le=10.0)] | None = Field(None, description=(
        "grasped region [m]: the free body nodes within it of the tool's path point at t_close; "
        "default 1.5 x the tool's radius"))
    compliance: Annotated[float, Field(ge=0.0, le=1e3)] = Field(0.0, description=(
        "attachment compliance [m/N] (XPBD alpha); 0: the nodes follow the jaws rigidly"))
    tear_force: Annotated[float, Field(gt=0.0, le=1e6)] | None = Field(None, description=(
        "an attached node whose constraint force exceeds it [N] tears free for good; default: never"))

    @model_validator(mode="after")
    def _ordered(self):
        if self.t_release <= self.t_close:
            raise ValueError(f"t_release must be after t_close, found t_close = {self.t_close}, "
                             f"t_release = {self.t_release}")
        return self

    def to_sim(self, probe: int, tool_radius: float) -> Grasp:
        radius = GRASP_RADIUS_FACTOR * tool_radius if self.radius is None else self.radius
        return Grasp(probe=probe, t_close=self.t_close, t_release=self.t_release, radius=radius,
                     compliance=self.compliance, tear_force=self.tear_force)


class ContactSpec(_Strict):
    bodies: Annotated[list[Annotated[str, Field(min_length=1, max_length=200)]], Field(
        min_length=2, max_length=2, description=(
            "two object names: two bodies, or a body and a static surface (its triangles' winding gives its outside)"))]
    friction: Annotated[float, Field(ge=0.0, le=10.0)] = Field(0.0, description=(
        "Coulomb friction coefficient (static and kinetic); 0: frictionless"))
    reach: Annotated[float, Field(gt=0.0, le=10.0)] | None = Field(None, description=(
        "deepest a node is found inside the other's surface [m]; default: a body's mean boundary edge, a static "
        "surface's mean edge or half its box's smallest side, whichever is larger"))


class FloorSpec(_Strict):
    point: Annotated[list[float], Field(min_length=3, max_length=3, description="a point of the plane [m]")]
    normal: Annotated[list[float], Field(min_length=3, max_length=3, description=(
        "the plane's normal, pointing to the side the body stays on (non-zero)"))]
    friction: Annotated[float, Field(ge=0.0, le=10.0)] = Field(0.0, description=(
        "Coulomb friction coefficient (static and kinetic); 0: frictionless"))

    @model_validator(mode="after")
    def _normal(self):
        if sum(a * a for a in self.normal) < 1e-12:
            raise ValueError(f"normal must be a non-zero vector, found {self.normal}")
        return self

    def to_sim(self) -> ContactPlane:
        return ContactPlane(self.point, self.normal, self.friction)


def check_interaction(scene):
    """``(key, message)`` for a grasp or floor that would have no effect (or cannot be honoured), else None."""
    uses = [(f"tools[{i}].grasp", "grasping") for i, t in enumerate(scene.tools) if t.grasp]
    uses += [(f"objects[{i}].floor", "a contact floor") for i, o in enumerate(scene.objects) if o.floor is not None]
    contacts = getattr(scene, "contacts", ())
    uses += [(f"contacts[{i}]", "contact between objects") for i in range(len(contacts))]
    kinds = {o.name: o.kind for o in scene.objects}
    pairs = set()
    for i, c in enumerate(contacts):
        for name in c.bodies:
            if name not in kinds:
                return f"contacts[{i}].bodies", f"expected object names, found {name!r}, which is not an object"
        a, b = c.bodies
        if a == b:
            return f"contacts[{i}].bodies", f"expected two different objects, found {a!r} twice (no self-contact)"
        if kinds[a] == kinds[b] == "surface":
            return f"contacts[{i}].bodies", f"{a!r} and {b!r} are both static surfaces: expected at least one body"
        if frozenset(c.bodies) in pairs:
            return f"contacts[{i}].bodies", f"the pair {a!r}, {b!r} is listed twice"
        pairs.add(frozenset(c.bodies))
    for i, o in enumerate(scene.objects):
        if o.floor is not None and o.kind == "surface":
            return f"objects[{i}].floor", "a static surface is never simulated: a floor has no effect on it; remove it"
    if not uses:
        return None
    key, what = uses[0]
    integrator = scene.simulation.integrator
    if not scene.simulated():
        return key, f"{what} acts on simulated tissue only, and this scene simulates nothing; remove it"
    if integrator not in INTERACTION_INTEGRATORS:
        return key, (f"{what} is implemented for the xpbd integrator only, not for simulation.integrator = "
                     f"{integrator!r}; use integrator = \"xpbd\" or remove it")
    return None
