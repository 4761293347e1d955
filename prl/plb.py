"""Physical Laws Bank (PLB): the catalogue of plan choices (paper Table II).

The catalogue is data (``assets/plb.yaml``); this module loads it into frozen
dataclasses, validates it, and converts plans between their three forms:

* index vector ``v`` (``np.ndarray[int64]``, one index per dimension), the form
  the networks predict and the RL agent acts in;
* named choices (``[0, -30, 2, "medium_wrap", "wrist_horizontal", "Y"]``);
* a one-line English description (``describe``).

Every problem in the catalogue or in a plan raises :class:`PLBError` (a
``ValueError``) whose message quotes the bad value.

Note: the catalogue's dimension sizes are the source of truth
(``PhysicalLawsBank.sizes``).  Table II gives ``[7, 7, 6, 4, 7, 6]`` in row
order; the product is 49,392 plans either way.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from prl.constants import JOINT_NAMES, REPO_ROOT, RS_DIMS, SENSOR_NAMES, TASKS
from prl.task_registry import base_of, declared

#: Where ``load_plb()`` looks when no path is given.
DEFAULT_PLB_PATH = REPO_ROOT / "assets" / "plb.yaml"

#: Dimensions the rest of the code relies on by name.
GRASP_DIM = "grasp_pattern"
MOTION_DIM = "kinematic_motion"

#: Tolerance on a prior's sum.
_PRIOR_ATOL = 1e-6

Choice = int | float | str


class PLBError(ValueError):
    """A malformed catalogue, or a plan / name that does not fit the catalogue."""


def _choice_key(value: object) -> tuple[str, object]:
    """Comparison key for a choice: numbers by value, names case- and space-insensitively."""
    if isinstance(value, bool | np.bool_):
        return ("bool", bool(value))
    if isinstance(value, int | float | np.integer | np.floating):
        return ("number", float(value))
    if isinstance(value, str):
        return ("name", value.strip().lower().replace(" ", "_"))
    return ("other", repr(value))


@dataclass(frozen=True)
class Dimension:
    """One dimension of the Representation Space (a row of Table II)."""

    name: str
    """Identifier, e.g. ``hand_tool_rot_x``."""
    description: str
    """What the dimension means physically."""
    unit: str
    """Unit of the choices (``deg``, ``anchor``, ``pattern``, ...)."""
    phrase: str
    """Format string for ``describe``; ``{choice}`` is the choice, underscores as spaces."""
    choices: tuple[Choice, ...]
    """The discrete choices, in index order."""
    class_constant: float | None = None
    """Constant ``c`` of Eq 4 for rotation dimensions, else ``None``."""

    def __post_init__(self) -> None:
        if not self.choices:
            raise PLBError(f"dimension '{self.name}' has no choices")
        for choice in self.choices:
            if isinstance(choice, bool) or not isinstance(choice, int | float | str):
                raise PLBError(f"dimension '{self.name}': choice {choice!r} is not a number or a name")
        keys = [_choice_key(c) for c in self.choices]
        if len(set(keys)) != len(keys):
            raise PLBError(f"dimension '{self.name}' has duplicate choices: {list(self.choices)}")
        if self.class_constant is not None and not self.class_constant > 0:
            raise PLBError(
                f"dimension '{self.name}': class_constant must be > 0, got {self.class_constant!r}"
            )
        try:
            self.phrase.format(choice="x")
        except (KeyError, IndexError, ValueError) as exc:
            raise PLBError(
                f"dimension '{self.name}': phrase {self.phrase!r} may only use the field {{choice}}"
            ) from exc

    @property
    def size(self) -> int:
        """Number of choices."""
        return len(self.choices)

    def index(self, value: object) -> int:
        """Index of the choice equal to ``value`` (names match ignoring case and ``_``/space)."""
        key = _choice_key(value)
        for i, choice in enumerate(self.choices):
            if _choice_key(choice) == key:
                return i
        allowed = ", ".join(str(c) for c in self.choices)
        raise PLBError(f"unknown {self.name} {value!r}; allowed: {allowed}")

    def describe(self, index: int) -> str:
        """The phrase for the choice at ``index``, e.g. ``rotate X -5 deg``."""
        return self.phrase.format(choice=str(self.choices[index]).replace("_", " "))


@dataclass(frozen=True)
class GraspPattern:
    """A grasp pattern of Eq 6: the set of contact sensors touching the tool."""

    name: str
    """Identifier, one of the ``grasp_pattern`` choices."""
    description: str
    """What the grasp looks like."""
    sensors: tuple[str, ...]
    """Names (from ``SENSOR_NAMES``) of the sensors in contact."""

    def __post_init__(self) -> None:
        if not self.sensors:
            raise PLBError(f"grasp pattern '{self.name}' has no sensors")
        for sensor in self.sensors:
            if sensor not in SENSOR_NAMES:
                raise PLBError(
                    f"grasp pattern '{self.name}': unknown sensor {sensor!r}; known: {', '.join(SENSOR_NAMES)}"
                )

    def vector(self) -> np.ndarray:
        """Binary ``(17,)`` uint8 vector over ``SENSOR_NAMES``."""
        return np.array([s in self.sensors for s in SENSOR_NAMES], dtype=np.uint8)


@dataclass(frozen=True)
class MotionTemplate:
    """A signed kinematic motion template of Eq 9."""

    name: str
    """Identifier, e.g. ``wrist_horizontal+``."""
    motion: int
    """Index of the ``kinematic_motion`` choice this template belongs to."""
    velocity: tuple[float, ...]
    """Dense joint-velocity direction over ``JOINT_NAMES`` (30 values)."""

    def __post_init__(self) -> None:
        if len(self.velocity) != len(JOINT_NAMES):
            raise PLBError(
                f"motion template '{self.name}': velocity has {len(self.velocity)} entries, "
                f"expected {len(JOINT_NAMES)}"
            )
        if not any(self.velocity):
            raise PLBError(f"motion template '{self.name}': joint velocity is all zero")


@dataclass(frozen=True)
class TaskSpec:
    """Per-task catalogue entry: text phrasings and the sampling prior."""

    name: str
    """Task name, one of ``TASKS``."""
    texts: tuple[str, ...]
    """Natural-language phrasings of the task goal."""
    prior: tuple[tuple[float, ...], ...]
    """One probability list per dimension, in dimension and choice order."""


@dataclass(frozen=True)
class PhysicalLawsBank:
    """The whole catalogue; immutable, picklable, cheap to pass around."""

    dims: tuple[Dimension, ...]
    """Representation-Space dimensions, in plan order."""
    grasp_patterns: tuple[GraspPattern, ...]
    """One pattern per ``grasp_pattern`` choice, in choice order."""
    motion_templates: tuple[MotionTemplate, ...]
    """The signed kinematic motion templates of Eq 9."""
    tasks: tuple[TaskSpec, ...]
    """Per-task texts and priors."""

    def __post_init__(self) -> None:
        names = [d.name for d in self.dims]
        if len(self.dims) != len(RS_DIMS):
            raise PLBError(f"expected {len(RS_DIMS)} dimensions, got {len(self.dims)}: {names}")
        if len(set(names)) != len(names):
            raise PLBError(f"duplicate dimension names: {names}")
        for required in (GRASP_DIM, MOTION_DIM):
            if required not in names:
                raise PLBError(f"missing dimension {required!r}; got {names}")
        pattern_names = tuple(p.name for p in self.grasp_patterns)
        if pattern_names != self.dim(GRASP_DIM).choices:
            raise PLBError(
                f"grasp patterns {list(pattern_names)} do not match the "
                f"{GRASP_DIM} choices {list(self.dim(GRASP_DIM).choices)}"
            )
        n_motions = self.dim(MOTION_DIM).size
        for t in self.motion_templates:
            if not 0 <= t.motion < n_motions:
                raise PLBError(
                    f"motion template '{t.name}': motion index {t.motion} not in 0..{n_motions - 1}"
                )
        uncovered = set(range(n_motions)) - {t.motion for t in self.motion_templates}
        if uncovered:
            missing = [self.dim(MOTION_DIM).choices[i] for i in sorted(uncovered)]
            raise PLBError(f"no motion template for {MOTION_DIM} choices {missing}")
        task_names = [t.name for t in self.tasks]
        for task in TASKS:
            if task not in task_names:
                raise PLBError(f"missing task {task!r}; got {task_names}")
        for task in self.tasks:
            self._check_prior(task)

    def _check_prior(self, task: TaskSpec) -> None:
        """Raise PLBError unless ``task.prior`` is a distribution per dimension."""
        if not task.texts:
            raise PLBError(f"task '{task.name}' has no texts")
        if len(task.prior) != len(self.dims):
            raise PLBError(
                f"task '{task.name}': prior has {len(task.prior)} lists, expected {len(self.dims)}"
            )
        for dim, probs in zip(self.dims, task.prior, strict=True):
            where = f"task '{task.name}' prior for {dim.name}"
            if len(probs) != dim.size:
                raise PLBError(f"{where}: {len(probs)} probabilities, expected {dim.size}: {list(probs)}")
            p = np.asarray(probs, dtype=float)
            if not np.all(np.isfinite(p)) or np.any(p < 0):
                raise PLBError(f"{where}: probabilities must be finite and >= 0, got {list(probs)}")
            if abs(p.sum() - 1.0) > _PRIOR_ATOL:
                raise PLBError(f"{where}: probabilities sum to {p.sum():.6g}, expected 1: {list(probs)}")

    # ------------------------------------------------------------------ lookup

    @property
    def dim_names(self) -> tuple[str, ...]:
        """Dimension names in plan order."""
        return tuple(d.name for d in self.dims)

    @property
    def sizes(self) -> tuple[int, ...]:
        """Number of choices per dimension (the MultiDiscrete nvec)."""
        return tuple(d.size for d in self.dims)

    @property
    def n_plans(self) -> int:
        """Number of distinct plans, the product of ``sizes``."""
        return int(np.prod(self.sizes))

    def dim(self, name: str) -> Dimension:
        """The dimension called ``name``."""
        for d in self.dims:
            if d.name == name:
                return d
        raise PLBError(f"unknown dimension {name!r}; known: {', '.join(self.dim_names)}")

    def task(self, name: str) -> TaskSpec:
        """The catalogue entry of task ``name``; for a task without one, the entry its class declares
        (``prl.task_registry.TaskDecl.catalogue_entry``: a task kept outside the repository) or, for a variant
        (``hammer_mixed``), its task's: same goal, texts and prior (so adding a variant edits no catalogue entry,
        nor the committed LN results of the tasks, ``prl.version.outcome_files``)."""
        for t in self.tasks:
            if t.name == name:
                return t
        own = declared().get(name)
        if own is not None and own.catalogue_entry is not None:
            spec = _parse_task(name, own.catalogue_entry, self.dims)
            self._check_prior(spec)
            return spec
        base = base_of(name)
        for t in self.tasks:
            if t.name == base != name:
                return t
        raise PLBError(f"unknown task {name!r}; known: {', '.join(t.name for t in self.tasks)}")

    def prior(self, task: str) -> tuple[np.ndarray, ...]:
        """Per-dimension sampling probabilities of ``task`` (fresh float arrays, each summing to 1)."""
        return tuple(np.asarray(p, dtype=float) / np.sum(p) for p in self.task(task).prior)

    def texts(self, task: str) -> tuple[str, ...]:
        """Natural-language phrasings of ``task``."""
        return self.task(task).texts

    def grasp_matrix(self) -> np.ndarray:
        """``(n_patterns, 17)`` uint8 matrix, one binary grasp pattern per row (Eq 6)."""
        return np.stack([p.vector() for p in self.grasp_patterns])

    def template_matrix(self) -> np.ndarray:
        """``(n_templates, 30)`` float matrix, one motion template per row (Eq 9)."""
        return np.array([t.velocity for t in self.motion_templates], dtype=float)

    @property
    def template_to_motion(self) -> np.ndarray:
        """``(n_templates,)`` int64 array: the ``kinematic_motion`` index of each template."""
        return np.array([t.motion for t in self.motion_templates], dtype=np.int64)

    # ------------------------------------------------------------------- plans

    def validate_plan(self, plan: Sequence[int] | np.ndarray) -> np.ndarray:
        """Check a plan index vector and return it as a fresh int64 array.

        Every entry must be an integer (Python or numpy; bools and floats are
        rejected, even ``2.0``) within ``0..size-1`` of its dimension.
        """
        try:
            values = list(plan)
        except TypeError:
            raise PLBError(f"plan must be a sequence of {len(self.dims)} integers, got {plan!r}") from None
        if len(values) != len(self.dims):
            raise PLBError(
                f"plan must have {len(self.dims)} entries (one per dimension), got {len(values)}: {plan!r}"
            )
        for dim, value in zip(self.dims, values, strict=True):
            if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
                raise PLBError(f"plan entry for {dim.name} must be an integer index, got {value!r}")
            if not 0 <= value < dim.size:
                raise PLBError(
                    f"plan entry for {dim.name} is {int(value)}, out of range; allowed 0..{dim.size - 1}"
                )
        return np.array(values, dtype=np.int64)

    def encode(self, choices: Mapping[str, object] | Sequence[object]) -> np.ndarray:
        """Index vector of a plan given by choice values.

        ``choices`` is either a mapping ``{dimension name: choice}`` with every
        dimension exactly once, or a sequence of choices in dimension order.
        Names match ignoring case and ``_``/space (``"medium wrap"`` works);
        numbers match by value (``-5`` and ``-5.0`` are the same choice).
        """
        if isinstance(choices, Mapping):
            missing = [n for n in self.dim_names if n not in choices]
            unknown = [k for k in choices if k not in self.dim_names]
            if missing or unknown:
                raise PLBError(f"plan choices: missing dimensions {missing}, unknown dimensions {unknown}")
            values = [choices[n] for n in self.dim_names]
        elif isinstance(choices, str):
            raise PLBError(f"plan choices must be a mapping or a sequence, got the string {choices!r}")
        else:
            values = list(choices)
            if len(values) != len(self.dims):
                raise PLBError(
                    f"expected {len(self.dims)} choices (one per dimension), got {len(values)}: {values}"
                )
        return np.array([d.index(v) for d, v in zip(self.dims, values, strict=True)], dtype=np.int64)

    def decode(self, plan: Sequence[int] | np.ndarray) -> list[Choice]:
        """The choice values of a plan index vector, in dimension order."""
        idx = self.validate_plan(plan)
        return [d.choices[i] for d, i in zip(self.dims, idx, strict=True)]

    def describe(self, plan: Sequence[int] | np.ndarray, task: str | None = None) -> str:
        """One-line description, e.g. ``hammer plan [0,3,2,0,0,1]: rotate X 0 deg, ...``."""
        idx = self.validate_plan(plan)
        head = "plan" if task is None else f"{self.task(task).name} plan"
        parts = ", ".join(d.describe(int(i)) for d, i in zip(self.dims, idx, strict=True))
        return f"{head} [{','.join(str(int(i)) for i in idx)}]: {parts}"

    def sample_plan(self, task: str, rng: np.random.Generator) -> np.ndarray:
        """Draw a plan for ``task`` from its prior, each dimension independently."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return np.array([rng.choice(len(p), p=p) for p in self.prior(task)], dtype=np.int64)


# --------------------------------------------------------------------- parsing


def _get(mapping: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    """``mapping[key]`` checked for presence and type, else PLBError naming ``where.key``."""
    if key not in mapping:
        raise PLBError(f"{where}: missing key {key!r}")
    value = mapping[key]
    if not isinstance(value, kind):
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise PLBError(f"{where}.{key} must be a {names}, got {value!r}")
    return value


def _parse_dimension(raw: object, i: int) -> Dimension:
    """A Dimension from its catalogue entry."""
    where = f"dimensions[{i}]"
    if not isinstance(raw, Mapping):
        raise PLBError(f"{where} must be a mapping, got {raw!r}")
    constant = raw.get("class_constant")
    if constant is not None and (isinstance(constant, bool) or not isinstance(constant, int | float)):
        raise PLBError(f"{where}.class_constant must be a number, got {constant!r}")
    return Dimension(
        name=_get(raw, "name", str, where),
        description=str(raw.get("description", "")),
        unit=_get(raw, "unit", str, where),
        phrase=str(raw.get("phrase", "{choice}")),
        choices=tuple(_get(raw, "choices", list, where)),
        class_constant=None if constant is None else float(constant),
    )


def _parse_grasp_patterns(raw: Mapping[str, Any], grasp_dim: Dimension) -> tuple[GraspPattern, ...]:
    """GraspPatterns in the order of the ``grasp_pattern`` choices."""
    missing = [c for c in grasp_dim.choices if c not in raw]
    unknown = [k for k in raw if k not in grasp_dim.choices]
    if missing or unknown:
        raise PLBError(
            f"grasp_patterns must list exactly the {grasp_dim.name} choices: missing {missing}, unknown {unknown}"
        )
    patterns = []
    for name in grasp_dim.choices:
        entry = raw[name]
        where = f"grasp_patterns.{name}"
        if not isinstance(entry, Mapping):
            raise PLBError(f"{where} must be a mapping, got {entry!r}")
        sensors = _get(entry, "sensors", list, where)
        patterns.append(GraspPattern(str(name), str(entry.get("description", "")), tuple(sensors)))
    return tuple(patterns)


def _parse_template(raw: object, i: int, motion_dim: Dimension) -> MotionTemplate:
    """A MotionTemplate from its catalogue entry (sparse ``{joint: value}``)."""
    where = f"motion_templates[{i}]"
    if not isinstance(raw, Mapping):
        raise PLBError(f"{where} must be a mapping, got {raw!r}")
    name = _get(raw, "name", str, where)
    motion = motion_dim.index(_get(raw, "motion", (str, int), f"{where} ({name})"))
    sparse = _get(raw, "joint_velocity", Mapping, f"{where} ({name})")
    velocity = [0.0] * len(JOINT_NAMES)
    for joint, value in sparse.items():
        if joint not in JOINT_NAMES:
            raise PLBError(
                f"motion template '{name}': unknown joint {joint!r}; known: {', '.join(JOINT_NAMES)}"
            )
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise PLBError(f"motion template '{name}': velocity of {joint} must be a number, got {value!r}")
        velocity[JOINT_NAMES.index(joint)] = float(value)
    return MotionTemplate(name, motion, tuple(velocity))


def _parse_task(name: str, raw: object, dims: tuple[Dimension, ...]) -> TaskSpec:
    """A TaskSpec; the prior mapping is reordered into dimension order."""
    where = f"tasks.{name}"
    if not isinstance(raw, Mapping):
        raise PLBError(f"{where} must be a mapping, got {raw!r}")
    texts = _get(raw, "texts", list, where)
    prior = _get(raw, "prior", Mapping, where)
    dim_names = [d.name for d in dims]
    missing = [n for n in dim_names if n not in prior]
    unknown = [k for k in prior if k not in dim_names]
    if missing or unknown:
        raise PLBError(f"{where}.prior: missing dimensions {missing}, unknown dimensions {unknown}")
    lists = []
    for dim_name in dim_names:
        probs = _get(prior, dim_name, list, f"{where}.prior")
        for p in probs:
            if isinstance(p, bool) or not isinstance(p, int | float):
                raise PLBError(f"{where}.prior.{dim_name}: {p!r} is not a number")
        lists.append(tuple(float(p) for p in probs))
    return TaskSpec(str(name), tuple(str(t) for t in texts), tuple(lists))


def parse_plb(raw: object) -> PhysicalLawsBank:
    """Build and validate a PhysicalLawsBank from the parsed YAML document."""
    if not isinstance(raw, Mapping):
        raise PLBError(f"the catalogue must be a mapping at top level, got {type(raw).__name__}")
    dims = tuple(_parse_dimension(d, i) for i, d in enumerate(_get(raw, "dimensions", list, "catalogue")))
    names = [d.name for d in dims]
    if len(dims) != len(RS_DIMS):
        raise PLBError(f"expected {len(RS_DIMS)} dimensions, got {len(dims)}: {names}")
    for required in (GRASP_DIM, MOTION_DIM):
        if required not in names:
            raise PLBError(f"missing dimension {required!r}; got {names}")
    grasp_dim = dims[names.index(GRASP_DIM)]
    motion_dim = dims[names.index(MOTION_DIM)]
    patterns = _parse_grasp_patterns(_get(raw, "grasp_patterns", Mapping, "catalogue"), grasp_dim)
    templates = tuple(
        _parse_template(t, i, motion_dim)
        for i, t in enumerate(_get(raw, "motion_templates", list, "catalogue"))
    )
    tasks = tuple(_parse_task(n, t, dims) for n, t in _get(raw, "tasks", Mapping, "catalogue").items())
    return PhysicalLawsBank(dims=dims, grasp_patterns=patterns, motion_templates=templates, tasks=tasks)


@functools.lru_cache(maxsize=8)
def _load_cached(path: Path, mtime_ns: int) -> PhysicalLawsBank:
    """Parse the file at ``path``; keyed on mtime so an edited file is re-read."""
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise PLBError(f"{path}: malformed YAML: {exc}") from exc
    try:
        return parse_plb(raw)
    except PLBError as exc:
        raise PLBError(f"{path}: {exc}") from exc


def load_plb(path: str | Path | None = None) -> PhysicalLawsBank:
    """Load and validate the catalogue (default ``assets/plb.yaml`` of this repo).

    The result is immutable and cached per (path, modification time).
    """
    resolved = Path(DEFAULT_PLB_PATH if path is None else path).expanduser().resolve()
    if not resolved.is_file():
        raise PLBError(f"PLB catalogue not found: {resolved}")
    return _load_cached(resolved, resolved.stat().st_mtime_ns)


# ------------------------------------------------- module-level conveniences


def validate_plan(plan: Sequence[int] | np.ndarray, plb: PhysicalLawsBank | None = None) -> np.ndarray:
    """:meth:`PhysicalLawsBank.validate_plan` on ``plb`` (default catalogue if None)."""
    return (plb or load_plb()).validate_plan(plan)


def parse_plan(text: str, plb: PhysicalLawsBank | None = None) -> np.ndarray:
    """A plan vector from its command-line form ``"0,3,2,0,0,1"``, validated; ``PLBError`` naming the text."""
    try:
        values = [int(part) for part in str(text).split(",")]
    except ValueError:
        raise PLBError(f"a plan is comma-separated integers such as 0,3,2,0,0,1; got {text!r}") from None
    return validate_plan(values, plb)


def encode(
    choices: Mapping[str, object] | Sequence[object], plb: PhysicalLawsBank | None = None
) -> np.ndarray:
    """:meth:`PhysicalLawsBank.encode` on ``plb`` (default catalogue if None)."""
    return (plb or load_plb()).encode(choices)


def decode(plan: Sequence[int] | np.ndarray, plb: PhysicalLawsBank | None = None) -> list[Choice]:
    """:meth:`PhysicalLawsBank.decode` on ``plb`` (default catalogue if None)."""
    return (plb or load_plb()).decode(plan)


def describe(
    plan: Sequence[int] | np.ndarray, task: str | None = None, plb: PhysicalLawsBank | None = None
) -> str:
    """:meth:`PhysicalLawsBank.describe` on ``plb`` (default catalogue if None)."""
    return (plb or load_plb()).describe(plan, task)


def sample_plan(task: str, rng: np.random.Generator, plb: PhysicalLawsBank | None = None) -> np.ndarray:
    """:meth:`PhysicalLawsBank.sample_plan` on ``plb`` (default catalogue if None)."""
    return (plb or load_plb()).sample_plan(task, rng)
