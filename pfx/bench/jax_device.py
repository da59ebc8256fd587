r"""The device JAX runs the benchmark on: its name, its memory, and its memory-bandwidth limit.

A bootstrap particle-step must at least move each particle's state through memory a few times
(read it, write the propagated state, read that back to weigh it, write the resampled copy: 4d
scalars), and a handful of per-particle scalars (the weight, its exponential, the cumulative sum,
the resampling offset, the noise's share), and a 4-byte ancestor index. The issue's count is

.. math::

    \text{bytes per particle-step} = (4d + 5)\,s + 4, \qquad d = 3,

with :math:`s` = 8 bytes (float64) or 4 (float32): 140 and 72 bytes. No filter can do more
particle-steps per second than the device's memory bandwidth divided by that; the benchmark
prints each row's rate as a fraction of this limit. The bandwidth comes from
:data:`KNOWN_BANDWIDTHS` (the maker's figure for the card named by ``jax.devices()``), or
from ``pfx bench --bandwidth BYTES_PER_S``; where neither knows it, the column stays blank.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Optional

from pfx.bench.report import cpu_model
from pfx.run.memory import available_memory

STATE_DIMENSION = 3          # the falling body's (altitude, velocity, ballistic coefficient)
INDEX_BYTES = 4
SCALAR_BYTES = {"float64": 8, "float32": 4}

# (words that all appear in jax's device_kind, bytes per second, the card): the makers' figures.
KNOWN_BANDWIDTHS = [
    (("H200",), 4.8e12, "NVIDIA H200"),
    (("H100", "HBM3"), 3.35e12, "NVIDIA H100 SXM"),          # device_kind "NVIDIA H100 80GB HBM3"
    (("A100", "80GB"), 2.0e12, "NVIDIA A100 80GB"),
]


def bytes_per_particle_step(precision: str, dimension: int = STATE_DIMENSION) -> int:
    """(4d + 5) scalars and a 4-byte index (module docstring)."""
    return (4 * dimension + 5) * SCALAR_BYTES[precision] + INDEX_BYTES


def working_set_bytes(particles_per_step: int, precision: str) -> int:
    """A rough peak of a JAX filter's device memory for ``particles_per_step`` (trials x N)
    particles: the arrays a step holds at once (the state and its moved and resampled copies, the
    noise, the weights, the float64 cumulative sums and offsets, the indices), about twice what a
    particle-step reads and writes, and 16 bytes of slack a particle."""
    return particles_per_step * (2 * bytes_per_particle_step(precision) + 16)


@dataclass(frozen=True)
class Device:
    """The JAX device, as the benchmark reports it."""

    platform: str                 # "cpu", "gpu", ...
    kind: str                     # jax's device_kind: "NVIDIA H200", "cpu"
    memory: Optional[int]         # bytes the benchmark may fill: the device's limit, or available RAM on a CPU
    bandwidth: Optional[float]    # bytes per second, None where unknown
    bandwidth_source: str         # where the bandwidth came from

    @property
    def is_gpu(self) -> bool:
        return self.platform == "gpu"

    def limit(self, precision: str) -> Optional[float]:
        """The memory-bandwidth limit in particle-steps per second, None where the bandwidth is unknown."""
        return self.bandwidth / bytes_per_particle_step(precision) if self.bandwidth else None


def known_bandwidth(kind: str) -> Optional[tuple[float, str]]:
    for words, bandwidth, card in KNOWN_BANDWIDTHS:
        if all(word.lower() in kind.lower() for word in words):
            return bandwidth, card
    return None


def jax_device(bandwidth: Optional[float] = None) -> Device:
    """The default JAX device, its memory, and its bandwidth (``bandwidth`` given, else the table's)."""
    import jax

    device = jax.devices()[0]
    stats = device.memory_stats() if hasattr(device, "memory_stats") else None
    memory = (stats or {}).get("bytes_limit") or available_memory()
    known = known_bandwidth(device.device_kind)
    if bandwidth:
        source = "--bandwidth"
    elif known:
        bandwidth, source = known[0], f"the maker's figure for the {known[1]}"
    else:
        source = "unknown"
    return Device(device.platform, device.device_kind, memory, bandwidth, source)


def machine_line(device: Device) -> str:
    """The CPU (pfx's numpy backend runs there), JAX's version and device, its memory and bandwidth."""
    import jax

    memory = f"{device.memory / 1024 ** 3:.0f} GiB {'available RAM' if device.platform == 'cpu' else 'of memory'}" \
        if device.memory else "memory unknown"
    bandwidth = (f"memory bandwidth {device.bandwidth:.3g} B/s ({device.bandwidth_source})" if device.bandwidth else
                 "memory bandwidth unknown (the fraction column is blank: give --bandwidth BYTES_PER_S)")
    return (f"machine: {cpu_model()}, {os.cpu_count()} cores; jax {jax.__version__}, device "
            f"{device.kind} ({device.platform}), {memory}; {bandwidth}")
