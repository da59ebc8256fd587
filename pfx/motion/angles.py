r"""Angles: the one place pfx's motion models wrap a heading.

.. math:: \operatorname{wrap}(a) = \pi - \big((\pi - a) \bmod 2\pi\big) \in (-\pi, \pi].

Probabilistic Robotics asks for every angle difference (a change of heading, a bearing, the
rotation error :math:`\hat\gamma`) to be normalised to this interval; without it a heading of
:math:`\pi - \epsilon` and one of :math:`-\pi + \epsilon` would look :math:`2\pi` apart.
"""

from __future__ import annotations

import numpy as np


def wrap_angle(angle):
    """The angle (radians, any shape) mapped into (-pi, pi]: both -pi and pi become pi."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)
