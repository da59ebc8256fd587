"""What ``pfx bench --backend jax`` prints: the table of rates and the goals (:mod:`pfx.bench.jax_bench`)."""

from __future__ import annotations

import math
from typing import Optional

from pfx.bench.jax_bench import Row
from pfx.bench.jax_device import Device, bytes_per_particle_step
from pfx.bench.report import _goal_line

NAME_WIDTH = 36


def _fraction(row: Row, device: Device) -> Optional[float]:
    """The row's rate over the bandwidth limit of where it ran: the JAX device, or (pfx numpy) the
    CPU when that is JAX's device too and its bandwidth was given."""
    if not row.runs or (not row.implementation.on_device and device.platform != "cpu"):
        return None
    limit = device.limit(row.implementation.precision)
    return row.rate / limit if limit else None


def _reference(rows: list[Row], row: Row) -> Optional[Row]:
    """The plain JAX filter's row of the same case and precision as pfx's jax row ``row``."""
    if row.implementation.kind != "pfx" or not row.implementation.on_device:
        return None
    return next((other for other in rows if other.case is row.case and other.implementation.kind == "reference"
                 and other.implementation.precision == row.implementation.precision and other.runs), None)


def _number(value: Optional[float], form: str, width: int) -> str:
    return f"{value:>{width}{form}}" if value is not None and math.isfinite(value) else f"{'-':>{width}}"


def format_jax_table(rows: list[Row], device: Device) -> str:
    """One line per (case, implementation): particle-steps/s, ns per particle-step, fraction of the
    bandwidth limit, pfx jax's rate over the reference's, the first call, RMSE, mean log-likelihood, runs."""
    header = (f"{'case':<16} {'implementation':<{NAME_WIDTH}} {'steps/s':>9} {'ns/step':>9} {'of limit':>8} "
              f"{'x ref':>6} {'1st call s':>10} {'alt. RMSE ft':>12} {'mean log L':>11} {'runs':>4}")
    lines = ["particle-steps per second (steps/s), ns per particle-step, the fraction of the memory-bandwidth "
             "limit, pfx jax's rate / the plain JAX filter's (x ref):", header, "-" * len(header)]
    previous = None
    for row in rows:
        label = row.case.label if row.case.label != previous else ""
        previous = row.case.label
        name = row.implementation.name
        if row.trials != row.case.trials:
            name += f" ({row.trials} of {row.case.trials} trials)"
        if row.note:
            lines.append(f"{label:<16} {name:<{NAME_WIDTH}} {row.note}")
            continue
        reference = _reference(rows, row)
        fraction = _fraction(row, device)
        lines.append(f"{label:<16} {name:<{NAME_WIDTH}} {_number(row.rate, '.3g', 9)} "
                     f"{_number(1e9 / row.rate, '.3g', 9)} {_number(fraction, '.1%', 8)} "
                     f"{_number(row.rate / reference.rate if reference else None, '.2f', 6)} "
                     f"{_number(row.first_call, '.2f', 10)} {_number(row.rmse, '.1f', 12)} "
                     f"{_number(row.log_likelihood, '.1f', 11)} {row.runs:>4}")
    limits = [f"{precision} {bytes_per_particle_step(precision)} bytes"
              + (f", limit {device.limit(precision):.3g} steps/s" if device.limit(precision) else "")
              for precision in ("float64", "float32")]
    lines.append(f"(the limit: bandwidth / bytes per particle-step, bytes = (4d + 5) scalars + a 4-byte index, d = 3: "
                 f"{'; '.join(limits)})")
    return "\n".join(lines)


def _find(rows: list[Row], particles: int, trials: int, name: str) -> Optional[Row]:
    return next((row for row in rows if (row.case.particles, row.case.trials, row.implementation.name)
                 == (particles, trials, name) and row.runs), None)


def format_jax_goals(rows: list[Row], device: Device) -> str:
    """The goals set for the jax backend, measured (never asserted by a test)."""
    gpu_only = "" if device.is_gpu else "no GPU: JAX ran on the CPU"
    lines = ["goals of the jax backend (rates of the best runs on this machine):"]
    for precision, goal in (("float32", 5.0), ("float64", 3.5)):
        row = _find(rows, 10_000, 1_000, f"pfx jax {precision}")
        lines.append(_goal_line(row.rate / 1e9 if row and device.is_gpu else None, goal, False,
                                f"1000 x N=1e4, GPU: pfx jax {precision}, 1e9 particle-steps/s",
                                gpu_only or "pfx jax not available or case not run"))
        fraction = _fraction(row, device) if row else None
        lines.append(_goal_line(fraction if device.is_gpu else None, 0.25, False,
                                f"1000 x N=1e4, GPU: pfx jax {precision}, fraction of the bandwidth limit (an aim)",
                                gpu_only or "bandwidth unknown or case not run"))
    for precision in ("float64", "float32"):
        ratios = [reference.rate / row.rate for row in rows
                  if row.implementation.name == f"pfx jax {precision}" and row.runs
                  and row.case.particles * row.case.trials >= 100_000
                  and (reference := _reference(rows, row)) is not None]
        lines.append(_goal_line(max(ratios) if ratios and device.is_gpu else None, 1.0, True,
                                f"from 1e5 particles a step, GPU: pfx jax {precision} time / plain JAX time, worst case",
                                gpu_only or "pfx jax not available or cases not run"))
    jax_row, numpy_row = _find(rows, 100, 1_000, "pfx jax float64"), _find(rows, 100, 1_000, "pfx numpy")
    ratio = numpy_row.rate / jax_row.rate if jax_row and numpy_row and not device.is_gpu else None
    lines.append(_goal_line(ratio, 1.5, True, "1000 x N=100, CPU: pfx jax float64 time / pfx numpy time",
                            "JAX ran on a GPU" if device.is_gpu else "pfx jax not available or case not run"))
    return "\n".join(lines)
