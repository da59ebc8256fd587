"""Gallery items for ``prob-robotics``, part B: the motion models (Figs. 5.3, 5.4, 5.8, 5.9) and Table 4.2.

:func:`motion_sections` is one part of the prob-robotics report (see :mod:`pfx.papers.base`),
itself assembled from five parts, one per experiment below, each returning nothing when its
folder is absent. The motion-model algorithms as pfx runs them (the book's, corrected) are in
docs/reference-facts.md. The book prints no numbers for these figures (no alpha values, no
densities), so every verdict checks a property the book states against our CSV numbers:

* **the sampler and the density agree** (Figs. 5.3 vs 5.4, 5.8 vs 5.9): Pearson's chi-square of
  the sampler's draws against the gridded density (table ``agreement``), passing at
  p >= :data:`P_LIMIT`; checked for the book's value as printed (Table 5.1 / 5.5, normalised)
  and for the density of the pose (the same divided by the Jacobian);
* **what the settings do** (panels b and c): larger translational error spreads the pose along
  the motion, larger rotational error across it: the variances along and across compared
  between settings (b, c) and the default (a), by z = difference / its standard error, for both
  noise families and both sample counts; significant at z > :data:`Z_LIMIT`;
* **normal and triangular errors give the same spread** (Table 5.4: the same variance b): the
  variances compared between the families, significant at |z| > :data:`Z_LIMIT`;
* **the binary Bayes filter converges** (Table 4.2): the worked example's final beliefs and,
  over the repeated runs, the visible cells' error and share misclassified per scan.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pfx.papers.base import (
    Figure,
    PaperResults,
    Part,
    Table,
    Verdict,
    assemble,
    format_number,
    markdown_table,
    p_value,
    percent,
    verdict_from_checks,
)
from pfx.result_folder import ResultFolder

VELOCITY_DENSITY = "fig-5.3-velocity-density"
VELOCITY_SAMPLES = "fig-5.4-velocity-samples"
ODOMETRY_DENSITY = "fig-5.8-odometry-density"
ODOMETRY_SAMPLES = "fig-5.9-odometry-samples"
BINARY_BAYES = "table-4.2-binary-bayes"

# Thresholds of the verdicts, stated once.
P_LIMIT = 1e-3      # chi-square: the draws follow the density unless p < 1e-3
Z_LIMIT = 3.0       # a difference of variances is significant beyond 3 standard errors

MODELS = {
    "velocity": {"density": VELOCITY_DENSITY, "samples": VELOCITY_SAMPLES, "figures": ("5.3", "5.4"),
                 "tables": ("5.1", "5.3"), "translational": "α1, α2", "rotational": "α3, α4"},
    "odometry": {"density": ODOMETRY_DENSITY, "samples": ODOMETRY_SAMPLES, "figures": ("5.8", "5.9"),
                 "tables": ("5.5", "5.6"), "translational": "α3, α4", "rotational": "α1, α2"},
}


def motion_sections(results: PaperResults) -> Part:
    """The motion-model and binary Bayes experiments present in ``results``: (items, verdicts)."""
    return assemble(results, (velocity_density_part, velocity_samples_part, odometry_density_part,
                              odometry_samples_part, binary_bayes_part))


def velocity_density_part(results: PaperResults) -> Part:
    return density_part(results, "velocity")


def velocity_samples_part(results: PaperResults) -> Part:
    return samples_part(results, "velocity")


def odometry_density_part(results: PaperResults) -> Part:
    return density_part(results, "odometry")


def odometry_samples_part(results: PaperResults) -> Part:
    return samples_part(results, "odometry")


def _printed(results: PaperResults, figure: str) -> str:
    """What paper.yaml says the book prints for a figure (``figures: {fig_5_3: {printed_numbers}}``)."""
    entry = results.numbers.get("figures", {}).get("fig_" + figure.replace(".", "_"), {})
    printed = entry.get("printed_numbers") if isinstance(entry, dict) else None
    return f"The book prints: {printed}." if printed else "The book prints no numbers for this figure."


def _labels(folder: ResultFolder) -> dict[str, str]:
    settings = folder.table("settings")
    return dict(zip(settings["setting"], settings["label"]))


def density_part(results: PaperResults, model: str) -> Part:
    """Fig. 5.3 or 5.8: the motion model's density, and the sampler's draws against it."""
    spec = MODELS[model]
    if not results.has(spec["density"]):
        return Part()
    folder = results.folder(spec["density"])
    printed = _printed(results, spec["figures"][0])
    agreement = folder.table("agreement")
    labels = _labels(folder)
    figure_number, (density_table, sampler_table) = spec["figures"][0], spec["tables"]
    pose = agreement[agreement["density"] == "pose"].set_index("setting")
    book = agreement[agreement["density"] == "table_5_1"].set_index("setting")
    n = int(pose["samples"].iloc[0])
    bin_text = f"{100 * pose['bin_x'].iloc[0]:.3g} cm x {100 * pose['bin_y'].iloc[0]:.3g} cm bins"
    items: list = [Figure(
        folder.path.name, "motion_density_panels.png",
        f"Fig. {figure_number} ({model} motion model): the density of the pose after one motion, summed over "
        f"a grid of headings, for the alpha settings of the config. {printed} Share of the distribution inside "
        f"the x-y grid and the heading window: {', '.join(format_number(m, 4) for m in pose['grid_mass'])}.")]
    table = pd.DataFrame({
        "setting": [labels.get(s, s) for s in pose.index],
        f"χ² p, Table {density_table} as printed": [p_value(book.loc[s, "p_value"]) for s in pose.index],
        f"TV, Table {density_table}": [book.loc[s, "total_variation"] for s in pose.index],
        "χ² p, pose density (÷ Jacobian)": [p_value(pose.loc[s, "p_value"]) for s in pose.index],
        "TV, pose density": [pose.loc[s, "total_variation"] for s in pose.index],
        "TV from sampling alone (mean / 99%)": [f"{pose.loc[s, 'tv_null_mean']:.3f} / {pose.loc[s, 'tv_null_q99']:.3f}"
                                               for s in pose.index],
        "χ² dof": pose["dof"].astype(int).tolist(),
    })
    items.append(Table(
        f"Fig. {figure_number} against the sampler (Table {sampler_table}): {n:,} draws per setting",
        markdown_table(table, digits=3),
        f"Pearson's chi-square of the draws in {bin_text} (bins expecting < 5 draws pooled) against the density "
        "(unitless p; TV = total variation distance between the binned draws and the density, unitless). "
        f"The book's Table {density_table} is the density of the motion noise at the pose's preimage; the "
        "density of the pose divides it by the Jacobian of the map from noise to pose, which varies across the "
        "distribution (∝ the executed translation)."))
    pose_ok = bool((pose["p_value"] >= P_LIMIT).all())
    book_ok = bool((book["p_value"] >= P_LIMIT).all())
    if book_ok and pose_ok:
        verdict = "reproduced"
    elif pose_ok:
        verdict = "partly reproduced"
    else:
        verdict = "not reproduced"
    per_setting = "; ".join(
        f"{s}: {p_value(book.loc[s, 'p_value'], in_words=True)} (TV {book.loc[s, 'total_variation']:.3f}) as printed, "
        f"{p_value(pose.loc[s, 'p_value'], in_words=True)} (TV {pose.loc[s, 'total_variation']:.3f}) ÷ Jacobian"
        for s in pose.index)
    sampling = f"{pose['tv_null_mean'].min():.3f}-{pose['tv_null_mean'].max():.3f}"
    evidence = (f"chi-square of {n:,} draws per setting against the gridded density (passes at p ≥ {P_LIMIT:g}): "
                f"{per_setting}; sampling alone gives TV ≈ {sampling}.")
    if verdict == "partly reproduced":
        evidence += (f" The sampler follows the density of the pose; Table {density_table}'s value, which leaves "
                     "out the Jacobian, has the right support and orientation but the wrong weights along the "
                     "motion.")
    verdicts = [Verdict(f"Figs. {spec['figures'][0]} and {spec['figures'][1]} show the same law: the sampler "
                        f"(Table {sampler_table}) draws from the density (Table {density_table}).", verdict, evidence)]
    return Part(items, verdicts)


def _z(first, second, column: str) -> float:
    """z of the difference second - first of a variance column, from the two standard errors."""
    difference = second[column] - first[column]
    return float(difference / math.hypot(first[f"{column}_se"], second[f"{column}_se"]))


def samples_part(results: PaperResults, model: str) -> Part:
    """Fig. 5.4 or 5.9: samples of the motion model, and what the alpha settings and noise families do."""
    spec = MODELS[model]
    if not results.has(spec["samples"]):
        return Part()
    folder = results.folder(spec["samples"])
    printed = _printed(results, spec["figures"][1])
    spread = folder.table("spread")
    settings = folder.table("settings")
    labels = dict(zip(settings["setting"], settings["label"]))
    figure_number, sampler_table = spec["figures"][1], spec["tables"][1]
    counts = sorted(spread["n"].unique())
    noises = list(dict.fromkeys(spread["noise"]))
    shown = int(counts[0])
    items: list = [
        Figure(folder.path.name, "motion_sample_panels.png",
               f"Fig. {figure_number} ({model} motion model): {shown} poses per panel drawn by Table {sampler_table}, "
               "with normal errors (top) and triangular errors (bottom), for the settings of Fig. "
               f"{spec['figures'][0]}."),
        Figure(folder.path.name, "motion_spread.png",
               f"Spread of the sampled positions along and across the direction of motion (from the start to the "
               f"noise-free end), {int(counts[-1]):,} draws per setting and error family, 95% intervals.")]
    table = spread.assign(setting=spread["setting"].map(labels),
                          ratio=spread["std_along"] / spread["std_across"])
    table = table[["setting", "noise", "n", "std_along", "std_across", "ratio", "correlation"]].rename(columns={
        "n": "draws", "std_along": "sd along (m)", "std_across": "sd across (m)", "ratio": "along / across",
        "correlation": "correlation"})
    items.append(Table(
        f"Fig. {figure_number}: spread of the sampled positions ({model} model)",
        markdown_table(table, digits=3),
        f"{printed} We draw {shown} per panel (the first {shown} of the {int(counts[-1]):,} draws of the "
        "statistics). 'along' is the direction from the start to the noise-free end pose."))
    verdicts = [_settings_verdict(spread, settings, spec), _noise_verdict(spread, labels, noises, counts, spec)]
    return Part(items, verdicts)


def _settings_verdict(spread: pd.DataFrame, settings: pd.DataFrame, spec: dict) -> Verdict:
    """(b) against (a): more along, less across; (c) against (a): more across, less along."""
    names = list(settings["setting"])
    claim = (f"Fig. {spec['figures'][0]} (b) and (c): larger translational error ({spec['translational']}) spreads "
             f"the pose along the motion, larger rotational error ({spec['rotational']}) across it (along the arc).")
    if len(names) < 3:
        return Verdict(claim, "not comparable", "the config has fewer than three settings (a, b, c).")
    default, translational, rotational = names[:3]
    comparisons = []     # (description, z): z > 0 in the claimed direction
    for (noise, n), group in spread.groupby(["noise", "n"], sort=False):
        rows = group.set_index("setting")
        a, b, c = rows.loc[default], rows.loc[translational], rows.loc[rotational]
        comparisons += [(f"{noise}, n={n}: along b > a", _z(a, b, "var_along")),
                        (f"{noise}, n={n}: across b < a", -_z(a, b, "var_across")),
                        (f"{noise}, n={n}: across c > a", _z(a, c, "var_across")),
                        (f"{noise}, n={n}: along c < a", -_z(a, c, "var_along"))]
    z_values = np.array([z for _, z in comparisons])
    if (z_values > Z_LIMIT).all():
        verdict = "reproduced"
    elif (z_values > 0).all():
        verdict = "partly reproduced"
    else:
        verdict = "not reproduced"
    extended = spread[(spread["n"] == spread["n"].max()) & (spread["noise"] == spread["noise"].iloc[0])]
    extended = extended.set_index("setting")
    sds = "; ".join(f"({name}) {extended.loc[s, 'std_along']:.3f} / {extended.loc[s, 'std_across']:.3f} m"
                    for name, s in zip("abc", (default, translational, rotational)))
    weakest = comparisons[int(np.argmin(z_values))]
    evidence = (f"sd along / across the motion ({extended['noise'].iloc[0]} errors, {int(extended['n'].iloc[0]):,} "
                f"draws): {sds}; {int((z_values > Z_LIMIT).sum())} of {len(z_values)} comparisons (both error "
                f"families, both draw counts) go the claimed way beyond {Z_LIMIT:g} standard errors, the weakest "
                f"({weakest[0]}) at z = {weakest[1]:.1f}.")
    return Verdict(claim, verdict, evidence)


def _noise_verdict(spread: pd.DataFrame, labels: dict, noises: list, counts: list, spec: dict) -> Verdict:
    """Normal against triangular: the variances along and across, setting by setting."""
    claim = ("Table 5.4: normal and triangular errors of the same variance give samples of the same spread "
             f"(Fig. {spec['figures'][1]}).")
    if len(noises) < 2:
        return Verdict(claim, "not comparable", "only one error family was drawn.")
    first, second = noises[:2]
    comparisons = []     # (setting, axis, n, relative difference of sd, z)
    for (setting, n), group in spread.groupby(["setting", "n"], sort=False):
        rows = group.set_index("noise")
        for axis in ("along", "across"):
            z = _z(rows.loc[first], rows.loc[second], f"var_{axis}")
            relative = rows.loc[second, f"std_{axis}"] / rows.loc[first, f"std_{axis}"] - 1
            comparisons.append((setting, axis, int(n), relative, z))
    significant = [c for c in comparisons if abs(c[4]) > Z_LIMIT]
    largest = max(comparisons, key=lambda c: abs(c[4]))
    extended = [c for c in comparisons if c[2] == max(counts)]
    widest = max(abs(c[3]) for c in extended)
    evidence = (f"{len(significant)} of {len(comparisons)} variance comparisons ({second} vs {first}, each setting, "
                f"along and across, {', '.join(f'{int(n):,}' for n in counts)} draws) differ beyond {Z_LIMIT:g} "
                f"standard errors; at {int(max(counts)):,} draws the standard deviations differ by at most "
                f"{100 * widest:.1f}%; the largest z is {largest[4]:+.1f} ({labels.get(largest[0], largest[0])}, "
                f"{largest[1]}, {largest[2]:,} draws, {percent(largest[3])} in sd).")
    if not significant:
        verdict = "reproduced"
    elif len(significant) <= len(comparisons) / 2:
        verdict = "partly reproduced"
        evidence += (" The errors have equal variances, so the spreads agree to first order; the pose depends on "
                     "them nonlinearly (the cosine of a rotation error), and the second-order terms involve their "
                     "fourth moments (3 b^2 normal, 2.4 b^2 triangular), which large errors make visible.")
    else:
        verdict = "not reproduced"
    return Verdict(claim, verdict, evidence)


def binary_bayes_part(results: PaperResults) -> Part:
    """Table 4.2: the binary Bayes filter's worked example and its convergence over repeated runs."""
    if not results.has(BINARY_BAYES):
        return Part()
    folder = results.folder(BINARY_BAYES)
    convergence = folder.table("convergence")
    final = folder.table("final")
    runs = int(convergence["runs"].iloc[0])
    scans = int(convergence["scan"].max())
    items: list = [
        Figure(folder.path.name, "binary_bayes_beliefs.png",
               f"Table 4.2, the binary Bayes filter in log odds: a corridor of {len(final)} cells scanned {scans} "
               f"times by a range sensor (inverse sensor model). Top: the example run's belief per cell after each "
               f"scan; bottom: the final belief against the true occupancy, with the mean over {runs:,} runs."),
        Figure(folder.path.name, "binary_bayes_convergence.png",
               f"Over {runs:,} runs: the error |belief − truth| of the cells the sensor sees, and the share of them "
               "on the wrong side of 1/2, after each scan (95% intervals)."),
    ]
    prior = float(convergence["prior"].iloc[0])
    table = convergence[["scan", "visible_error_mean", "visible_error_se", "visible_wrong_mean",
                         "hidden_belief_mean"]].rename(columns={
        "visible_error_mean": "mean abs(belief − truth), visible cells", "visible_error_se": "its SE",
        "visible_wrong_mean": "share of visible cells misclassified",
        "hidden_belief_mean": f"mean belief of occluded cells (prior {prior:g})"})
    items.append(Table(f"Table 4.2 example: convergence over {runs:,} runs", markdown_table(table, digits=3),
                       "Beliefs are probabilities (unitless). The book gives the algorithm and no example numbers."))
    visible = final[final["visible"].astype(bool)]
    truth = visible["occupied"].astype(bool)
    example_correct = np.where(truth, visible["example_belief"] > 0.5, visible["example_belief"] < 0.5)
    errors = convergence["visible_error_mean"].to_numpy()
    monotone = bool((np.diff(errors) < 0).all())
    first, last = convergence.iloc[0], convergence.iloc[-1]
    wrong_z = (first["visible_wrong_mean"] - last["visible_wrong_mean"]) / math.hypot(
        first["visible_wrong_se"], last["visible_wrong_se"]) if first["visible_wrong_se"] > 0 else float("inf")
    verdict = verdict_from_checks([example_correct.all(), monotone, wrong_z > 2])
    hidden = final[~final["visible"].astype(bool)]
    evidence = (f"example: {int(example_correct.sum())} of {len(visible)} visible cells end on their true side "
                f"after {scans} scans; over {runs:,} runs the visible cells' mean error falls "
                f"{'at every scan' if monotone else 'but not at every scan'} from {first['visible_error_mean']:.3g} "
                f"to {last['visible_error_mean']:.3g} and the share misclassified from "
                f"{first['visible_wrong_mean']:.3g} to {last['visible_wrong_mean']:.3g} (± {last['visible_wrong_se']:.1g} SE)")
    if not hidden.empty:
        evidence += (f"; the {len(hidden)} occluded cells keep a mean belief of {hidden['belief_mean'].mean():.3f} "
                     f"(prior {prior:g}: they are almost never observed)")
    verdicts = [Verdict("Table 4.2: accumulating log odds, the belief of every cell the sensor sees converges to "
                        "its true state (free or occupied).", verdict, evidence + ".")]
    return Part(items, verdicts)
