"""Memory: estimate what a cell needs, size batches of trials to fit, refuse what cannot.

The engine holds, per trial, a handful of particle-sized arrays (the state, its prediction and
the model's temporaries, log-weights, weights, the weighting's innovations) and the per-step
traces and values (error, ESS, NEES, NIS and squared error per state, for steps_summary.csv). :func:`trial_bytes` estimates that peak as

    8 bytes x [N (8 d + 4 m + 12) + T (4 d + m + 12)]

for N particles, d state and m measurement components and T steps: about 1.3 to 2.5 times the
peak that tracemalloc measures on the bundled models (``tests/test_memory.py`` checks that it
is never below). Trials are run in batches that fit the budget (by default half the memory
available when the run starts, shared by the worker processes); a cell of which even one
trial does not fit is refused before anything runs, with the estimate.

:func:`keep_freed_memory` tunes the C allocator for the engine's pattern of allocation: every
step creates and frees particle-sized temporaries (megabytes each). By default glibc hands
such blocks back to the system when they are freed and maps fresh pages for the next one,
and each first touch of a fresh page costs a page fault: on the virtual machines pfx is
benchmarked on that doubled the cost of a particle-step at N = 1e5 (``pfx bench``).
"""

from __future__ import annotations

import os
import re
from typing import Optional

from pfx.errors import ConfigError

_UNITS = {"": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}


def parse_size(text: str) -> int:
    """'512M', '4G', '1.5G' or a number of bytes -> bytes."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)i?B?\s*", str(text), re.IGNORECASE)
    if not match:
        raise ConfigError(f"--max-memory: cannot read {text!r} (use e.g. 512M or 4G)")
    return int(float(match.group(1)) * _UNITS[match.group(2).upper()])


def format_size(size: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if size < 1024 or unit == "TiB":
            return f"{size:.1f} {unit}" if unit != "B" else f"{int(size)} B"
        size /= 1024
    return f"{size:.1f} TiB"


def available_memory() -> int:
    """Bytes of memory available now (MemAvailable on Linux; physical memory elsewhere)."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 4 * 1024**3


def default_budget() -> int:
    return available_memory() // 2


def trial_bytes(particles: int, state_dimension: int, measurement_dimension: int, steps: int) -> int:
    """Estimated peak bytes of one trial in the engine (see the module docstring)."""
    d, m = state_dimension, measurement_dimension
    return 8 * (particles * (8 * d + 4 * m + 12) + steps * (4 * d + m + 12))


def cell_trial_bytes(cell, genealogy: bool = False, auto_particles: int = 1) -> int:
    """One trial's peak: the engine's, plus the recorded history the smoothers (or
    genealogy.csv, ``genealogy``) need: T N (d + 1) numbers and T N ancestors, and the smoothers'
    trajectories and temporaries (:func:`pfx.filters.particle.smoothing.history_bytes`)."""
    model = cell.filter_model
    particles = getattr(cell.filter, "particles", 1)
    if particles == "auto":       # PMMH's pilot chooses it (pfx.estimation.particle_count), at most its cap
        particles = auto_particles
    need = trial_bytes(particles, model.state_dimension, model.measurement_dimension, model.steps)
    if cell.filter.uses_particles:
        from pfx.filters.particle.smoothing import history_bytes

        smoothers = list(getattr(cell.filter, "smoothers", None) or ())
        extra = history_bytes(particles, model.state_dimension, model.steps, smoothers)
        if genealogy and not extra:
            extra = model.steps * particles * (8 * model.state_dimension + 8 + 4)
        need += extra
    return need


def check_fits(plan, budget: int) -> None:
    """Refuse the plan if one trial of some cell does not fit the budget."""
    genealogy = bool(getattr(plan.experiment.outputs, "genealogy", 0)) if plan.cells else False
    estimation = getattr(plan.experiment, "estimation", None)
    cap = estimation.pilot.largest if estimation is not None else 1
    for cell in plan.cells:
        need = cell_trial_bytes(cell, genealogy, cap)
        if need > budget:
            smoothing = " with its smoothers' history" if getattr(cell.filter, "smoothers", None) or genealogy else ""
            raise ConfigError(
                f"one trial of cell '{cell.labels['arm']}' ({cell.filter.particles} particles x "
                f"{cell.filter_model.state_dimension} state components{smoothing}) needs about {format_size(need)}, "
                f"more than the memory limit of {format_size(budget)} (half the available memory "
                "unless --max-memory says otherwise); use fewer particles",
                file=plan.file, key="filter.smoothers" if smoothing else "filter.particles")


# Particles per batch from which the engine's fixed cost per step (some 70 microseconds of
# Python and NumPy calls, whatever the batch) is a few per cent of the particles' own work
# (~30 ns each on the benchmark's model): `pfx bench`, N = 1e3 against 1e5.
SPEED_PARTICLES = 65_536


def trials_per_batch(cell, trials: int, budget: int, workers: int = 1, genealogy: bool = False) -> int:
    """Trials run together: as many as fit the budget (shared by the workers); ~10 batches for
    the progress bar, unless that makes batches of fewer than :data:`SPEED_PARTICLES`
    particles, where the per-step cost would dominate (but at least one batch per worker)."""
    workers = max(1, workers)
    by_memory = max(1, budget // workers // cell_trial_bytes(cell, genealogy))
    for_progress = -(-trials // 10) if trials >= 20 else trials
    for_speed = min(-(-SPEED_PARTICLES // max(1, cell.filter.particles)), -(-trials // workers))
    return int(max(1, min(trials, by_memory, max(for_progress, for_speed))))


# mallopt parameters (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 32 * 1024**2           # the largest glibc accepts on 64-bit systems


def keep_freed_memory() -> bool:
    """Ask glibc to serve blocks below 32 MiB from its heap and keep freed memory for reuse.

    The process then holds on to its peak heap until it exits (which the memory budget
    already assumes). Returns whether the allocator accepted (False off glibc: nothing done).
    Commands that run filters call it once (``pfx run``, ``pfx reproduce``, ``pfx bench``);
    worker processes forked from them inherit it.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX) and mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))


def budget_from_option(option: Optional[str]) -> int:
    return parse_size(option) if option else default_budget()
