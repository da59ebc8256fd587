r"""The kim-mcl report: Kim, Kim & Kim (2011), Monte Carlo localisation with a noisy motion model.

The document is described in docs/papers/kim-mcl.md. The report reads ``results/kim-mcl/``
(made by ``pfx reproduce kim-mcl`` from ``configs/papers/kim-mcl/``) and the document's facts
(``paper.yaml``):

* ``arena`` (Figs. 3 and 5): pfx's arena and route, which the paper does not give;
* ``one-run`` (Fig. 4's screen): the particle cloud of one noisy-model run, snapshots and GIF;
* ``paper-runs`` (Figs. 6 and 7, the paper's 10 runs per point) and ``extended`` (100 runs per
  point): convergence time (actions) and error distance at convergence (cm) for 200..400
  particles, noise-free against noisy motion model, each with the paper's sensor variance
  (1.0 cm²) and a tempered one (100 cm²) in the filter.

The paper prints no values for Figs. 6 and 7, only what they show; its finding has four parts,
and each gets a verdict per filter sensor variance, from the extended runs:

1. *noise-free converges faster*: per particle count N, the paired difference (trial t of both
   arms sees the same truth, :func:`pfx.analysis.compare.paired_comparison`) of the convergence time,
   noise-free - noisy, with its 95% t-interval; the claim holds at N when the interval lies
   below 0.
2. *noise-free lands farther from the truth*: the same for the error at convergence, holding
   when the interval lies above 0.
   For 1 and 2: *reproduced* if the claim holds at every N, *partly reproduced* at some,
   *not reproduced* at none (:func:`per_count_verdict`).
3. *noisy is far more accurate*: the relative change of the mean error at convergence, noisy /
   noise-free - 1, over all N pooled (pairs: same N and trial;
   :func:`pfx.analysis.paired_statistics.relative_change_interval`); "far" is read as at least halving it:
   *reproduced* when the interval's upper end is below -50 %, *partly reproduced* when it is
   below 0 only, else *not reproduced* (:func:`accuracy_verdict`).
4. *noisy improves with N*: the least-squares slope of the noisy arm's error at convergence
   against N (its trials as points) with its 95% t-interval: *reproduced* when the interval lies
   below 0, else *not reproduced* (:func:`trend_verdict`).

Convergence is pfx's spread criterion (docs/reference-facts.md, convergence criteria), the
parameters read from the result's config: the paper's "every particle within a circle of about
2 mm" is replaced, for the reasons given in the configs.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from pfx.analysis.compare import paired_comparison
from pfx.analysis.paired_statistics import relative_change_interval
from pfx.analysis.value_ranges import metric_range
from pfx.errors import ConfigError
from pfx.papers.base import (
    REPORTS,
    Figure,
    PaperResults,
    Part,
    Section,
    Table,
    Text,
    Verdict,
    assemble,
    format_number,
    interval,
    markdown_table,
    percent,
    verdict_from_checks,
)

PAPER = "kim-mcl"
VARIANCE = "filter_model_measurement_noise_variance"
NOISE_FREE, NOISY = "noise-free", "noisy"
FAR = -0.5                 # "far more accurate": the noisy arm's mean error at most half the noise-free one's
COMPARED = ("convergence_step", "error_at_convergence", "error_distance_final", "converged")


def per_count_verdict(low: np.ndarray, high: np.ndarray, sign: int) -> str:
    """Verdict of a claim tested at each particle count by a 95% interval of a paired difference.

    ``sign`` -1: the claim is that the difference is negative (holds where ``high < 0``);
    +1: positive (holds where ``low > 0``). All counts: reproduced; some: partly; none: not.
    """
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    return verdict_from_checks(high < 0 if sign < 0 else low > 0)


def accuracy_verdict(high: float) -> str:
    """'Far more accurate' from the upper end of the relative change's interval (noisy / noise-free - 1)."""
    if high < FAR:
        return "reproduced"
    return "partly reproduced" if high < 0 else "not reproduced"


def trend_verdict(high: float) -> str:
    """'Improves with N': the slope of the error against N lies below 0 (its interval's upper end)."""
    return "reproduced" if high < 0 else "not reproduced"


def error_slope(frame: pd.DataFrame, metric: str = "error_at_convergence") -> tuple[float, float, float, int]:
    """Least-squares slope of ``metric`` on n_particles (trials as points; NaN left out): slope, 95% CI, n."""
    usable = frame[np.isfinite(frame[metric].to_numpy(dtype=float))]
    n = len(usable)
    if n < 3 or usable["n_particles"].nunique() < 2:
        return math.nan, math.nan, math.nan, n
    fit = stats.linregress(usable["n_particles"].to_numpy(dtype=float), usable[metric].to_numpy(dtype=float))
    half = float(stats.t.ppf(0.975, n - 2)) * fit.stderr
    return fit.slope, fit.slope - half, fit.slope + half, n


def _criterion(results: PaperResults, experiment: str) -> dict:
    """The convergence criterion of an experiment's resolved config."""
    return (results.config(experiment).get("metrics") or {}).get("convergence") or {}


def criterion_text(criterion: dict, unit: str) -> str:
    """The convergence criterion in words, for the tables that need it named.

    docs/reference-facts.md (convergence criteria) asks that a convergence result name its criterion.
    """
    if criterion.get("criterion") != "spread":
        return f"convergence criterion {criterion}"
    mean = "weighted" if criterion.get("weighted") else "unweighted"
    return (f"converged = at least {100 * criterion['fraction']:g} % of the particles within "
            f"{criterion['radius']:g} {unit} of their {mean} mean (pfx criterion `spread`); time = actions "
            "until then; error distance = |true - estimated position| at that step")


def _mean_and_interval(mean, low, high) -> str:
    """A table cell "1.9 (1.82–1.98)": the mean and its 95% CI; blank when no run converged."""
    if not np.isfinite(mean):
        return ""
    return f"{format_number(mean)} {interval(low, high, brackets='()', separator='–')}"


def _cell_rows(summary: pd.DataFrame, variance: float) -> pd.DataFrame:
    rows = summary[np.isclose(summary[VARIANCE], variance)]
    return rows.sort_values(["arm", "n_particles"])


def _results_table(paper: pd.DataFrame, extended: pd.DataFrame, variance: float) -> pd.DataFrame:
    """Per arm x N: share converged, mean time and mean error (95% CI), for 10 and for extended runs."""
    out = []
    for _, row in _cell_rows(extended, variance).iterrows():
        line = {"motion model": row["arm"], "N": int(row["n_particles"])}
        for tag, summary in (("10 runs", paper), (f"{int(row['trials'])} runs", extended)):
            match = summary[(summary["arm"] == row["arm"]) & (summary["n_particles"] == row["n_particles"])
                            & np.isclose(summary[VARIANCE], variance)]
            if match.empty:
                continue
            cell = match.iloc[0]
            line[f"{tag}: converged"] = f"{int(round(cell['converged_mean'] * cell['trials']))}/{int(cell['trials'])}"
            line[f"{tag}: time [actions]"] = _mean_and_interval(cell["convergence_step_mean"],
                                                                cell["convergence_step_ci95_low"],
                                                                cell["convergence_step_ci95_high"])
            line[f"{tag}: error [cm]"] = _mean_and_interval(cell["error_at_convergence_mean"],
                                                            cell["error_at_convergence_ci95_low"],
                                                            cell["error_at_convergence_ci95_high"])
        out.append(line)
    return pd.DataFrame(out)


def first_trials_coincide(paper: pd.DataFrame, extended: pd.DataFrame, labels: list[str]) -> bool:
    """Whether the paper-runs trials are the extended run's trials of the same numbers, value for value."""
    keys = [c for c in labels if c in paper and c in extended] + ["trial"]
    merged = paper.merge(extended, on=keys, how="left", suffixes=("", "_extended"))
    if len(merged) != len(paper):
        return False
    for column in COMPARED:
        a = merged[column].to_numpy(dtype=float)
        b = merged[f"{column}_extended"].to_numpy(dtype=float)
        if not np.array_equal(a, b, equal_nan=True):
            return False
    return True


def _sensor_name(variance: float) -> str:
    return (f"the paper's sensor model ({variance:g} cm²)" if variance <= 1.0
            else f"a tempered sensor model ({variance:g} cm²)")


def _verdicts(trials: pd.DataFrame, labels: list[str], variance: float) -> list[Verdict]:
    """The four parts of the finding, at one filter sensor variance (module docstring)."""
    frame = trials[np.isclose(trials[VARIANCE], variance)]
    name = _sensor_name(variance)
    runs = int(frame.groupby(["arm", "n_particles"]).size().min())
    share = frame.groupby("arm")["converged"].mean()
    shares = ", ".join(f"{arm} {100 * value:.0f} %" for arm, value in share.items())
    verdicts = []

    def paired(metric: str):
        try:
            table = paired_comparison(frame, metric, by="arm", baseline=NOISY, label_columns=labels)
        except ConfigError:            # no run converged in both arms: nothing to pair, the claim fails
            return pd.DataFrame(columns=["n_particles", "mean_difference", "ci95_low", "ci95_high"])
        return table.sort_values("n_particles")

    def listing(table, unit: str) -> str:
        return "; ".join(f"N = {int(r['n_particles'])}: {format_number(r['mean_difference'])} "
                         f"({format_number(r['ci95_low'])} to {format_number(r['ci95_high'])}) {unit}"
                         for _, r in table.iterrows())

    time = paired("convergence_step")
    verdicts.append(Verdict(
        f"with {name}: the noise-free model converges faster (Fig. 6)",
        per_count_verdict(time["ci95_low"], time["ci95_high"], -1),
        f"{runs} runs per point, runs converged: {shares}; mean convergence time noise-free - noisy, paired "
        f"(95% CI): {listing(time, 'actions')}."))
    error = paired("error_at_convergence")
    verdicts.append(Verdict(
        f"with {name}: the noise-free model lands farther from the truth at convergence (Fig. 7)",
        per_count_verdict(error["ci95_low"], error["ci95_high"], +1),
        f"mean error at convergence noise-free - noisy, paired (95% CI): {listing(error, 'cm')}."))
    pairs = frame.pivot_table(index=["n_particles", "trial"], columns="arm", values="error_at_convergence")
    change, low, high = relative_change_interval(pairs[NOISE_FREE].to_numpy(), pairs[NOISY].to_numpy(),
                                                 value_range=metric_range("error_at_convergence"))
    means = pairs.mean()
    verdicts.append(Verdict(
        f"with {name}: the noisy model is far more accurate (read: at most half the noise-free error)",
        accuracy_verdict(high),
        f"mean error at convergence over all N: noisy {format_number(means[NOISY])} cm, noise-free "
        f"{format_number(means[NOISE_FREE])} cm, relative change {percent(change, decimals=0, suffix=' %')} "
        f"(95% CI {percent(low, decimals=0, suffix=' %')} to {percent(high, decimals=0, suffix=' %')}; "
        f"'far' needs the whole interval below {100 * FAR:.0f} %)."))
    slope, slope_low, slope_high, n = error_slope(frame[frame["arm"] == NOISY])
    free_slope, free_low, free_high, _ = error_slope(frame[frame["arm"] == NOISE_FREE])
    by_count = frame[frame["arm"] == NOISY].groupby("n_particles")["error_at_convergence"].mean()
    verdicts.append(Verdict(
        f"with {name}: the noisy model's error falls as N grows (Fig. 7)",
        trend_verdict(slope_high),
        f"least-squares slope of the noisy model's error at convergence on N ({n} converged runs): "
        f"{format_number(100 * slope)} cm per 100 particles (95% CI {format_number(100 * slope_low)} to "
        f"{format_number(100 * slope_high)}); mean {format_number(by_count.iloc[0])} cm at N = {int(by_count.index[0])}, "
        f"{format_number(by_count.iloc[-1])} cm at N = {int(by_count.index[-1])} (noise-free's slope, which the paper "
        f"calls flat: {format_number(100 * free_slope)}, CI {format_number(100 * free_low)} to "
        f"{format_number(100 * free_high)})."))
    return verdicts


def _overall(verdicts: list[Verdict]) -> str:
    held = sum(v.verdict == "reproduced" for v in verdicts)
    partly = sum(v.verdict == "partly reproduced" for v in verdicts)
    if held == len(verdicts):
        return "the finding holds in all four parts"
    if held + partly == 0:
        return "the finding does not hold in any part"
    return f"the finding holds in {held} of its {len(verdicts)} parts" + (f" and partly in {partly}" if partly else "")


# -- the parts of the report, in the section's order ------------------------------------------

def arena_part(results: PaperResults) -> Part:
    """Figs. 3 and 5: pfx's arena and route (the paper gives neither)."""
    if not results.has("arena"):
        return Part()
    return Part([
        Figure("arena", "arena_map.png",
               "Figs. 3 and 5 (pfx's own, the paper gives neither): the arena's walls (cm), the start "
               "pose and the commanded 40-action route executed exactly, numbered by action (turns "
               "in place share a label), with one true path of the real robot, which covers 92 % of "
               "each move and turns 3 % too far, with noise."),
        Figure("arena", "trajectory_map.png",
               "One run of the noisy motion model (300 particles, tempered sensor model): true and "
               "estimated paths.")])


def one_run_part(results: PaperResults) -> Part:
    """Fig. 4's screen: the particle cloud of one noisy-model run."""
    if not results.has("one-run"):
        return Part()
    return Part([
        Figure("one-run", "particle_snapshots.png",
               "Fig. 4's screen: the 300 weighted particles of one noisy-model run (tempered sensor "
               "model) on the map, from the uniform prior over free space to a cloud around the "
               "robot, at six of its 40 actions."),
        Figure("one-run", "particle_animation.gif", "The same run action by action (animated GIF).")])


def figures_6_and_7_part(results: PaperResults) -> Part:
    """Figs. 6 and 7 with the paper's 10 runs and with 100; the four verdicts per filter sensor model."""
    if not (results.has("paper-runs") and results.has("extended")):
        return Part()
    numbers = results.numbers
    items, verdicts = [], []
    paper, extended = results.folder("paper-runs"), results.folder("extended")
    unit = extended.units.get("position", "cm")
    criterion = criterion_text(_criterion(results, "extended"), unit)
    same = first_trials_coincide(paper.trials, extended.trials, extended.label_columns)
    for experiment, runs in (("paper-runs", "the paper's 10 runs"), ("extended", f"{int(extended.summary['trials'].max())} runs")):
        items.append(Figure(experiment, "convergence_vs_particles.png",
                            f"Fig. 6 with {runs} per point: mean convergence time in actions (band: 95% CI) and "
                            "the share of runs converged against the particle count, one line per motion model "
                            "and filter sensor variance (cm²)."))
        items.append(Figure(experiment, "error_at_convergence_vs_particles.png",
                            f"Fig. 7 with {runs} per point: mean error distance at convergence (cm, band: 95% "
                            "CI) against the particle count."))
    figures_note = numbers.get("figure6_convergence_time", {}), numbers.get("figure7_error_distance", {})
    items.append(Table(
        "The paper's Figs. 6 and 7 (values not printed; what its text says they show)",
        markdown_table(pd.DataFrame([
            {"motion model": NOISE_FREE, "convergence time (Fig. 6)": figures_note[0].get("noise_free", ""),
             "error distance (Fig. 7)": figures_note[1].get("noise_free", "")},
            {"motion model": NOISY, "convergence time (Fig. 6)": figures_note[0].get("noisy", ""),
             "error distance (Fig. 7)": figures_note[1].get("noisy", "")}])),
        f"The paper's criterion: {numbers.get('convergence_criterion', '')}; its error distance has no stated "
        "unit. Its absolute numbers could not be compared anyway: the arena and route are pfx's own."))
    for variance in sorted(extended.summary[VARIANCE].unique()):
        items.append(Table(
            f"Figs. 6 and 7 as a table, with {_sensor_name(variance)} in the filter: mean (95% CI)",
            markdown_table(_results_table(paper.summary, extended.summary, variance)),
            f"Criterion: {criterion}. Means over converged runs. The truth's sonar noise is 1.0 cm² "
            f"throughout; the filter assumes {variance:g} cm²."))
        verdicts += _verdicts(extended.trials, extended.label_columns, variance)
    items.append(Text(
        "**Why two sensor models.** With the paper's sensor variance of 1.0 cm² in the filter (sd 1 cm), "
        "the first readings leave weight on a handful of the 200..400 uniformly spread particles, whose "
        "spacing is about sqrt(free area / N) ≈ 12 cm at N = 300, none of them near the truth: both motion "
        "models then collapse within about two actions far from the robot. A filter sensor sd of the order "
        "of the particle spacing (100 cm², sd 10 cm) lets the particles present carry weight; it is the same "
        "in both arms, so the comparison of the motion models stands. The paper's real robot may have "
        "differed (its error-distance unit, arena and route are unknown).\n\n"
        "**Criterion.** The paper's \"all particles inside a circle of about 2 mm\" cannot be met by a "
        "noisy-model cloud, whose particles spread by the motion noise itself (a localised noisy cloud that "
        "tracks the robot from its known start has a median RMS spread of 8 cm); only the noise-free cloud, "
        "made of copies of one particle, shrinks to a point. pfx uses the spread criterion above (90 % within "
        "15 cm, what a localised cloud reaches; 90 % so that a few strays do not postpone convergence "
        "indefinitely).\n\n"
        f"**Same trials.** paper-runs and extended share model, filter, arms, sweep and seed: the 10 "
        f"paper-runs trials {'are' if same else 'are NOT'} value for value trials 0-9 of the extended runs."))
    return Part(items, verdicts)


def _findings(verdicts: list[Verdict]) -> list[str]:
    """'with <sensor model>, the finding holds in ...': one clause per filter sensor model.

    The verdicts of one sensor model are the four of :func:`_verdicts`, whose claims all start
    with "with <sensor model>:"; that prefix groups them.
    """
    by_sensor: dict[str, list[Verdict]] = {}
    for verdict in verdicts:
        by_sensor.setdefault(verdict.claim.split(":")[0], []).append(verdict)
    return [f"{sensor}, {_overall(group)}" for sensor, group in by_sensor.items()]


# -- the report -------------------------------------------------------------------------------

PARTS = (arena_part, one_run_part, figures_6_and_7_part)


@REPORTS.register(PAPER)
def kim_mcl_report(results: PaperResults) -> Section:
    numbers = results.numbers
    items, verdicts = assemble(results, PARTS)
    findings = _findings(verdicts)
    summary = (
        f"{numbers.get('citation', 'Kim, Kim & Kim (2011)')} A Lego NXT robot with one forward ultrasonic "
        "sensor localises itself with a particle filter; the paper compares a noise-free motion model (the "
        "commanded action exactly) with a noisy one (92 % of each move, 103 % of each turn, variances 9.0 and "
        "13.0), for 200..400 particles, 10 runs each, by the convergence time (actions) and the error distance at "
        "convergence. Its arena, route and figure values are not given: pfx simulates the robot (with the "
        "paper's biases and noise) in an arena and along a route of its own, in centimetres. "
        + ("In our simulation " + "; ".join(findings) + " (verdicts below, from the extended runs)." if findings else ""))
    return Section(PAPER, f"{PAPER}: {numbers.get('title', 'Particle Filter Localization Using Noisy Models')}",
                   summary, items, verdicts)
