"""The design-space model: parts, joints, instances and candidate tree structures.

A *design space* says which parts a robot is made of, how they may be connected
(candidate tree structures) and which specifications are searched (given as a
``{low, high}`` bound, ``{low, high, log: true}`` on a log scale) or fixed (given as a
number). A *design* is one point of it:
a tree plus concrete specs, ready to be written as URDF.

Geometry conventions (shared by decoding, the URDF writer and the worker tasks):
- Every link frame sits at the joint to its parent. A cylinder link extends along
  the frame's +z axis from 0 to ``length``. A box link is ``2 radius`` by
  ``2 radius`` in x and y and ``length`` along z, over the same span. A capsule
  link is the cylinder with a ball of ``radius`` on each end.
- A child's joint sits on its parent's axis at ``position * parent.length``
  (``position`` = 1.0: at the parent's far end); at joint angle 0 the child's frame
  is its parent's turned by the joint's offset (``offset_roll``, ``offset_pitch``,
  ``offset_yaw``: URDF's rpy, 0 by default), so a chain of unturned joints at rest is
  straight along +z.
- A joint is revolute, continuous, prismatic or fixed (``JointKind``).
- A joint's axis, in the child's frame, is
  ``(sin(theta) cos(phi), sin(theta) sin(phi), cos(theta))``: theta = 0 runs along
  the links, theta = pi/2 is perpendicular to them.
- A link's mass is its ``mass`` spec, or, when its part gives ``density`` (kg/m^3)
  instead, ``density`` times its shape's volume: a solid cylinder's
  ``pi radius^2 length``, a box's ``(2 radius)^2 length`` (``link_mass``). Exactly one
  of the two applies to each link; an instance's override of either replaces its
  part's.
- The spec vector orders the instances' part specs, then the instances' joint specs:
  the joint of an instance is the one to its parent, so every structure has the same
  spec slots; the root's joint slots are padded.

Spec keys: ``"<instance>.<part spec>"`` (``"a.length"``) and
``"<instance>.joint.<joint spec>"`` (``"b.joint.axis_theta"``).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import (
    Field,
    PrivateAttr,
    model_validator,
)

from adclient.catalogues import check_catalogue, choice_slots
from adclient.parts import JointType, PartInstance, PartType
from adclient.spec_constraints import SpecConstraint
from adclient.specs import (
    JOINT_SPECS,
    MASS_SPECS,
    NAME_PATTERN,
    OFFSET_SPECS,
    PART_SPECS,
    PLACEHOLDERS,
    UNUSED_JOINT_SPECS,
    Bound,
    check_limits,
    check_spec,
    show_spec,
)
from adclient.strict import StrictInput
from adclient.ties import Tie, mirrored_angle, resolve_ties, slot_used
from adclient.trees import Edge, EdgeArray, all_trees, check_tree, valid_name
from adclient.urdf_model import JointKind


class DesignSpace(StrictInput):
    """Parts, instances and candidate trees; see the module docstring for conventions.

    ``structures: "all"`` means every labelled tree over the instances (Cayley:
    n^(n-2) of them for n instances, enumerated through Pruefer sequences), each
    rooted at the first instance with its edges pointing away from the root. The
    first instance is the base: which instance is the root changes the robot's
    geometry (children sit at their parent's far end), so the rooted variants of one
    tree are different robots; list them explicitly to search over them.

    Fusion settings (used only with several structures; see
    ``adservice.representation``): ``fusion_solver`` and ``fusion_margin`` (the gap
    forced between consecutive similarity levels), ``reference_per_structure`` Sobol
    references per structure (capped near 512 in all, at least 2 each) drawn with
    ``reference_seed``, and the embedding's ``embedding_mass`` and
    ``embedding_max_dim``.

    ``encoding`` says how a space with several structures is searched:
    - ``mixed`` (the default, docs/method.md, "The mixed encoding"): a structure index
      followed by the normalised spec vector, decoded by identity; the fused geometry places the
      structures, and the proposer relates them through a structure kernel;
    - ``fused``: the preprint's encoding (docs/method.md, "Representations"), the MDS
      embedding of the fused distances decoded by nearest reference and an affine map; kept so the
      benchmarks can compare it (bench/paper.py);
    - ``onehot``: the plain encoding a user would build without fusion: one [0, 1]
      coordinate per structure (the largest names the structure) followed by the
      normalised spec vector.
    Single-structure spaces search the spec vector either way.
    """

    type: Literal["design"]
    parts: dict[str, PartType]
    joint: JointType = Field(default_factory=JointType)
    instances: list[PartInstance] = Field(min_length=1, max_length=32)
    structures: list[list[EdgeArray]] | Literal["all"] = Field(
        description="Candidate trees as edge lists, or 'all' trees over the instances"
    )
    max_structures: int = Field(default=64, ge=1, le=1000)
    encoding: Literal["mixed", "fused", "onehot"] = Field(
        default="mixed",
        description="Search vector of a multi-structure space: structure index + spec "
        "vector (mixed), the preprint's fused MDS embedding (fused), or one-hot "
        "structure + spec vector (onehot)",
    )
    catalogues: dict[str, dict[str, dict[str, float]]] = Field(
        default_factory=dict,
        description="Components a part or the joint may choose from: name -> component -> entries",
    )
    spec_constraints: list[SpecConstraint] = Field(
        default_factory=list,
        max_length=64,
        description="Linear budgets on specs every design satisfies",
    )
    allow_overlaps: bool | None = Field(
        default=None,
        description="Evaluate designs whose links interpenetrate at the rest pose "
        "(adclient.overlaps); false: a space where every design does is refused, and a "
        "design that does fails its trial before any simulation. null: false for a new "
        "study (the server stores false); a study stored before the check is not checked",
    )
    fusion_solver: Literal["osqp", "exact"] = "osqp"
    fusion_margin: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    reference_per_structure: int = Field(default=16, ge=2, le=256)
    reference_seed: int = Field(default=0, ge=0, le=2**31 - 1)
    embedding_mass: float = Field(
        default=0.99,
        gt=0.0,
        le=1.0,
        description="Fraction of the positive eigenvalue mass the MDS embedding keeps",
    )
    embedding_max_dim: int | None = Field(
        default=None,
        ge=1,
        le=256,
        description=(
            "Cap on the embedding's dimension; default: free specs + min(structures - 1, 8)"
        ),
    )

    _trees: list[list[Edge]] | None = PrivateAttr(default=None)
    _ties: dict[str, Tie] = PrivateAttr(default_factory=dict)
    _turned: bool | None = PrivateAttr(default=None)

    def __eq__(self, other: object) -> bool:
        """Equal by fields: the private attributes are caches and ties derived from them."""
        if not isinstance(other, DesignSpace):
            return NotImplemented
        return type(self) is type(other) and self.__dict__ == other.__dict__

    @model_validator(mode="after")
    def _check(self) -> DesignSpace:
        if not self.parts:
            raise ValueError("parts: at least one part type is needed")
        self._tie_instances()
        self._check_catalogues()
        for part_name, part in self.parts.items():
            if not valid_name(part_name):
                raise ValueError(f"parts: part type name {part_name!r} must match {NAME_PATTERN}")
            _check_mass_specs(
                part.mass, part.density, f"parts: part {part_name!r}", "leave one out"
            )
        seen: dict[str, int] = {}
        for index, instance in enumerate(self.instances):
            if instance.name in seen:
                raise ValueError(
                    f"instances[{index}]: duplicate instance name {instance.name!r} "
                    f"(also instances[{seen[instance.name]}])"
                )
            seen[instance.name] = index
            if instance.part not in self.parts:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): unknown part {instance.part!r} "
                    f"(known: {', '.join(sorted(self.parts))})"
                )
            if all(name in instance.overrides for name in MASS_SPECS):
                _check_mass_specs(
                    instance.overrides["mass"],
                    instance.overrides["density"],
                    f"instances[{index}] ({instance.name!r}): overrides",
                    "override only one (either replaces its part's)",
                )
            check_limits(
                self.joint_spec(instance.name, "lower"),
                self.joint_spec(instance.name, "upper"),
                f"instances[{index}] ({instance.name!r})",
            )
            kind = self.joint_kind(instance.name)
            unused = sorted(set(instance.joint_overrides) & set(UNUSED_JOINT_SPECS.get(kind, ())))
            if unused:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): its joint is {kind}, which has "
                    f"no use for {', '.join(unused)}: leave them out of joint_overrides"
                )
        if self.structures == "all":
            n = len(self.instances)
            if n < 2:
                raise ValueError("structures: 'all' needs at least two instances")
            count = n ** (n - 2)
            if count > self.max_structures:
                raise ValueError(
                    f"structures: 'all' over {n} instances gives {count} trees, more than "
                    f"max_structures={self.max_structures}; list the structures instead "
                    "or raise max_structures (up to 1000)"
                )
        else:
            self._check_structures(self.structures)
        for number, constraint in enumerate(self.spec_constraints):
            self._check_spec_constraint(constraint, f"spec_constraints[{number}]")
        return self

    def _tie_instances(self) -> None:
        """Resolve ``same_as`` chains; a tied instance's part is its source's."""
        names = [instance.name for instance in self.instances]
        if len(set(names)) != len(names):
            return  # the duplicate is named next
        self._ties = resolve_ties(
            {instance.name: instance.same_as for instance in self.instances},
            {instance.name: instance.mirror for instance in self.instances},
            {instance.name: instance.joint_overrides for instance in self.instances},
        )
        for index, instance in enumerate(self.instances):
            tie = self._ties.get(instance.name)
            if tie is None:
                continue
            source_part = self.instance(tie.source).part
            if not instance.part:
                instance.part = source_part
            elif instance.part != source_part:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): part {instance.part!r} differs "
                    f"from {tie.source!r}'s part {source_part!r}; a tied instance is its "
                    "source's part (leave part out)"
                )

    def _check_spec_constraint(self, constraint: SpecConstraint, where: str) -> None:
        """Each term is a spec every structure has, on a linear scale (a log spec is not
        linear in the searched coordinate); the fused encoding decodes non-linearly."""
        if self.encoding == "fused" and len(self.tree_structures()) > 1:
            raise ValueError(
                f"{where}: spec_constraints need the mixed or onehot encoding (the fused "
                "encoding's decoding is not linear, so a proposal could not be kept inside)"
            )
        names = {instance.name for instance in self.instances}
        for key in constraint.terms:
            instance, _, spec = key.partition(".")
            if instance not in names:
                raise ValueError(
                    f"{where}.terms: {key!r} names unknown instance {instance!r} "
                    f"(instances: {', '.join(sorted(names))})"
                )
            joint = spec.startswith("joint.")
            known = [f"joint.{name}" for name in JOINT_SPECS] if joint else list(PART_SPECS)
            if spec not in known:
                raise ValueError(
                    f"{where}.terms: {key!r} is no spec (an instance's specs: "
                    f"{', '.join(PART_SPECS)}; its joint's: joint.{', joint.'.join(JOINT_SPECS)})"
                )
            value = (
                self.joint_spec(instance, spec.removeprefix("joint."))
                if joint
                else self.part_spec(instance, spec)
            )
            if self.catalogue_sets(instance, spec):
                raise ValueError(
                    f"{where}.terms: {key!r} is set by the component chosen from a catalogue; "
                    "constrain its metric instead (outcome constraints on "
                    "'<catalogue>.<entry>')"
                )
            if value is None:
                raise ValueError(
                    f"{where}.terms: {key!r}: {instance!r}'s mass is given by "
                    f"{self.mass_spec(instance)}, so it has no {spec} spec"
                )
            if isinstance(value, Bound) and value.log:
                raise ValueError(
                    f"{where}.terms: {key!r} is searched on a log scale; spec_constraints are "
                    "linear in the searched coordinates, so constrain specs on a linear scale"
                )
            for index, edges in enumerate(self.tree_structures()):
                present = {child for _, child in edges} if joint else {n for e in edges for n in e}
                if instance not in present:
                    raise ValueError(
                        f"{where}.terms: {key!r} is not in structures[{index}] ({instance!r} "
                        f"{'is no child' if joint else 'is absent'} there); a constraint's "
                        "specs must be in every structure"
                    )

    def _check_catalogues(self) -> None:
        """Valid catalogues; every ``choose`` names one; the specs a component sets are
        valid specs of what chooses it."""
        for name, catalogue in self.catalogues.items():
            check_catalogue(name, catalogue)
        choosers = [(f"parts.{n}", part.choose, "part") for n, part in self.parts.items()]
        choosers.append(("joint", self.joint.choose, "joint"))
        for where, chosen, kind in choosers:
            if chosen is None:
                continue
            if chosen not in self.catalogues:
                known = ", ".join(sorted(self.catalogues)) or "none"
                raise ValueError(
                    f"{where}.choose: unknown catalogue {chosen!r} (catalogues: {known})"
                )
            specs = JOINT_SPECS if kind == "joint" else PART_SPECS
            for component, entries in self.catalogues[chosen].items():
                for key, value in entries.items():
                    if key in specs:
                        check_spec(key, value, f"catalogues.{chosen}.{component}")
                if kind == "joint" and entries.get("lower", -math.inf) > entries.get(
                    "upper", math.inf
                ):
                    raise ValueError(
                        f"catalogues.{chosen}.{component}: lower ({entries['lower']}) exceeds "
                        f"upper ({entries['upper']})"
                    )
            if kind == "part":
                part = self.parts[where.removeprefix("parts.")]
                given = "mass" if part.mass is not None else "density"
                other = "density" if given == "mass" else "mass"
                if other in next(iter(self.catalogues[chosen].values())):
                    raise ValueError(
                        f"{where}.choose: catalogue {chosen!r} sets {other} but the part's "
                        f"mass is given by {given}"
                    )

    def check_at_creation(self) -> None:
        """Rules a new space meets that a stored one need not: they came after studies
        were stored under looser ones, and a stored study must still load
        (read, listed, proposed for), so the server checks them when it creates a study,
        not whenever a space is read. ValueError naming what breaks one."""
        for index, instance in enumerate(self.instances):
            self._check_chosen_overrides(f"instances[{index}] ({instance.name!r})", instance)
        for number, constraint in enumerate(self.spec_constraints):
            for key in constraint.terms:
                name, _, spec = key.partition(".")
                kind = self.joint_kind(name)
                if spec.startswith("joint.") and spec[6:] in UNUSED_JOINT_SPECS.get(kind, ()):
                    raise ValueError(
                        f"spec_constraints[{number}].terms: {key!r} is a placeholder: "
                        f"{name!r}'s joint is {kind}, which has no use for it, so no "
                        "design changes it; leave it out"
                    )

    def _check_chosen_overrides(self, where: str, instance: PartInstance) -> None:
        """An instance overrides no spec its chosen component sets (the component's would
        win unseen), and its mass is given by the spec its part's catalogue sets, if any
        (an override of density under a catalogue of masses left the masses unused)."""
        fields: tuple[tuple[str, Literal["part", "joint"]], ...] = (
            ("overrides", "part"),
            ("joint_overrides", "joint"),
        )
        for field, kind in fields:
            chosen = self.chosen_catalogue(instance.name, kind)
            if chosen is None:
                continue
            entries = next(iter(self.catalogues[chosen].values()))
            clashing = sorted(set(getattr(instance, field)) & set(entries))
            if clashing:
                raise ValueError(
                    f"{where}: {field} {', '.join(clashing)}: the component chosen from "
                    f"catalogue {chosen!r} sets them; leave them out"
                )
            if kind == "part" and instance.same_as is None:
                given = self.mass_spec(instance.name)
                other = "density" if given == "mass" else "mass"
                if other in entries:
                    raise ValueError(
                        f"{where}: its mass is given by {given} (its override), but catalogue "
                        f"{chosen!r} sets {other}; override {other} instead, or nothing"
                    )

    def chosen_catalogue(self, instance_name: str, kind: Literal["part", "joint"]) -> str | None:
        """The catalogue an instance's part (or its joint) is chosen from; None if none."""
        if kind == "joint":  # a fixed joint has no motor to choose
            return None if self.joint_kind(instance_name) == "fixed" else self.joint.choose
        return self.parts[self.instance(instance_name).part].choose

    def catalogue_sets(self, instance_name: str, spec: str) -> bool:
        """Whether a component chosen from a catalogue gives this spec (``length``,
        ``joint.effort``), rather than the part or joint itself."""
        kind: Literal["part", "joint"] = "joint" if spec.startswith("joint.") else "part"
        unused = UNUSED_JOINT_SPECS.get(self.joint_kind(instance_name), ())
        if spec.removeprefix("joint.") in unused:
            return False  # its kind has no use for it: a placeholder, whatever the component
        chosen = self.chosen_catalogue(instance_name, kind)
        if chosen is None:
            return False
        first = next(iter(self.catalogues[chosen].values()))
        return spec.removeprefix("joint.") in first

    def tie(self, instance_name: str) -> Tie | None:
        """Where a tied instance's specs come from; None for an untied one."""
        return self._ties.get(instance_name)

    def ties(self) -> dict[str, Tie]:
        """Every tied instance's Tie, by instance name."""
        return dict(self._ties)

    def _check_structures(self, structures: list[list[Edge]]) -> None:
        if not structures:
            raise ValueError("structures: at least one structure is needed")
        if len(structures) > self.max_structures:
            raise ValueError(
                f"structures: {len(structures)} structures, more than "
                f"max_structures={self.max_structures}"
            )
        names = {instance.name for instance in self.instances}
        used: set[str] = set()
        first_of: dict[frozenset[Edge], int] = {}
        for index, edges in enumerate(structures):
            where = f"structures[{index}]"
            check_tree(edges, names, where)
            key = frozenset(edges)
            if key in first_of:
                raise ValueError(f"{where}: same tree as structures[{first_of[key]}]")
            first_of[key] = index
            for parent, child in edges:
                used.update((parent, child))
        unused = [instance.name for instance in self.instances if instance.name not in used]
        if unused:
            raise ValueError(
                f"instances: {', '.join(map(repr, unused))} appear in no structure; "
                "remove them or use them in a structure"
            )

    # -- queries ---------------------------------------------------------------

    def instance(self, name: str) -> PartInstance:
        for instance in self.instances:
            if instance.name == name:
                return instance
        raise KeyError(f"unknown instance {name!r}")

    def mass_spec(self, instance_name: str) -> Literal["mass", "density"]:
        """Which spec gives an instance's mass: the one it overrides, else the one its
        part gives (``density``: the mass is density times the link's volume)."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.mass_spec(tie.source)
        instance = self.instance(instance_name)
        for name in MASS_SPECS:
            if name in instance.overrides:
                return "density" if name == "density" else "mass"
        return "mass" if self.parts[instance.part].mass is not None else "density"

    def part_spec(self, instance_name: str, spec: str) -> float | Bound | None:
        """An instance's part spec: its override, else its part type's value; ``None``
        for the one of ``mass`` and ``density`` that does not give its mass. A tied
        instance's is its source's."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.part_spec(tie.source, spec)
        instance = self.instance(instance_name)
        if spec in MASS_SPECS and spec != self.mass_spec(instance_name):
            return None
        if spec in instance.overrides:
            return instance.overrides[spec]
        value: float | Bound | None = getattr(self.parts[instance.part], spec)
        return value

    def uses_offsets(self) -> bool:
        """Whether any joint of the space is turned on its parent (an offset not 0, or
        searched): its designs then show every joint's offsets."""
        if self._turned is None:  # decoding asks on every ask, lease and job
            self._turned = any(
                self._joint_spec(instance.name, spec) != 0.0
                for instance in self.instances
                for spec in OFFSET_SPECS
            )
        return self._turned

    def joint_kind(self, instance_name: str) -> JointKind:
        """The kind of the joint from an instance to its parent (a tied one's source's)."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.joint_kind(tie.source)
        return self.instance(instance_name).joint_type or self.joint.type

    def joint_spec(self, instance_name: str, spec: str) -> float | Bound:
        """The spec of the joint from an instance to its parent; a tied instance's is
        its source's, a fixed axis angle mirrored (a searched one is the source's slot).
        A spec its kind has no use for (``UNUSED_JOINT_SPECS``) is a placeholder: a
        continuous joint's limits -pi and pi, a fixed joint's axis along its parent
        (theta 0) and its motor's numbers their given value or lower bound."""
        if spec in UNUSED_JOINT_SPECS.get(self.joint_kind(instance_name), ()):
            if spec in PLACEHOLDERS:
                return PLACEHOLDERS[spec]
            given = self._joint_spec(instance_name, spec)
            return given.low if isinstance(given, Bound) else given
        return self._joint_spec(instance_name, spec)

    def _joint_spec(self, instance_name: str, spec: str) -> float | Bound:
        tie = self.tie(instance_name)
        own = self.instance(instance_name).joint_overrides
        if tie is not None and spec not in own:
            value = self._joint_spec(tie.source, spec)
            return value if isinstance(value, Bound) else mirrored_angle(spec, value, tie)
        instance = self.instance(instance_name)
        if spec in instance.joint_overrides:
            return instance.joint_overrides[spec]
        return getattr(self.joint, spec)

    def tree_structures(self) -> list[list[Edge]]:
        """The candidate structures as edge lists (``"all"`` enumerated, deterministic)."""
        if self._trees is None:
            if self.structures == "all":
                names = [instance.name for instance in self.instances]
                self._trees = list(all_trees(names))
            else:
                self._trees = [[(p, c) for p, c in edges] for edges in self.structures]
        return self._trees

    def free_specs(self) -> list[tuple[str, Bound]]:
        """The free specs' keys in spec-vector order, with their Bounds.

        A part slot exists when its instance is in some structure and its spec is a
        Bound; a joint slot when its instance is a child in some structure. A tied
        instance's specs are its source's slots, which exist when either would
        (``slot_used``); its own searched ``position`` is its only slot.
        """
        structures = self.tree_structures()
        members = {name for edges in structures for edge in edges for name in edge}
        children = {child for edges in structures for _, child in edges}

        def used(key: str) -> bool:
            return slot_used(key, members, children, self._ties)

        slots: list[tuple[str, Bound]] = []
        for instance in self.instances:
            if not used(f"{instance.name}.length") or instance.name in self._ties:
                continue
            slots += self._choice_slots(instance.name, "part")
            for spec in PART_SPECS:
                if self.catalogue_sets(instance.name, spec):
                    continue
                value = self.part_spec(instance.name, spec)
                if isinstance(value, Bound):
                    slots.append((f"{instance.name}.{spec}", value))
        for instance in self.instances:
            if instance.name not in self._ties and used(f"{instance.name}.joint.choice"):
                slots += self._choice_slots(instance.name, "joint")
            for spec in JOINT_SPECS:
                if not used(f"{instance.name}.joint.{spec}"):
                    continue
                if instance.name in self._ties and spec not in instance.joint_overrides:
                    continue
                if self.catalogue_sets(instance.name, f"joint.{spec}"):
                    continue
                value = self.joint_spec(instance.name, spec)
                if isinstance(value, Bound):
                    slots.append((f"{instance.name}.joint.{spec}", value))
        return slots

    def _choice_slots(
        self, instance_name: str, kind: Literal["part", "joint"]
    ) -> list[tuple[str, Bound]]:
        """The searched entries of the catalogue an instance's part or joint chooses
        from (``adclient.catalogues``), named ``<instance>.choice.<entry>`` and
        ``<instance>.joint.choice.<entry>``."""
        chosen = self.chosen_catalogue(instance_name, kind)
        if chosen is None:
            return []
        owner = instance_name if kind == "part" else f"{instance_name}.joint"
        return [
            (f"{owner}.choice.{slot.key}", Bound(low=slot.low, high=slot.high, log=slot.log))
            for slot in choice_slots(self.catalogues[chosen])
        ]

    @property
    def searches_nothing(self) -> bool:
        """Whether the space is one design: a single structure and no searched spec. A
        study of it evaluates that design again and again, each trial with its own seed
        (docs/study-file.md, "Evaluating one design")."""
        return len(self.tree_structures()) == 1 and not self.free_specs()

    def spec_slots(self) -> tuple[list[str], list[tuple[float, float]]]:
        """Free spec keys in spec-vector order, and their physical (low, high).

        The ranges are the values a spec takes, log-scaled or not: what a person
        reads and what bounds checks compare with. How a slot is normalised (its
        ``log``) is in ``free_specs`` and ``adclient.decode.SpecLayout``.
        """
        slots = self.free_specs()
        return [key for key, _ in slots], [(bound.low, bound.high) for _, bound in slots]


def _check_mass_specs(
    mass: float | Bound | None, density: float | Bound | None, where: str, fix: str
) -> None:
    """A link's mass is given once: by ``mass`` or by ``density``, not both, not neither."""
    if mass is not None and density is not None:
        raise ValueError(
            f"{where} gives both mass ({show_spec(mass)}) and density ({show_spec(density)}); "
            f"a link's mass is its mass or its density times its volume: {fix}"
        )
    if mass is None and density is None:
        raise ValueError(
            f"{where} gives neither mass nor density; give one (mass in kg, or density "
            "in kg/m^3 for a mass of density times the link's volume)"
        )
