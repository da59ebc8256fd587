r"""A map of wall segments: ray casting, free space, and map files.

A map is a set of straight walls :math:`[a_j, b_j]` (end points in the plane, in centimetres
for kim-mcl) that form closed polygons: the arena's outline and any obstacles standing in it.
**Free space** is every point inside an odd number of polygons (the even-odd rule): inside the
outline and outside every obstacle. A point is tested by counting the walls crossed by the
horizontal ray from it towards :math:`+x`, so the map never needs to know which polygon is the
outline and which an obstacle, nor the order of the walls.

**Ray casting.** The ray :math:`p + t\,d` (:math:`t \ge 0`, unit direction :math:`d`) meets
the wall :math:`a + s\,e` (:math:`e = b - a`, :math:`s \in [0, 1]`) where

.. math:: t = \frac{(a - p) \times e}{d \times e}, \qquad
          s = \frac{(a - p) \times d}{d \times e}, \qquad u \times v = u_x v_y - u_y v_x .

The distance to the wall ahead is the smallest such :math:`t` over all walls (infinite where the
ray meets none). A ray parallel to a wall (:math:`d \times e = 0`) does not meet it: in a closed
polygon the ray that runs along a wall's line meets the next wall at the shared corner instead.
A ray through a corner (:math:`s` = 0 or 1, up to a relative 1e-9) meets it. Every quantity is an
array over the points' leading dimensions times the walls: no Python loop over points, nor over
walls, so :meth:`WallMap.ray_distance` and :meth:`WallMap.contains` take NumPy or JAX arrays
(:mod:`pfx.numerics.arrays`; the walls stay NumPy constants) and serve both backends. On NumPy
the ray casting works in place (it is the sonar model's hot spot); on JAX, where arrays cannot be
written, it computes the same t and s without writing (:meth:`WallMap._ray_distance_functional`).

A map file holds the walls as YAML (a list of ``[x1, y1, x2, y2]``, or ``{walls: [...]}``) or
as CSV with the header ``x1,y1,x2,y2`` and one wall per row.
"""

from __future__ import annotations

import csv
import io
from collections import Counter
from pathlib import Path

import numpy as np

from pfx.errors import ConfigError
from pfx.numerics.arrays import namespace
from pfx.safe_yaml import MAX_FILE_BYTES, parse_yaml
from pfx.user_files import UnreadableFile, read_user_file

CORNER_TOLERANCE = 1e-9     # relative slack on s in [0, 1], so a ray through a corner meets it
CSV_HEADER = ["x1", "y1", "x2", "y2"]


def cross(ux, uy, vx, vy):
    """The planar cross product u x v = u_x v_y - u_y v_x."""
    return ux * vy - uy * vx


class WallMap:
    """Walls as arrays (start points a_j and edges e_j = b_j - a_j), with the map's geometry."""

    def __init__(self, walls) -> None:
        walls = np.asarray(walls, dtype=float).reshape(-1, 4)
        self.walls = walls
        self.start_x, self.start_y = walls[:, 0], walls[:, 1]
        self.edge_x, self.edge_y = walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]
        with np.errstate(over="ignore", invalid="ignore"):     # absurd coordinates: caught where used
            self._start_cross_edge = cross(self.start_x, self.start_y, self.edge_x, self.edge_y)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the box around every wall."""
        points = self.walls.reshape(-1, 2)
        return points.min(axis=0), points.max(axis=0)

    def ray_distance(self, x: np.ndarray, y: np.ndarray, cos_heading: np.ndarray,
                     sin_heading: np.ndarray) -> np.ndarray:
        """Distance from (x, y) along the unit direction (cos, sin) to the first wall; inf if none.

        The arguments broadcast together to a shape S; the result has shape S.
        """
        xp = namespace(x, y, cos_heading, sin_heading)
        if xp is not np:
            return self._ray_distance_functional(xp, *xp.broadcast_arrays(x, y, cos_heading, sin_heading))
        x, y, dx, dy = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, y, cos_heading, sin_heading)))
        shape = x.shape
        point = np.stack([x.ravel(), y.ravel()], axis=-1)             # (P, 2)
        direction = np.stack([dx.ravel(), dy.ravel()], axis=-1)
        # Every point-by-wall cross product is a matrix product: u x e = u @ [e_y, -e_x] and
        # a x d = d @ [-a_y, a_x], so (a - p) x e = a x e - p @ [e_y, -e_x] and
        # (a - p) x d = d @ [-a_y, a_x] - p x d.
        normal = np.stack([self.edge_y, -self.edge_x])                   # (2, W)
        start_normal = np.stack([-self.start_y, self.start_x])
        denominator = direction @ normal                                 # d x e, (P, W)
        along_ray = self._start_cross_edge - point @ normal              # (a - p) x e
        along_wall = direction @ start_normal - cross(point[:, :1], point[:, 1:], direction[:, :1],
                                                      direction[:, 1:])  # (a - p) x d
        with np.errstate(divide="ignore", invalid="ignore"):
            # parallel walls give t, s = +-inf or nan: no comparison below holds for them
            t = np.divide(along_ray, denominator, out=along_ray)
            s = np.divide(along_wall, denominator, out=along_wall)
            # s in [0, 1] (with the corner slack) as one comparison: |s - 1/2| <= 1/2
            np.subtract(s, 0.5, out=s)
            np.abs(s, out=s)
            miss = np.greater(s, 0.5 + CORNER_TOLERANCE, out=np.empty(s.shape, dtype=bool))
            miss |= ~(t >= 0.0)
        t[miss] = np.inf
        return t.min(axis=-1).reshape(shape)

    def _ray_distance_functional(self, xp, x, y, dx, dy):
        """:meth:`ray_distance` without writing into arrays (JAX), points of any shape S.

        The cross products are written out per (point, wall) pair, (S..., W), rather than as
        matrix products: a float32 matrix product on a GPU may run at reduced (TF32) precision.
        The same t and s, up to rounding, as the NumPy path.
        """
        offset_x = self.start_x - x[..., None]                         # a - p, (S..., W)
        offset_y = self.start_y - y[..., None]
        denominator = cross(dx[..., None], dy[..., None], self.edge_x, self.edge_y)   # d x e
        t = cross(offset_x, offset_y, self.edge_x, self.edge_y) / denominator         # (a - p) x e / d x e
        s = cross(offset_x, offset_y, dx[..., None], dy[..., None]) / denominator     # (a - p) x d / d x e
        # parallel walls give t, s = +-inf or nan: neither comparison holds for them
        meets = (xp.abs(s - 0.5) <= 0.5 + CORNER_TOLERANCE) & (t >= 0.0)
        return xp.min(xp.where(meets, t, np.inf), axis=-1)

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where (x, y) lies in free space (even-odd rule; see the module docstring)."""
        xp = namespace(x, y)
        px, py = xp.asarray(x)[..., None], xp.asarray(y)[..., None]
        end_y = self.start_y + self.edge_y
        straddles = (self.start_y > py) != (end_y > py)      # the wall crosses the line y = p_y
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            crossing_x = self.start_x + (py - self.start_y) * self.edge_x / self.edge_y
        crossings = xp.count_nonzero(straddles & (crossing_x > px), axis=-1)
        return crossings % 2 == 1

    def open_ends(self) -> list[tuple[int, tuple[float, float]]]:
        """(wall index, end point) of every wall end that meets no other wall end.

        In closed polygons every corner is shared by an even number of wall ends.
        """
        ends = [(index, (float(w[0]), float(w[1]))) for index, w in enumerate(self.walls)]
        ends += [(index, (float(w[2]), float(w[3]))) for index, w in enumerate(self.walls)]
        count = Counter(point for _, point in ends)
        return sorted((index, point) for index, point in ends if count[point] % 2 == 1)


def read_wall_file(path: Path) -> list[list[float]]:
    """The walls listed in a map file (YAML or CSV; see the module docstring).

    Raises ValueError with a reason naming the file (and the row or line) on any problem.
    """
    name = str(path)
    try:
        data = read_user_file(path, MAX_FILE_BYTES)
    except UnreadableFile as error:
        if error.missing:
            raise ValueError(f"cannot read map file {name!r} (no such file)") from None
        raise ValueError(f"map file {name!r} {error.reason}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"map file {name!r} is not UTF-8 text") from None
    if Path(name).suffix.lower() == ".csv":
        return _walls_from_csv(text, name)
    try:
        document = parse_yaml(text, name)
    except ConfigError as error:
        raise ValueError(f"map file {error}") from None
    if isinstance(document, dict) and set(document) == {"walls"}:
        document = document["walls"]
    if not isinstance(document, list):
        raise ValueError(f"map file {name!r} must hold a list of walls [x1, y1, x2, y2] "
                         "(or a mapping with the one key walls)")
    return [_wall(row, f"map file {name!r}, walls[{index}]") for index, row in enumerate(document)]


def _walls_from_csv(text: str, name: str) -> list[list[float]]:
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or [cell.strip() for cell in rows[0]] != CSV_HEADER:
        raise ValueError(f"map file {name!r} must start with the header {','.join(CSV_HEADER)}")
    return [_wall([cell.strip() for cell in row], f"map file {name!r}, line {line}")
            for line, row in enumerate(rows[1:], start=2) if row]


def _wall(row, where: str) -> list[float]:
    """One wall as four finite numbers; numbers in text (CSV cells) are parsed."""
    if not isinstance(row, (list, tuple)) or len(row) != 4:
        raise ValueError(f"{where}: expected four numbers x1, y1, x2, y2")
    values = []
    for value in row:
        if isinstance(value, bool):
            raise ValueError(f"{where}: expected four numbers x1, y1, x2, y2")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: {value!r} is not a number") from None
        if not np.isfinite(number):
            raise ValueError(f"{where}: coordinates must be finite")
        values.append(number)
    return values
