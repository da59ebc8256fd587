r"""kim-mcl: Monte Carlo localisation of a robot with one forward sonar in a walled arena.

The state is the pose :math:`x = [x, y, \theta]`: position in centimetres, heading
:math:`\theta` in degrees counter-clockwise from the :math:`+x` axis (an angle: the estimate
averages it on the circle and its error is wrapped, :mod:`pfx.numerics.angles`). The robot follows a
``route`` of actions, one per filter step (the time unit is the action). With the process
noise :math:`w = [w_d, w_\alpha]`:

* **move** :math:`d` cm: the robot covers :math:`\delta = b_d\, d + w_d` along its heading,
  :math:`x' = x + \delta\cos\theta,\ y' = y + \delta\sin\theta,\ \theta' = \theta`;
* **turn** :math:`\alpha` degrees (positive: counter-clockwise): :math:`x' = x,\ y' = y,\
  \theta' = \theta + b_\alpha\,\alpha + w_\alpha` (mod 360).

The paper's robot (Kim, Kim & Kim 2011, sec. 3) covers on average 92 % of a commanded move and
turns 3 % too far: :math:`b_d = 0.92`, :math:`\operatorname{Var} w_d = 9.0` cm²,
:math:`b_\alpha = 1.03`, :math:`\operatorname{Var} w_\alpha = 13.0` deg². The paper writes each
action's law as one normal :math:`N(x_t; m_d, \sigma_d^2)` around the biased mean pose; pfx
reads :math:`\sigma_d^2` as the variance of what the action executes (the distance moved, the
angle turned), so a move does not change the heading and a turn does not move the robot.

A move that would cross a wall stops ``clearance`` short of it (the robot bumps into the wall):
:math:`\delta` is clipped to :math:`r(x, y, \pm\theta) - \text{clearance}` (no less than 0),
:math:`r` the free distance in the direction of travel. Truth and particles obey the same rule,
so no pose ever leaves free space.

The sonar reads the distance to the nearest wall straight ahead, :math:`r(x, y, \theta)`, by ray
casting against the map (:mod:`pfx.models.walls`), with noise :math:`v` (the paper's
:math:`N(z; m_s, \sigma_s^2 = 1.0)`) and a maximum range :math:`r_\max` that it reports when
nothing nearer echoes:

.. math:: z = \min(r(x) + v,\ r_\max), \qquad
          p(z \mid x) = \begin{cases} p_v(z - r(x)) & z < r_\max \\
                                      P(v \ge r_\max - r(x)) & z = r_\max \end{cases}

(a censored measurement: a saturated reading weighs a pose by the probability of saturating).

``motion`` selects what a filter assumes: ``noisy`` is the model above (the paper's noisy
model, which here is exactly the truth's), ``noise-free`` executes the commanded action exactly
(:math:`b_d = b_\alpha = 1`, no noise). The filter's default prior is uniform over free space
(inside the outline, outside every obstacle) with a uniform heading (:class:`FreeSpaceLaw`).

The EKF and UKF run on this model through finite differences, but a single range reading of a
uniform prior is far from Gaussian: the model is here for particle filters.

**Both backends.** ``propagate``, ``measurement_mean``, ``measure`` and ``log_likelihood`` take
NumPy or JAX arrays (:mod:`pfx.numerics.arrays`), the ray casting included
(:meth:`pfx.models.walls.WallMap.ray_distance`). A control given as a NumPy array (the NumPy
backend) selects the action's formula in Python, as before; a traced control (the JAX backend's
per-step input) computes both and keeps the commanded one (``xp.where``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictFloat,
    StringConstraints,
    ValidationInfo,
    model_validator,
)

from pfx.errors import ModelNumericalError
from pfx.laws.initial import GaussianLaw, InitialLaw, PointLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.models.kidnap import Kidnap
from pfx.models.walls import WallMap, read_wall_file
from pfx.numerics.angles import wrap_into_turn
from pfx.numerics.arrays import namespace
from pfx.numerics.key_streams import KeyStreams

FULL_TURN = 360.0
RADIANS_PER_DEGREE = np.pi / 180.0
ACTIONS = ("move", "turn")
ACTION_PATTERN = r"^(move|turn)\s+[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?$"   # "move 30", "turn -90"
MOMENT_GRID = 256           # grid points per axis for the prior's moments (Gaussian filters only)
MAX_REJECTION_ROUNDS = 1000   # the prior's rejection sampling gives up (free space < ~0.1 % of the box)

Wall = tuple[StrictFloat, StrictFloat, StrictFloat, StrictFloat]


def _action(value: Any) -> Any:
    """Accept 'move 30' / 'turn -90' as well as {move: 30} / {turn: -90}."""
    if isinstance(value, str):
        parts = value.split()
        if len(parts) == 2 and parts[0] in ACTIONS:
            try:
                return {parts[0]: float(parts[1])}
            except ValueError:
                pass
        raise ValueError(f"expected 'move <cm>' or 'turn <degrees>', got {value!r}")
    if isinstance(value, dict) and len(value) != 1:
        raise ValueError("an action is one of {move: <cm>} or {turn: <degrees>}")
    return value


Action = Annotated[dict[Literal["move", "turn"], StrictFloat], BeforeValidator(
    _action, json_schema_input_type=Union[Annotated[str, StringConstraints(pattern=ACTION_PATTERN)],
                                          dict[Literal["move", "turn"], float]])]


def _direction(heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos, sin) of a heading in degrees."""
    xp = namespace(heading)
    radians = heading * RADIANS_PER_DEGREE
    return xp.cos(radians), xp.sin(radians)


class FreeSpaceLaw(BaseModel):
    """Uniform over the map's free space, heading uniform in [0, 360) degrees.

    Drawn by rejection: candidates uniform in the box around the walls, kept if in free space,
    until every trial has its count. Each trial draws from its own stream until it alone is
    full, so the draws of a trial do not depend on the other trials of its batch.

    On the JAX backend (``random`` a :class:`~pfx.numerics.key_streams.KeyStreams`) the rounds
    are a ``lax.while_loop``: every trial draws in every round (a trial already full ignores its
    draws), round j from the keys of this draw folded with j, so a trial's poses still depend on
    its own keys alone. A slot still empty after the last round holds NaN: a lost particle,
    which the JAX engine reports, as it cannot raise here.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["free_space"] = "free_space"
    walls: list[Wall] = Field(description="the map's walls [x1, y1, x2, y2]")

    _map: WallMap = PrivateAttr(None)

    @model_validator(mode="after")
    def _build(self) -> "FreeSpaceLaw":
        self._map = WallMap(self.walls)
        return self

    def bind(self, dimension: int) -> "FreeSpaceLaw":
        if dimension != 3:
            raise ValueError(f"the free-space law is over poses [x, y, heading], not {dimension} value(s)")
        return self

    def sample(self, random, shape=()) -> np.ndarray:
        count = int(np.prod(shape, dtype=np.int64))
        trials = len(random)
        if isinstance(random, KeyStreams):
            return self._sample_by_keys(random, count).reshape((trials,) + tuple(shape) + (3,))
        out = np.empty((trials, count, 3))
        filled = np.zeros(trials, dtype=np.int64)
        pending = np.arange(trials)
        for _ in range(MAX_REJECTION_ROUNDS):
            if not (pending.size and count):
                return out.reshape((trials,) + tuple(shape) + (3,))
            streams = random if pending.size == trials else random.subset(pending)
            draws = streams.uniform((count, 3))
            candidates = self._candidates(draws)
            inside = self._map.contains(candidates[..., 0], candidates[..., 1])
            slot = filled[pending, None] + np.cumsum(inside, axis=1)       # 1-based slot of each accepted
            keep = inside & (slot <= count)
            rows, columns = np.nonzero(keep)
            out[pending[rows], slot[rows, columns] - 1] = candidates[rows, columns]
            filled[pending] = np.minimum(slot[:, -1], count)
            pending = pending[filled[pending] < count]
        raise ModelNumericalError(f"the map's free space is empty or tiny: {MAX_REJECTION_ROUNDS} rounds of "
                                  "uniform draws in the box around the walls did not fill the prior")

    def _candidates(self, draws):
        """Uniform draws (..., 3) on [0, 1) made into poses uniform in the walls' box, any heading."""
        xp = namespace(draws)
        low, high = self._map.bounds
        return xp.concatenate([low + (high - low) * draws[..., :2], FULL_TURN * draws[..., 2:]], axis=-1)

    def _sample_by_keys(self, random: KeyStreams, count: int):
        """The rejection rounds on JAX arrays (class docstring): (trials, count, 3)."""
        import jax
        import jax.numpy as jnp

        trials = len(random)
        if count == 0:
            return jnp.zeros((trials, 0, 3), random.dtype)
        streams = random.at(random.counter)       # this draw's keys; the rounds are folded below them
        random.counter += 1
        rows = jnp.arange(trials)[:, None]

        def another_round(carry):
            round_index, out, filled = carry
            candidates = self._candidates(streams.at(round_index).uniform((count, 3)))
            inside = self._map.contains(candidates[..., 0], candidates[..., 1])
            slot = filled[:, None] + jnp.cumsum(inside, axis=1)       # 1-based slot of each accepted
            target = jnp.where(inside & (slot <= count), slot - 1, count)     # count: out of range, dropped
            out = out.at[rows, target].set(candidates, mode="drop")
            return round_index + 1, out, jnp.minimum(slot[:, -1], count).astype(filled.dtype)

        def unfinished(carry):
            round_index, _, filled = carry
            return (round_index < MAX_REJECTION_ROUNDS) & jnp.any(filled < count)

        empty = jnp.full((trials, count, 3), jnp.nan, random.dtype)
        _, out, _ = jax.lax.while_loop(unfinished, another_round, (jnp.int32(0), empty, jnp.zeros(trials, jnp.int32)))
        return out

    def _moment_points(self) -> np.ndarray:
        low, high = self._map.bounds
        axes = [low[j] + (high[j] - low[j]) * (np.arange(MOMENT_GRID) + 0.5) / MOMENT_GRID for j in range(2)]
        x, y = np.meshgrid(*axes, indexing="ij")
        inside = self._map.contains(x, y)
        return np.column_stack([x[inside], y[inside]])

    def mean_vector(self) -> np.ndarray:
        """Centroid of free space (on a fine grid) and the mean heading of U[0, 360): 180."""
        return np.append(self._moment_points().mean(axis=0), FULL_TURN / 2.0)

    def covariance_matrix(self) -> np.ndarray:
        covariance = np.zeros((3, 3))
        covariance[:2, :2] = np.cov(self._moment_points().T, bias=True)
        covariance[2, 2] = FULL_TURN ** 2 / 12.0
        return covariance


@MODELS.register_kind
class SonarMCL(Model):
    """kim-mcl: pose <x, y, heading> in a walled arena, moves and turns, one forward sonar."""

    kind: Literal["sonar_mcl"] = "sonar_mcl"
    walls: Optional[list[Wall]] = Field(
        None, description="wall segments [[x1, y1, x2, y2], ...] in cm, forming closed polygons: the "
                          "arena's outline and any obstacles (no default: give walls or map_file)")
    map_file: Optional[str] = Field(
        None, description="file of walls instead of `walls`: YAML (a list of [x1, y1, x2, y2]) or CSV "
                          "(header x1,y1,x2,y2); a relative path is read from the config file's folder; "
                          "the resolved config lists the walls read (no default)")
    route: list[Action] = Field(
        min_length=1, description="the commanded actions, one per step: {move: cm} or {turn: degrees} "
                                  "(or 'move 30', 'turn -90'); positive turns are counter-clockwise")
    motion: Literal["noisy", "noise-free"] = Field(
        "noisy", description="noisy: moves and turns with move_bias, turn_bias and process_noise; "
                             "noise-free: the commanded action exactly (biases 1, no noise)")
    move_bias: StrictFloat = Field(0.92, gt=0, description="mean distance covered / commanded distance (paper: 0.92)")
    turn_bias: StrictFloat = Field(1.03, gt=0, description="mean angle turned / commanded angle (paper: 1.03)")
    process_noise: Optional[Noise] = Field(
        None, description="motion noise [w_move, w_turn]: variance [cm^2, deg^2] of the distance "
                          "covered and the angle turned (preset: the paper's [9.0, 13.0])")
    initial: Optional[InitialLaw] = Field(
        None, description="the real robot's start pose, {kind: point, state: [x, y, heading]} in cm, cm "
                          "and degrees (no default; required)")
    measurement_noise: Optional[Noise] = Field(
        None, description="sonar noise v, variance in cm^2 (preset: the paper's 1.0)")
    max_range: StrictFloat = Field(
        255.0, gt=0, description="sonar range in cm: nothing nearer reads max_range (Lego NXT "
                                 "ultrasonic sensor: 255)")
    clearance: StrictFloat = Field(
        1.0, ge=0, description="a move that would cross a wall stops this many cm short of it")
    kidnap: Optional[Kidnap] = Field(
        None, description="{step: k, to: [x, y, heading]}: the true robot is carried to `to` at step k "
                          "(the filter is not told); default none")

    _map: WallMap = PrivateAttr(None)
    _controls: np.ndarray = PrivateAttr(None)

    @model_validator(mode="before")
    @classmethod
    def _read_map_file(cls, data: Any, info: ValidationInfo) -> Any:
        """Replace map_file by the walls it lists (so the resolved config holds the map itself)."""
        if not isinstance(data, dict) or data.get("map_file") is None or not isinstance(data["map_file"], str):
            return data
        if data.get("walls") is not None:
            raise ValueError("@map_file: give walls or map_file, not both")
        config_file = (info.context or {}).get("config_file")
        path = Path(data["map_file"])
        if config_file and not path.is_absolute():
            path = Path(config_file).parent / path
        try:
            walls = read_wall_file(path)
        except ValueError as error:
            raise ValueError(f"@map_file: {error}") from None
        return {**data, "walls": walls, "map_file": None}

    def presets(self):
        if self.motion == "noise-free":
            # the commanded action exactly, whatever was given (e.g. merged from the truth's settings)
            self.move_bias, self.turn_bias = 1.0, 1.0
            self.process_noise = Noise(family="gaussian", variance=0.0)
        if self.initial is None:
            raise ValueError("@initial: required: the real robot's start pose, "
                             "{kind: point, state: [x_cm, y_cm, heading_degrees]}")
        return {
            "steps": len(self.route), "dt": 1.0,
            "process_noise": Noise(family="gaussian", variance=[9.0, 13.0]),
            "measurement_noise": Noise(family="gaussian", variance=1.0),
        }

    def check(self):
        if self.walls is None:
            raise ValueError("@walls: required: the arena's walls [[x1, y1, x2, y2], ...] in cm (or map_file)")
        if len(self.walls) < 3:
            raise ValueError("@walls: at least 3 walls are needed to enclose an arena")
        for index, (x1, y1, x2, y2) in enumerate(self.walls):
            if x1 == x2 and y1 == y2:
                raise ValueError(f"@walls[{index}]: a wall needs two different end points")
        wall_map = WallMap(self.walls)
        open_ends = wall_map.open_ends()
        if open_ends:
            index, (x, y) = open_ends[0]
            raise ValueError(f"@walls[{index}]: walls must form closed polygons (the arena's outline, "
                             f"obstacles); the end ({x:g}, {y:g}) meets no other wall")
        for index, action in enumerate(self.route):
            if next(iter(action.values())) == 0.0:
                raise ValueError(f"@route[{index}]: an action of 0 does nothing; remove it")
        if self.steps > len(self.route):
            raise ValueError(f"@steps: the route has only {len(self.route)} action(s), one per step")
        if self.kidnap is not None:
            self.kidnap.check(self.steps)
            x, y, _ = self.kidnap.to
            if not wall_map.contains(x, y):
                raise ValueError(f"@kidnap.to: the position ({x:g}, {y:g}) is not in the arena's free space")
        start, key = None, None
        if isinstance(self.initial, PointLaw):
            start, key = self.initial.state, "initial.state"
        elif isinstance(self.initial, GaussianLaw):
            start, key = self.initial.mean, "initial.mean"
        if start is not None and len(start) == 3 and not wall_map.contains(start[0], start[1]):
            raise ValueError(f"@{key}: the start position ({start[0]:g}, {start[1]:g}) is not in the "
                             "arena's free space (inside the outline, outside obstacles)")

    def setup(self):
        self._map = WallMap(self.walls)
        self._controls = np.array([[action.get("move", 0.0), action.get("turn", 0.0)] for action in self.route])

    @property
    def state_names(self):
        return ("x", "y", "heading")

    @property
    def state_units(self):
        return ("cm", "cm", "deg")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def process_noise_dimension(self):
        return 2

    @property
    def position_components(self):
        return (0, 1)

    @property
    def angular_components(self):
        return (2,)

    @property
    def full_turn(self):
        return FULL_TURN

    time_unit: ClassVar[str] = "action"

    @property
    def wall_map(self) -> WallMap:
        return self._map

    def default_prior(self):
        return FreeSpaceLaw(walls=self.walls)

    def scene(self):
        """The walls, and the commanded route as a ``path``: one row per action, executed exactly.

        Row k of the path is where the noise-free route puts the robot after action k (row 0:
        the start, when the start is a point); its ``label`` is k and ``heading`` the heading
        then, so a map can number the actions (several turns share one position).
        """
        elements = [{"element": "wall", "x": x1, "y": y1, "x_end": x2, "y_end": y2}
                    for x1, y1, x2, y2 in self.walls]
        if isinstance(self.initial, PointLaw) and len(self.initial.state) == 3:
            x, y, heading = self.initial.state
            elements.append({"element": "path", "x": x, "y": y, "heading": heading, "label": "0"})
            for number, (distance, angle) in enumerate(self._controls, start=1):
                cos, sin = _direction(np.asarray(heading))
                x, y = x + distance * float(cos), y + distance * float(sin)
                heading = float(wrap_into_turn(np.asarray(heading + angle), FULL_TURN))
                elements.append({"element": "path", "x": x, "y": y, "heading": heading, "label": str(number)})
        return elements

    def truth_event(self, state, step):
        return state if self.kidnap is None else self.kidnap.apply(state, step)

    def control(self, step):
        """u_k = [d, 0] for a move of d cm, [0, alpha] for a turn of alpha degrees."""
        return self._controls[step - 1]

    def propagate(self, state, control, noise):
        """A move (``control = [d, 0]``) or a turn (``[0, alpha]``) with its noise (module docstring)."""
        distance, angle = control[0], control[1]
        if namespace(control) is np:          # a host control: only its action is computed
            return self._move(state, distance, noise) if distance != 0.0 else self._turn(state, angle, noise)
        # a traced control (the JAX backend): both actions computed, the commanded one kept
        return namespace(control).where(distance != 0.0, self._move(state, distance, noise),
                                        self._turn(state, angle, noise))

    def _move(self, state, distance, noise):
        """x' = x + delta cos(theta), y' = y + delta sin(theta) with delta = b_d d + w_d, stopped at walls."""
        xp = namespace(state, distance, noise)
        x, y, heading = state[..., 0], state[..., 1], state[..., 2]
        cos, sin = _direction(heading)
        covered = self._stop_at_walls(x, y, cos, sin, self.move_bias * distance + noise[..., 0])
        return xp.stack([x + covered * cos, y + covered * sin, heading], axis=-1)

    def _turn(self, state, angle, noise):
        """theta' = theta + b_alpha alpha + w_alpha (mod 360); the position unchanged."""
        xp = namespace(state, angle, noise)
        turned = wrap_into_turn(state[..., 2] + self.turn_bias * angle + noise[..., 1], FULL_TURN)
        return xp.stack([state[..., 0], state[..., 1], turned], axis=-1)

    def _stop_at_walls(self, x, y, cos, sin, distance):
        """The signed distance, shortened to stop ``clearance`` before the wall in its way."""
        xp = namespace(x, y, distance)
        direction = xp.where(distance >= 0.0, 1.0, -1.0)
        free = self._map.ray_distance(x, y, direction * cos, direction * sin)
        return direction * xp.minimum(xp.abs(distance), xp.maximum(free - self.clearance, 0.0))

    def wall_distance(self, state) -> np.ndarray:
        """r(x): distance from the pose straight ahead to the nearest wall (inf if none), shape (...)."""
        return self._map.ray_distance(state[..., 0], state[..., 1], *_direction(state[..., 2]))

    def measurement_mean(self, state):
        return namespace(state).minimum(self.wall_distance(state), self.max_range)[..., None]

    def measure(self, state, noise):
        return namespace(state, noise).minimum(self.wall_distance(state)[..., None] + noise, self.max_range)

    def log_likelihood(self, measurement, state):
        xp = namespace(measurement, state)
        expected = self.wall_distance(state)[..., None]
        with np.errstate(invalid="ignore"):       # inf - inf cannot occur: readings are finite
            density = self.measurement_noise.log_density(measurement - expected)
        saturated = measurement[..., 0] >= self.max_range
        if xp is np and not np.any(saturated):    # NumPy: the tail only where a reading saturated
            return density
        return xp.where(saturated, self.measurement_noise.log_tail(self.max_range - expected), density)
