r"""Angles: the one place pfx's motion models wrap a heading.

.. math:: \operatorname{wrap}(a) = \pi - \big((\pi - a) \bmod 2\pi\big) \in (-\pi, \pi].

Probabilistic Robotics asks for every angle difference (a change of heading, a bearing, the
rotation error :math:`\hat\gamma`) to be normalised to this interval; without it a heading of
:math:`\pi - \epsilon` and one of :math:`-\pi + \epsilon` would look :math:`2\pi` apart. It is
:func:`pfx.angles.wrap_difference` at a full turn of :math:`2\pi`.
"""

from __future__ import annotations

import numpy as np

from pfx.angles import wrap_difference


def wrap_angle(angle):
    """The angle (radians, any shape) mapped into (-pi, pi]: both -pi and pi become pi."""
    return wrap_difference(np.asarray(angle, dtype=float), 2.0 * np.pi)
