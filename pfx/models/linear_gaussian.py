r"""Linear state-space model of any dimension.

.. math::

    x_k = A x_{k-1} + B u_k + w_k, \qquad z_k = H x_k + v_k,

with :math:`w_k` and :math:`v_k` from the configured noise families (gaussian by default,
when the Kalman filter is the exact posterior). Matrices are given in the config as lists of
rows; ``controls`` is one input vector for every step or a list of T vectors.

EKF Jacobians: analytic (F = A, L = I, H = H), so the EKF on this model is the Kalman filter.

The matrices are NumPy float64 arrays; ``propagate`` and ``measurement_mean`` take NumPy or JAX
arrays (:mod:`pfx.numerics.arrays`) and cast them to the state's dtype (float64 or float32).
"""

from __future__ import annotations

from typing import Literal, Optional

import numpy as np
from pydantic import Field, PrivateAttr, StrictFloat

from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.numerics.arrays import namespace

Matrix = list[list[StrictFloat]]


@MODELS.register_kind
class LinearGaussian(Model):
    """Linear model x' = A x + B u + w, z = H x + v (any dimension)."""

    kind: Literal["linear_gaussian"] = "linear_gaussian"
    transition_matrix: Matrix = Field(description="A (d x d)")
    measurement_matrix: Matrix = Field(description="H (m x d)")
    control_matrix: Optional[Matrix] = Field(None, description="B (d x c); needs controls")
    controls: Optional[list[list[StrictFloat]]] = Field(
        None, description="control inputs u_k: one vector (used at every step) or T vectors")
    names: Optional[list[str]] = Field(None, description="state component names (default x1..xd)")
    position: Optional[list[int]] = Field(
        None, description="0-based indices of the components forming the position (default: all)")

    # the noise variances may differ by trial row or particle (parameter estimation)
    vectorised_parameters = ("process_noise.variance", "measurement_noise.variance")

    _A: np.ndarray = PrivateAttr(None)
    _H: np.ndarray = PrivateAttr(None)
    _B: Optional[np.ndarray] = PrivateAttr(None)
    _U: Optional[np.ndarray] = PrivateAttr(None)

    def presets(self):
        d = len(self.transition_matrix)
        return {
            "steps": 50, "dt": 1.0,
            "process_noise": Noise(family="gaussian", variance=1.0),
            "measurement_noise": Noise(family="gaussian", variance=1.0),
            "initial": GaussianLaw(mean=[0.0] * d, covariance=1.0),
        }

    def check(self):
        for key in ("transition_matrix", "measurement_matrix", "control_matrix", "controls"):
            rows = getattr(self, key)
            if rows is not None and len({len(row) for row in rows}) > 1:
                raise ValueError(f"@{key}: every row must have the same length")
        A = np.asarray(self.transition_matrix, dtype=float)
        if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
            raise ValueError("@transition_matrix: must be a non-empty square matrix (list of rows)")
        H = np.asarray(self.measurement_matrix, dtype=float)
        if H.ndim != 2 or H.shape[1] != A.shape[0] or H.shape[0] == 0:
            raise ValueError(f"@measurement_matrix: must have {A.shape[0]} columns (one per state component)")
        if (self.control_matrix is None) != (self.controls is None):
            raise ValueError("@controls: control_matrix and controls go together")
        if self.control_matrix is not None:
            B = np.asarray(self.control_matrix, dtype=float)
            if B.ndim != 2 or B.shape[0] != A.shape[0]:
                raise ValueError(f"@control_matrix: must have {A.shape[0]} rows")
            U = np.asarray(self.controls, dtype=float)
            if U.ndim != 2 or U.shape[1] != B.shape[1]:
                raise ValueError(f"@controls: each control vector needs {B.shape[1]} value(s)")
            if U.shape[0] not in (1, self.steps):
                raise ValueError(f"@controls: give one vector or {self.steps} (one per step)")
        if self.names is not None and len(self.names) != A.shape[0]:
            raise ValueError(f"@names: expected {A.shape[0]} names")
        if self.position is not None and any(not 0 <= i < A.shape[0] for i in self.position):
            raise ValueError(f"@position: indices must lie in 0..{A.shape[0] - 1}")

    def setup(self):
        self._A = np.asarray(self.transition_matrix, dtype=float)
        self._H = np.asarray(self.measurement_matrix, dtype=float)
        if self.control_matrix is not None:
            self._B = np.asarray(self.control_matrix, dtype=float)
            self._U = np.asarray(self.controls, dtype=float)

    @property
    def state_names(self):
        return tuple(self.names) if self.names else tuple(f"x{i + 1}" for i in range(len(self.transition_matrix)))

    @property
    def measurement_dimension(self):
        return len(self.measurement_matrix)

    @property
    def position_components(self):
        return tuple(self.position) if self.position else tuple(range(self.state_dimension))

    @property
    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, H) as arrays."""
        return self._A, self._H

    def control(self, step):
        if self._U is None:
            return None
        if len(self._U) == 1:
            return self._B @ self._U[0]
        if not 1 <= step <= len(self._U):      # ValueError, not numpy's IndexError: the step is the user's
            raise ValueError(f"@controls: {len(self._U)} control vectors, for steps 1..{len(self._U)}; "
                             f"none for step {step}")
        return self._B @ self._U[step - 1]

    def propagate(self, state, control, noise):
        moved = state @ namespace(state).asarray(self._A, dtype=state.dtype).T
        if control is not None:
            moved = moved + control
        return moved + noise

    def measurement_mean(self, state):
        return state @ namespace(state).asarray(self._H, dtype=state.dtype).T

    def transition_jacobian(self, state, control):
        xp = namespace(state)
        return xp.broadcast_to(xp.asarray(self._A, dtype=state.dtype), state.shape[:-1] + self._A.shape)

    def process_noise_jacobian(self, state, control):
        xp = namespace(state)
        return xp.broadcast_to(xp.eye(self.state_dimension, dtype=state.dtype),
                               state.shape[:-1] + (self.state_dimension,) * 2)

    def measurement_jacobian(self, state):
        xp = namespace(state)
        return xp.broadcast_to(xp.asarray(self._H, dtype=state.dtype), state.shape[:-1] + self._H.shape)
